//! Keypoints of a cell robot's colour images lifted to 3D in its base with the aligned depth, and matched
//! between two robots into 3D-3D correspondences for [`crate::calibration::feature_init`].
//!
//! Each robot's keypoints of all its frames are pooled. Because one place on the table shows in many
//! frames, the ratio test compares the best match with the best match at *another place* (a keypoint
//! farther than `place_radius_m` in the robot's base from the best one), and the cross-check asks the
//! best match's own best match to be at the query's place.

use super::features::{
    detect_features, knn_match, Descriptors, FeatureConfig, FeatureKind, Features,
};
use super::frames::load_aligned_frame;
use crate::calibration::feature_init::{
    FeatureCorrespondence, FeatureInitializer, FeatureMethodConfig,
};
use crate::camera::DepthImage;
use crate::cell::CellRobot;
use crate::error::{Error, Result};
use nalgebra::{Point2, Point3};
use rayon::prelude::*;

/// One robot's pooled keypoints with their 3D points.
pub struct LiftedKeypoints {
    /// Each keypoint's point in the robot's base, metres.
    pub points: Vec<Point3<f64>>,
    /// Each keypoint's frame (index into the robot's frames).
    pub frame: Vec<usize>,
    /// Each keypoint's pixel.
    pub pixels: Vec<Point2<f64>>,
    /// Their descriptors, in the same order.
    pub descriptors: Descriptors,
    /// Keypoints detected before lifting (all frames).
    pub detected: usize,
}

/// The depth at pixel `p` if its 3x3 neighbourhood is complete and flat enough (see
/// [`FeatureMethodConfig::max_depth_step_m`]): the median of the nine, metres.
fn depth_at(depth: &DepthImage, scale: f64, p: &Point2<f64>, max_step_m: f64) -> Option<f64> {
    let (u, v) = (p.x.round() as i64, p.y.round() as i64);
    if u < 1 || v < 1 || u + 1 >= depth.width as i64 || v + 1 >= depth.height as i64 {
        return None;
    }
    let mut z = [0f64; 9];
    let mut k = 0;
    for dv in -1..=1 {
        for du in -1..=1 {
            let raw = depth.get((u + du) as u32, (v + dv) as u32);
            if raw == 0 {
                return None;
            }
            z[k] = raw as f64 * scale;
            k += 1;
        }
    }
    z.sort_by(f64::total_cmp);
    (z[8] - z[0] <= max_step_m.max(0.02 * z[4])).then_some(z[4])
}

/// Detects keypoints in every frame of `robot` (in parallel) and lifts those with clean depth into its
/// base. Returns them pooled in frame order, and a note per frame that gave none.
pub fn lift_robot_keypoints(
    robot: &CellRobot,
    cfg: &FeatureMethodConfig,
) -> Result<(LiftedKeypoints, Vec<String>)> {
    let kind: FeatureKind = cfg
        .detector
        .parse()
        .map_err(|e: String| Error::InvalidInput(format!("features method, detector: {e}")))?;
    let fcfg = FeatureConfig {
        kind,
        max_features: cfg.max_per_image,
        ..FeatureConfig::default()
    };
    type One = (Features, Vec<usize>, Vec<Point3<f64>>);
    let per: Vec<Result<One>> = (0..robot.frames.len())
        .into_par_iter()
        .map(|i| -> Result<One> {
            let (grey, depth) = load_aligned_frame(robot, i, "features")?;
            let f = detect_features(&grey, &fcfg)?;
            let t = robot.t_base_cam(i);
            let mut keep = Vec::new();
            let mut pts = Vec::new();
            for (k, kp) in f.keypoints.iter().enumerate() {
                let Some(z) = depth_at(
                    &depth,
                    robot.intrinsics.depth_scale,
                    &kp.pt,
                    cfg.max_depth_step_m,
                ) else {
                    continue;
                };
                let c = robot.intrinsics.deproject([kp.pt.x, kp.pt.y], z);
                keep.push(k);
                pts.push(t * Point3::new(c[0], c[1], c[2]));
            }
            Ok((f, keep, pts))
        })
        .collect();
    let mut out: Option<LiftedKeypoints> = None;
    let mut notes = Vec::new();
    for (i, r) in per.into_iter().enumerate() {
        let (f, keep, pts) = r?;
        let fid = &robot.frames[i].id;
        if keep.is_empty() {
            notes.push(if f.keypoints.is_empty() {
                format!("frame {fid}: no keypoints in the colour image")
            } else {
                format!(
                    "frame {fid}: none of its {} keypoints has clean depth under it (missing depth or a depth edge)",
                    f.keypoints.len()
                )
            });
        }
        let d = f.descriptors.select(&keep);
        let pixels: Vec<Point2<f64>> = keep.iter().map(|&k| f.keypoints[k].pt).collect();
        match &mut out {
            None => {
                out = Some(LiftedKeypoints {
                    frame: vec![i; pts.len()],
                    points: pts,
                    pixels,
                    descriptors: d,
                    detected: f.keypoints.len(),
                })
            }
            Some(o) => {
                o.frame.extend(std::iter::repeat_n(i, pts.len()));
                o.points.extend(pts);
                o.pixels.extend(pixels);
                o.descriptors.append(&d)?;
                o.detected += f.keypoints.len();
            }
        }
    }
    let out =
        out.ok_or_else(|| Error::InvalidInput(format!("robot {:?} has no frames", robot.name)))?;
    if out.points.is_empty() {
        return Err(Error::InvalidInput(format!(
            "robot {:?}: no keypoint of its {} colour images has depth under it ({} detected):\n  {}",
            robot.name,
            robot.frames.len(),
            out.detected,
            notes.join("\n  ")
        )));
    }
    Ok((out, notes))
}

