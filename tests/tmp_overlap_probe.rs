use depthcal::fusion::{fuse_frames, CropBox, FrameInput, FuseConfig};
use depthcal::index::KdIndex;
use depthcal::sim::{NoiseLevel, SimCell, SimConfig};

#[test]
fn probe() {
    for overlap in [0.0, 0.3, 0.5, 0.7, 1.0] {
        let mut fr = Vec::new();
        for seed in [8u64, 9] {
            let cfg = SimConfig {
                seed,
                frames: 12,
                noise_level: NoiseLevel::None,
                overlap,
                color: false,
                ..Default::default()
            };
            let cell = SimCell::generate(&cfg).unwrap();
            let ws = cell.workspace_base1();
            let t = cell.t_base1_base2();
            let mut clouds = Vec::new();
            for r in 0..2 {
                let frames = cell.render_robot(r).unwrap();
                let inputs: Vec<FrameInput> = frames
                    .iter()
                    .enumerate()
                    .map(|(k, f)| FrameInput {
                        depth: &f.depth,
                        t_base_cam: if r == 0 {
                            cell.robots[r].t_base_cam(k)
                        } else {
                            t * cell.robots[r].t_base_cam(k)
                        },
                    })
                    .collect();
                let fc = FuseConfig {
                    crop: Some(CropBox {
                        min: ws.min,
                        max: ws.max,
                    }),
                    voxel_size_m: Some(0.003),
                    outlier: None,
                    normals: None,
                    ..Default::default()
                };
                clouds.push(fuse_frames(&inputs, &cell.robots[r].camera.intrinsics, &fc).unwrap());
            }
            let idx = KdIndex::new(&clouds[0].cloud.points);
            let near = clouds[1]
                .cloud
                .points
                .iter()
                .filter(|p| {
                    idx.nearest(p)
                        .map(|(_, d2)| d2 < 0.006f32 * 0.006)
                        .unwrap_or(false)
                })
                .count();
            let idx2 = KdIndex::new(&clouds[1].cloud.points);
            let near2 = clouds[0]
                .cloud
                .points
                .iter()
                .filter(|p| {
                    idx2.nearest(p)
                        .map(|(_, d2)| d2 < 0.006f32 * 0.006)
                        .unwrap_or(false)
                })
                .count();
            fr.push((
                near as f64 / clouds[1].cloud.len() as f64,
                near2 as f64 / clouds[0].cloud.len() as f64,
            ));
        }
        println!("overlap {overlap}: shared {:?}", fr);
    }
}
