#![no_main]
//! Registration of tiny clouds built from the bytes, with a small configuration: no panic, and a result is
//! a finite rigid transform.
use depthcal::registration::{register, RegisterConfig};
use depthcal::PointCloud;
use libfuzzer_sys::fuzz_target;
use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};

fuzz_target!(|data: &[u8]| {
    if data.len() < 8 {
        return;
    }
    let (head, body) = data.split_at(8);
    let n = 10 + head[0] as usize % 50;
    let scale = [1e-3f32, 1e-2, 0.1, 1.0, 10.0, 1e3][head[1] as usize % 6];
    let byte = |i: usize| -> u8 {
        if body.is_empty() {
            (i * 37 % 251) as u8
        } else {
            body[i % body.len()] ^ (i / body.len().max(1)) as u8
        }
    };
    let mut src: Vec<[f32; 3]> = (0..n)
        .map(|i| {
            let v = |k: usize| {
                i16::from_le_bytes([byte(6 * i + 2 * k), byte(6 * i + 2 * k + 1)]) as f32 / 32768.0
                    * scale
            };
            [v(0), v(1), v(2)]
        })
        .collect();
    if head[2] & 1 == 1 {
        src[0] = [f32::NAN, 0.0, 0.0];
    }
    if head[2] & 2 == 2 {
        // Degenerate: everything on a line.
        for p in &mut src {
            p[1] = 0.0;
            p[2] = 0.0;
        }
    }
    let angle = head[3] as f64 / 255.0 * std::f64::consts::PI;
    let axis = Vector3::new(head[4] as f64 - 127.5, head[5] as f64 - 127.5, 1.0).normalize();
    let truth = Isometry3::from_parts(
        Translation3::new(head[6] as f64 / 255.0 * scale as f64, 0.0, 0.0),
        UnitQuaternion::from_scaled_axis(axis * angle),
    );
    let keep = n - (head[7] as usize % (n / 2));
    let tgt: Vec<[f32; 3]> = src[..keep]
        .iter()
        .map(|p| {
            let q = truth * Point3::new(p[0] as f64, p[1] as f64, p[2] as f64);
            [q.x as f32, q.y as f32, q.z as f32]
        })
        .collect();
    let mut cfg = RegisterConfig::default();
    cfg.ransac.max_iterations = 300;
    cfg.icp.max_iterations = 8;
    cfg.icp_levels = 1;
    cfg.seed = head[0] as u64;
    let init = (head[2] & 4 == 4).then(Isometry3::identity);
    let (s, t) = (PointCloud::from_points(src), PointCloud::from_points(tgt));
    if let Ok(r) = register(&s, &t, init.as_ref(), &cfg) {
        let m = r.transform.to_homogeneous();
        assert!(m.iter().all(|v| v.is_finite()), "NaN in the transform: {m}");
        assert!(!r.fitness.is_nan(), "NaN fitness");
    }
});