/// For each query row, the best train row and whether it passes the place-aware ratio test.
fn best_places(
    knn: &[Vec<(usize, f32)>],
    train_points: &[Point3<f64>],
    place_r: f64,
    ratio: f64,
) -> Vec<Option<usize>> {
    knn.iter()
        .map(|nn| {
            let &(best, d0) = nn.first()?;
            let second = nn
                .iter()
                .skip(1)
                .find(|(j, _)| (train_points[*j] - train_points[best]).norm() > place_r);
            match second {
                Some(&(_, d1)) if (d0 as f64) >= ratio * d1 as f64 => None,
                _ => Some(best),
            }
        })
        .collect()
}

/// Matches the other robot's keypoints to the reference robot's (place-aware ratio test and cross-check)
/// into 3D correspondences base2 → base1.
pub fn feature_correspondences(
    reference: &CellRobot,
    other: &CellRobot,
    cfg: &FeatureMethodConfig,
) -> Result<(FeatureInitializer, Vec<String>)> {
    let ((a, mut notes), (b, notes_b)) = {
        let (ra, rb) = rayon::join(
            || lift_robot_keypoints(reference, cfg),
            || lift_robot_keypoints(other, cfg),
        );
        (ra?, rb?)
    };
    let tag = |r: &CellRobot, v: Vec<String>| -> Vec<String> {
        v.into_iter()
            .map(|n| format!("robot {:?}: {n}", r.name))
            .collect()
    };
    notes = tag(reference, notes);
    notes.extend(tag(other, notes_b));
    let k = cfg.knn.max(2);
    let forward = knn_match(&b.descriptors, &a.descriptors, k)?;
    let best_ab = best_places(&forward, &a.points, cfg.place_radius_m, cfg.ratio);
    let best_ba = if cfg.cross_check {
        let backward = knn_match(&a.descriptors, &b.descriptors, k)?;
        Some(best_places(&backward, &b.points, cfg.place_radius_m, 1.0))
    } else {
        None
    };
    let mut correspondences = Vec::new();
    for (i, m) in best_ab.iter().enumerate() {
        let Some(j) = *m else { continue };
        if let Some(back) = &best_ba {
            match back[j] {
                Some(i2) if (b.points[i2] - b.points[i]).norm() <= cfg.place_radius_m => {}
                _ => continue,
            }
        }
        correspondences.push(FeatureCorrespondence {
            other: b.points[i],
            reference: a.points[j],
            other_frame: other.frames[b.frame[i]].id.clone(),
            reference_frame: reference.frames[a.frame[j]].id.clone(),
        });
    }
    let summary = format!(
        "{} keypoints: {} ({} with depth) of {} and {} ({} with depth) of {}, {} matches",
        cfg.detector,
        a.detected,
        a.points.len(),
        reference.name,
        b.detected,
        b.points.len(),
        other.name,
        correspondences.len()
    );
    if correspondences.len() < 3 {
        return Err(Error::InvalidInput(format!(
            "features: only {} keypoint matches between the robots' images ({summary}); the method needs \
             textured surfaces that both robots see",
            correspondences.len()
        )));
    }
    Ok((
        FeatureInitializer {
            correspondences,
            ransac: cfg.ransac.clone(),
            summary,
        },
        notes,
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn depth_needs_a_clean_neighbourhood() {
        let mut d = DepthImage::zeros(10, 10);
        d.data.iter_mut().for_each(|v| *v = 500);
        let p = Point2::new(4.2, 4.8);
        assert_eq!(depth_at(&d, 0.001, &p, 0.01), Some(0.5));
        d.data[4 * 10 + 4] = 0;
        assert_eq!(depth_at(&d, 0.001, &p, 0.01), None);
        d.data[4 * 10 + 4] = 560;
        assert_eq!(depth_at(&d, 0.001, &p, 0.01), None, "a depth edge");
        d.data[4 * 10 + 4] = 505;
        assert!(depth_at(&d, 0.001, &p, 0.01).is_some());
        assert_eq!(depth_at(&d, 0.001, &Point2::new(0.2, 4.0), 0.01), None);
    }

    #[test]
    fn ratio_test_compares_places() {
        let pts = vec![
            Point3::new(0.0, 0.0, 0.0),
            Point3::new(0.005, 0.0, 0.0),
            Point3::new(0.5, 0.0, 0.0),
        ];
        // Best two at the same place, the third elsewhere and far in descriptor space: accepted.
        let knn = vec![
            vec![(0, 1.0), (1, 1.05), (2, 3.0)],
            vec![(0, 1.0), (2, 1.1)],
        ];
        assert_eq!(best_places(&knn, &pts, 0.015, 0.8), vec![Some(0), None]);
    }
}
