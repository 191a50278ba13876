//! The markers a cell robot's colour images show: per frame each marker's `T_cam_marker` by planar PnP on
//! its corners, refined with the aligned depth ([`crate::calibration::marker_init::refine_with_depth`]).

use super::frames::load_aligned_frame;
use super::markers::{detect_markers, MarkerConfig};
use super::pnp::pose_of_points;
use crate::calibration::marker_init::{refine_with_depth, MarkerMethodConfig, MarkerSighting};
use crate::cell::{CellRobot, MarkerTarget};
use crate::error::{Error, Result};
use nalgebra::{Point2, Point3};
use rayon::prelude::*;

/// What one robot's frames showed: the sightings (frame order, then id), and one line per frame or marker
/// that was seen but not used (to warn about).
pub struct RobotSightings {
    /// The usable sightings.
    pub sightings: Vec<MarkerSighting>,
    /// Frames without any marker of the target and sightings that were dropped, with the reason.
    pub notes: Vec<String>,
}

/// Finds `target`'s markers in every frame of `robot` (in parallel) and solves their poses. Errors when a
/// frame's images are missing or not aligned (naming the frame); no marker at all is not an error here.
pub fn robot_marker_sightings(
    robot: &CellRobot,
    target: &MarkerTarget,
    cfg: &MarkerMethodConfig,
) -> Result<RobotSightings> {
    let dictionary = target
        .dictionary
        .parse()
        .map_err(|e: Error| Error::InvalidInput(format!("[markers] dictionary: {e}")))?;
    let detect = MarkerConfig {
        dictionary,
        ..MarkerConfig::default()
    };
    type Frame = (Vec<MarkerSighting>, Vec<String>);
    let per: Vec<Result<Frame>> = (0..robot.frames.len())
        .into_par_iter()
        .map(|i| -> Result<Frame> {
            let f = &robot.frames[i];
            let (grey, depth) = load_aligned_frame(robot, i, "marker")?;
            let found = detect_markers(&grey, &detect)?;
            let mut out = Vec::new();
            let mut notes = Vec::new();
            for d in found.iter().filter(|d| target.uses(d.id)) {
                let size = target.size_of(d.id);
                let object: [Point3<f64>; 4] = d.object_corners(size);
                let corners: [Point2<f64>; 4] = d.corners;
                let pose = match pose_of_points(&corners, &object, &robot.intrinsics) {
                    Ok(p) if p.rms_px <= cfg.max_rms_px => p,
                    Ok(p) => {
                        notes.push(format!(
                            "frame {}: marker {} dropped, PnP RMS {:.2} px > {:.2} px",
                            f.id, d.id, p.rms_px, cfg.max_rms_px
                        ));
                        continue;
                    }
                    Err(e) => {
                        notes.push(format!(
                            "frame {}: marker {} dropped, PnP failed: {e}",
                            f.id, d.id
                        ));
                        continue;
                    }
                };
                let (t, fit) = if cfg.use_depth {
                    match refine_with_depth(
                        &corners,
                        &object,
                        &pose.t_cam_board,
                        &robot.intrinsics,
                        &depth,
                        &cfg.depth,
                    ) {
                        Some(Ok((t, fit))) => (t, Some(fit)),
                        Some(Err(reason)) => {
                            notes
                                .push(format!("frame {}: marker {} dropped, {reason}", f.id, d.id));
                            continue;
                        }
                        None => {
                            notes.push(format!(
                                "frame {}: marker {}: no usable depth under it, PnP pose alone",
                                f.id, d.id
                            ));
                            (pose.t_cam_board, None)
                        }
                    }
                } else {
                    (pose.t_cam_board, None)
                };
                out.push(MarkerSighting {
                    frame: f.id.clone(),
                    id: d.id,
                    t_cam_marker: t,
                    rms_px: pose.rms_px,
                    depth: fit,
                });
            }
            if out.is_empty() && notes.is_empty() {
                notes.push(format!(
                    "frame {}: no marker of {} found",
                    f.id, target.dictionary
                ));
            }
            Ok((out, notes))
        })
        .collect();
    let mut all = RobotSightings {
        sightings: Vec::new(),
        notes: Vec::new(),
    };
    for r in per {
        let (s, n) = r?;
        all.sightings.extend(s);
        all.notes.extend(n);
    }
    Ok(all)
}
