//! Where does the refinement settle when started at the truth? `cargo run --release --example refine_probe --
//! FIRST COUNT [OVERLAP]` (optionally with `DEPTHCAL_REG_JSON`, a RegisterConfig patch for the refinement,
//! and `DEPTHCAL_SIM_JSON`, a SimConfig to start from). Prints per seed the error of ICP from the truth:
//! rotation (degrees), translation at the base origin and at the workspace centre (mm).
use depthcal::calibration::robot_to_robot::CalibrateConfig;
use depthcal::cell::{Cell, GroundTruth};
use depthcal::fusion::fuse_robot;
use depthcal::geometry::transform::pose_error;
use depthcal::registration::{register, RegisterConfig};
use depthcal::sim::{simulate_cell, SimConfig};
use nalgebra::Point3;

fn main() {
    let a: Vec<String> = std::env::args().collect();
    let first: u64 = a.get(1).and_then(|s| s.parse().ok()).unwrap_or(1);
    let n: u64 = a.get(2).and_then(|s| s.parse().ok()).unwrap_or(5);
    let overlap: Option<f64> = a.get(3).and_then(|s| s.parse().ok());
    let mut reg: RegisterConfig = CalibrateConfig::default().register;
    if let Ok(j) = std::env::var("DEPTHCAL_REG_JSON") {
        let mut v = serde_json::to_value(&reg).unwrap();
        let patch: serde_json::Value = serde_json::from_str(&j).expect("DEPTHCAL_REG_JSON");
        merge(&mut v, &patch);
        reg = serde_json::from_value(v).unwrap();
    }
    let (mut rs, mut ts, mut ws) = (Vec::new(), Vec::new(), Vec::new());
    for seed in first..first + n {
        let base: SimConfig = std::env::var("DEPTHCAL_SIM_JSON")
            .ok()
            .map(|j| serde_json::from_str(&j).expect("DEPTHCAL_SIM_JSON is a SimConfig"))
            .unwrap_or_default();
        let mut cfg = SimConfig { seed, ..base };
        cfg.color = false;
        if let Some(o) = overlap {
            cfg.overlap = o;
        }
        let dir = std::env::temp_dir().join(format!("depthcal-refine-{seed}"));
        let _ = std::fs::remove_dir_all(&dir);
        simulate_cell(&cfg, &dir, &|_| {}).unwrap();
        let cell = Cell::open(&dir).unwrap();
        let gt = GroundTruth::read(&dir)
            .unwrap()
            .unwrap()
            .t_base1_base2
            .unwrap();
        let mut fcfg = CalibrateConfig::default().fuse;
        if let Ok(j) = std::env::var("DEPTHCAL_FUSE_JSON") {
            let mut v = serde_json::to_value(&fcfg).unwrap();
            merge(
                &mut v,
                &serde_json::from_str(&j).expect("DEPTHCAL_FUSE_JSON"),
            );
            fcfg = serde_json::from_value(v).unwrap();
        }
        let c1 = fuse_robot(&cell.robots[0], &fcfg, &|_| {}).unwrap().cloud;
        let c2 = fuse_robot(&cell.robots[1], &fcfg, &|_| {}).unwrap().cloud;
        if let Ok(d) = std::env::var("DEPTHCAL_DUMP") {
            let d = std::path::Path::new(&d).join(format!("s{seed}"));
            std::fs::create_dir_all(&d).unwrap();
            depthcal::io::write_cloud(d.join("ref.ply"), &c1).unwrap();
            depthcal::io::write_cloud(d.join("other.ply"), &c2).unwrap();
            depthcal::io::write_matrix_file(d.join("truth.txt"), &gt).unwrap();
        }
        let t0 = std::time::Instant::now();
        let r = register(&c2, &c1, Some(&gt), &reg).unwrap();
        let (er, et) = pose_error(&r.transform, &gt);
        let centre = c2
            .points
            .iter()
            .fold(Point3::origin(), |s: Point3<f64>, p| {
                s + nalgebra::Vector3::new(p[0] as f64, p[1] as f64, p[2] as f64)
            })
            / c2.len() as f64;
        let ew = (r.transform * centre - gt * centre).norm();
        let d = r.transform.translation.vector - gt.translation.vector;
        let w = (r.transform.rotation * gt.rotation.inverse()).scaled_axis()
            * (180.0 / std::f64::consts::PI);
        println!(
            "seed {seed:3}: {er:.4} deg  {:.3} mm  at centre {:.3} mm  dt [{:.2} {:.2} {:.2}] mm  rot [{:.3} {:.3} {:.3}]  points {}/{}  overlap {:.2}  {:.0} ms",
            et * 1e3, ew * 1e3, d.x * 1e3, d.y * 1e3, d.z * 1e3, w.x, w.y, w.z, c1.len(), c2.len(), r.overlap,
            t0.elapsed().as_secs_f64() * 1e3
        );
        rs.push(er);
        ts.push(et * 1e3);
        ws.push(ew * 1e3);
        let _ = std::fs::remove_dir_all(&dir);
    }
    let st = |v: &mut Vec<f64>| {
        v.sort_by(|a, b| a.total_cmp(b));
        (v[v.len() / 2], *v.last().unwrap())
    };
    let (a1, b1) = st(&mut rs);
    let (a2, b2) = st(&mut ts);
    let (a3, b3) = st(&mut ws);
    println!("median {a1:.4} deg {a2:.3} mm (centre {a3:.3}); worst {b1:.4} deg {b2:.3} mm (centre {b3:.3})");
}

fn merge(a: &mut serde_json::Value, b: &serde_json::Value) {
    match (a, b) {
        (serde_json::Value::Object(a), serde_json::Value::Object(b)) => {
            for (k, v) in b {
                merge(a.entry(k.clone()).or_insert(serde_json::Value::Null), v);
            }
        }
        (a, b) => *a = b.clone(),
    }
}
