//! Registration on real data with ground truth (../shared/data), from seeded random starting poses.
//! Each test skips with a message when the data folder is absent.

mod common;
use common::*;
use depthcal::io::read_cloud;
use depthcal::registration::RegisterConfig;

/// More seeds from `DEPTHCAL_EXTRA_SEEDS=N` (seeds 1000..1000+N), for robustness sweeps.
fn extra_seeds() -> impl Iterator<Item = u64> {
    let n: u64 = std::env::var("DEPTHCAL_EXTRA_SEEDS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(0);
    1000..1000 + n
}

/// Registers fragment `j` of the 3DMatch redkitchen scene onto fragment `i` from seeded random poses: each answer
/// within the data set's truth floor (2.5° / 5 cm) and trusted.
fn three_dmatch_pair(i: usize, j: usize, seeds: &[u64]) {
    let Some(d) = data("3dmatch-redkitchen") else {
        return;
    };
    let text = std::fs::read_to_string(d.join("gt.log")).unwrap();
    let lines: Vec<&str> = text.lines().collect();
    let mut truth = None;
    for k in (0..lines.len()).step_by(5) {
        let h: Vec<usize> = lines[k]
            .split_whitespace()
            .map(|v| v.parse().unwrap())
            .collect();
        if h[0] == i && h[1] == j {
            let m: Vec<f64> = lines[k + 1..k + 5]
                .iter()
                .flat_map(|l| l.split_whitespace().map(|v| v.parse::<f64>().unwrap()))
                .collect();
            truth = Some(
                depthcal::geometry::transform::isometry_from_rows(&m.try_into().unwrap(), "gt")
                    .unwrap(),
            );
        }
    }
    let truth = truth.unwrap();
    let src = read_cloud(d.join(format!("cloud_bin_{j}.ply"))).unwrap();
    let tgt = read_cloud(d.join(format!("cloud_bin_{i}.ply"))).unwrap();
    for seed in seeds.iter().copied().chain(extra_seeds()) {
        let (r, t, reg) = perturbed_errors(
            &src,
            &tgt,
            &truth,
            seed,
            180.0,
            1.0,
            &RegisterConfig::default(),
        );
        eprintln!(
            "3DMatch {j}->{i} seed {seed}: {r:.3} deg, {:.1} mm, fitness {:.3}, overlap {:.3}, trusted {} {:?}, {:?}",
            t * 1e3,
            reg.fitness,
            reg.overlap,
            reg.trust.trusted,
            reg.trust.reasons,
            reg.timings_ms
        );
        assert!(
            r < 2.5 && t < 0.05,
            "3DMatch {j}->{i} seed {seed}: {r:.3} deg, {:.1} mm",
            t * 1e3
        );
        // Right at the data set's truth floor, so it must be trusted (30 of 30 seeds were).
        assert!(
            reg.trust.trusted,
            "3DMatch {j}->{i} seed {seed}: right but refused: {:?}",
            reg.trust.reasons
        );
    }
}

#[test]
fn three_dmatch_1_to_0() {
    three_dmatch_pair(0, 1, &[1, 2]);
}

#[test]
fn three_dmatch_4_to_0() {
    three_dmatch_pair(0, 4, &[3, 4]);
}

#[test]
fn three_dmatch_4_to_1() {
    three_dmatch_pair(1, 4, &[5, 6]);
}

#[test]
fn lidar_pair() {
    let Some(d) = data("lidar-small_gicp") else {
        return;
    };
    let truth = matrix(&d.join("T_target_source.txt"));
    let src = read_cloud(d.join("source.ply")).unwrap();
    let tgt = read_cloud(d.join("target.ply")).unwrap();
    for seed in [7, 8].into_iter().chain(extra_seeds()) {
        let (r, t, reg) = perturbed_errors(
            &src,
            &tgt,
            &truth,
            seed,
            180.0,
            5.0,
            &RegisterConfig::default(),
        );
        eprintln!(
            "LiDAR seed {seed}: {r:.3} deg, {:.1} mm, voxel {:.3}, {:?}",
            t * 1e3,
            reg.voxel,
            reg.timings_ms
        );
        assert!(
            r < 0.5 && t < 0.05,
            "LiDAR seed {seed}: {r:.3} deg, {:.1} mm",
            t * 1e3
        );
        // The pair's reference is good to about 1.5 cm, 0.3° (its two references disagree by that):
        // enough to tell an honest 1-σ. Independent residuals alone claimed 0.024° / 16 mm here (normalised
        // error 3.6); the cluster-robust covariance is honest.
        let moved_truth = truth * perturbation(seed, 180.0, 5.0).inverse();
        let z = depthcal::calibration::uncertainty::normalised_error(
            &reg.transform,
            &moved_truth,
            &reg.covariance,
        )
        .expect("an invertible covariance")
        .pose;
        eprintln!("LiDAR seed {seed}: normalised error {z:.2}");
        assert!(z < 3.0, "LiDAR seed {seed}: normalised error {z:.2}");
    }
}

/// 3DLoMatch (about 20% overlap, 118° apart): the cost's optimum lies 5-6° from the stated truth (ICP
/// started at the truth settles at 5.3-5.8°, ours and Open3D's at 2 cm), beyond the 3DMatch truth floor
/// of 2.5° / 5 cm, so the answer must not be trusted unless it is within that floor. The hold test refuses
/// it: ICP started ±1.07° off along the weakest rotation ends 0.19° apart (the bar is 0.065 of the step).
#[test]
fn three_dlomatch_low_overlap_is_right_or_not_trusted() {
    let Some(d) = data("3dlomatch-redkitchen") else {
        return;
    };
    let truth = matrix(&d.join("T_21_34.txt"));
    let src = read_cloud(d.join("cloud_bin_34.ply")).unwrap();
    let tgt = read_cloud(d.join("cloud_bin_21.ply")).unwrap();
    for seed in [0, 11].into_iter().chain(extra_seeds()) {
        let (r, t, reg) = perturbed_errors(
            &src,
            &tgt,
            &truth,
            seed,
            180.0,
            1.0,
            &RegisterConfig::default(),
        );
        eprintln!(
            "3DLoMatch seed {seed}: {r:.3} deg, {:.1} mm, overlap {:.3}, trusted {}, {:?}",
            t * 1e3,
            reg.overlap,
            reg.trust.trusted,
            reg.trust.reasons
        );
        let right = r < 2.5 && t < 0.05;
        assert!(
            right || !reg.trust.trusted,
            "3DLoMatch seed {seed}: {r:.3} deg, {:.1} mm off and trusted",
            t * 1e3
        );
        if !reg.trust.trusted {
            assert!(
                !reg.trust.reasons.is_empty(),
                "seed {seed}: refused without a reason"
            );
        }
    }
}

#[test]
fn geotransformer_demo_pair() {
    let Some(d) = data("geotransformer-3dmatch-demo") else {
        return;
    };
    // gt.npy is a 4x4 float64 array.
    let bytes = std::fs::read(d.join("gt.npy")).unwrap();
    let vals: Vec<f64> = bytes[bytes.len() - 128..]
        .chunks(8)
        .map(|c| f64::from_le_bytes(c.try_into().unwrap()))
        .collect();
    let truth =
        depthcal::geometry::transform::isometry_from_rows(&vals.try_into().unwrap(), "gt").unwrap();
    let src = read_cloud(d.join("src.npy")).unwrap();
    let tgt = read_cloud(d.join("ref.npy")).unwrap();
    for seed in [21, 22].into_iter().chain(extra_seeds()) {
        let (r, t, _) = perturbed_errors(
            &src,
            &tgt,
            &truth,
            seed,
            180.0,
            1.0,
            &RegisterConfig::default(),
        );
        eprintln!(
            "GeoTransformer demo seed {seed}: {r:.3} deg, {:.1} mm",
            t * 1e3
        );
        // This pair's truth is ~1° / 8 cm from the geometric optimum: point-to-plane ICP started at the
        // truth (ours, and Open3D's at 2 cm) settles at 1.0° / 7.8-8.5 cm. The bound sits just above it.
        assert!(
            r < 2.5 && t < 0.12,
            "seed {seed}: {r:.3} deg, {:.1} mm",
            t * 1e3
        );
    }
}
