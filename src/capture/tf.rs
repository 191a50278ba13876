//! Robot poses from a recording's TF: a small transform tree built from `/tf` and `/tf_static` messages
//! (`tf2_msgs/TFMessage`), looked up between two frames at a time, as `tf2` does.
//!
//! * Each message gives `T_parent_child` (metres, unit quaternion) at its stamp: `p_parent = T · p_child`.
//!   Static transforms (`/tf_static`) hold at every time; dynamic ones (`/tf`) are samples in time.
//! * [`TfBuffer::lookup`] chains the edges between two frames through their common ancestor (frames with a
//!   leading `/`, as old ROS1 `tf` wrote them, are the same frames without it). Each dynamic edge is
//!   interpolated at the time asked for between its two nearest samples: linearly in translation, by slerp in
//!   rotation. Nothing is extrapolated: a time before the first or after the last sample of an edge takes
//!   that sample only when it is within [`TfConfig::tolerance_s`], and two samples farther apart than
//!   [`TfConfig::max_gap_s`] are not interpolated across (the robot may have moved any way between them).
//! * [`PoseRows::from_tf`] gives one pose row `T_base_ee` per depth frame at its stamp, for
//!   [`crate::capture::import_recording`].
//!
//! Errors name the frame that is missing, the edge whose samples do not cover the time, and the gap.

use super::{PoseRows, StreamFrames};
use crate::error::{Error, Result};
use crate::io::poses::{PoseFormat, PoseRecord};
use nalgebra::{Isometry3, Translation3};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::Path;

/// How TF lookups treat time.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TfConfig {
    /// How far before the first or after the last sample of a dynamic edge a lookup may be and still take
    /// that sample, seconds (default 0.02; nothing is extrapolated).
    pub tolerance_s: f64,
    /// The longest interval between two samples of a dynamic edge that is interpolated across, seconds
    /// (default 0.25: publishers down to 4 Hz).
    pub max_gap_s: f64,
}

impl Default for TfConfig {
    fn default() -> Self {
        TfConfig {
            tolerance_s: 0.02,
            max_gap_s: 0.25,
        }
    }
}

impl TfConfig {
    /// Checks the ranges; the error names the field.
    pub fn validate(&self) -> Result<()> {
        crate::error::check::non_negative("tf.tolerance_s", self.tolerance_s)?;
        crate::error::check::positive("tf.max_gap_s", self.max_gap_s)
    }
}

/// A frame id as TF compares them: without a leading `/`.
pub fn frame_name(id: &str) -> &str {
    id.trim().trim_start_matches('/')
}

/// The edge from a parent frame to one child frame.
#[derive(Clone, Debug, Default)]
struct Edge {
    parent: String,
    /// Other parents the child was also published under (an inconsistent tree), reported on lookup.
    other_parents: Vec<String>,
    /// The static transform, if published on `/tf_static`.
    fixed: Option<Isometry3<f64>>,
    /// Dynamic samples `(t_s, T_parent_child)`, sorted by time after [`TfBuffer::finish`].
    samples: Vec<(f64, Isometry3<f64>)>,
}

/// What [`TfBuffer::edges`] lists of one edge.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct TfEdge {
    /// The parent frame.
    pub parent: String,
    /// The child frame.
    pub child: String,
    /// Published on `/tf_static`.
    pub is_static: bool,
    /// Dynamic samples on `/tf`.
    pub samples: usize,
    /// Their first and last stamps, seconds.
    pub span_s: Option<(f64, f64)>,
}

/// The transforms of a recording, by child frame.
#[derive(Clone, Debug, Default)]
pub struct TfBuffer {
    edges: BTreeMap<String, Edge>,
}

/// `a` moved toward `b` by `f` in [0, 1]: translation lerp, rotation slerp.
fn interpolate(a: &Isometry3<f64>, b: &Isometry3<f64>, f: f64) -> Isometry3<f64> {
    let t = a.translation.vector.lerp(&b.translation.vector, f);
    let r = a
        .rotation
        .try_slerp(&b.rotation, f, 1e-12)
        .unwrap_or(if f < 0.5 { a.rotation } else { b.rotation });
    Isometry3::from_parts(Translation3::from(t), r)
}

fn ms(s: f64) -> String {
    format!("{:.1} ms", s * 1e3)
}

impl TfBuffer {
    /// An empty buffer.
    pub fn new() -> Self {
        Self::default()
    }

    /// Adds `T_parent_child` at `t_s` (seconds), static or dynamic.
    pub fn insert(
        &mut self,
        parent: &str,
        child: &str,
        t_s: f64,
        t_parent_child: Isometry3<f64>,
        is_static: bool,
    ) {
        let (parent, child) = (frame_name(parent), frame_name(child));
        let e = self.edges.entry(child.to_string()).or_insert_with(|| Edge {
            parent: parent.to_string(),
            ..Edge::default()
        });
        if e.parent != parent {
            if !e.other_parents.iter().any(|p| p == parent) {
                e.other_parents.push(parent.to_string());
            }
            return;
        }
        if is_static {
            e.fixed = Some(t_parent_child);
        } else {
            e.samples.push((t_s, t_parent_child));
        }
    }

    /// Sorts every edge's samples by time (the last of equal stamps wins). Call after the last
    /// [`TfBuffer::insert`].
    pub fn finish(&mut self) {
        for e in self.edges.values_mut() {
            // A stable sort keeps equal stamps in arrival order; the later one is kept.
            e.samples.sort_by(|a, b| a.0.total_cmp(&b.0));
            let mut out: Vec<(f64, Isometry3<f64>)> = Vec::with_capacity(e.samples.len());
            for s in e.samples.drain(..) {
                match out.last_mut() {
                    Some(l) if l.0 == s.0 => *l = s,
                    _ => out.push(s),
                }
            }
            e.samples = out;
        }
    }

    /// True when nothing was inserted.
    pub fn is_empty(&self) -> bool {
        self.edges.is_empty()
    }

    /// Every frame of the tree, sorted.
    pub fn frames(&self) -> Vec<String> {
        let mut v: Vec<String> = self
            .edges
            .iter()
            .flat_map(|(c, e)| [c.clone(), e.parent.clone()])
            .collect();
        v.sort();
        v.dedup();
        v
    }

    /// The edges, by child frame.
    pub fn edges(&self) -> Vec<TfEdge> {
        self.edges
            .iter()
            .map(|(c, e)| TfEdge {
                parent: e.parent.clone(),
                child: c.clone(),
                is_static: e.fixed.is_some(),
                samples: e.samples.len(),
                span_s: e
                    .samples
                    .first()
                    .zip(e.samples.last())
                    .map(|(a, b)| (a.0, b.0)),
            })
            .collect()
    }

    /// `T_parent_child` of the edge above `child` at `t_s`.
    fn edge_at(
        &self,
        child: &str,
        e: &Edge,
        t_s: f64,
        cfg: &TfConfig,
    ) -> std::result::Result<Isometry3<f64>, String> {
        let name = format!("{} -> {child}", e.parent);
        if let Some(p) = e.other_parents.first() {
            return Err(format!(
                "frame {child:?} is published as a child of both {:?} and {p:?}: the TF tree is inconsistent",
                e.parent
            ));
        }
        match (e.fixed, e.samples.is_empty()) {
            (Some(_), false) => {
                return Err(format!(
                    "{name} is published both on /tf_static and on /tf: depthcal cannot tell which holds"
                ))
            }
            (Some(t), true) => return Ok(t),
            _ => {}
        }
        let s = &e.samples;
        let (first, last) = (s[0].0, s[s.len() - 1].0);
        let span = format!(
            "its {} /tf samples span t = {first:.6} .. {last:.6} s",
            s.len()
        );
        if t_s < first || t_s > last {
            let (edge_t, d) = if t_s < first {
                (s[0], first - t_s)
            } else {
                (s[s.len() - 1], t_s - last)
            };
            if d <= cfg.tolerance_s {
                return Ok(edge_t.1);
            }
            return Err(format!(
                "no /tf sample of {name} at t = {t_s:.6} s: it is {} {} the {} sample ({span}; tolerance {}, \
                 no extrapolation)",
                ms(d),
                if t_s < first { "before" } else { "after" },
                if t_s < first { "first" } else { "last" },
                ms(cfg.tolerance_s)
            ));
        }
        let i = s.partition_point(|x| x.0 <= t_s);
        // s[i - 1].0 <= t_s, and t_s <= last: i - 1 is the sample at or before t_s.
        let (a, b) = (s[i - 1], s.get(i).copied().unwrap_or(s[i - 1]));
        if a.0 == t_s || b.0 == a.0 {
            return Ok(a.1);
        }
        if b.0 - a.0 > cfg.max_gap_s {
            return Err(format!(
                "the /tf samples of {name} around t = {t_s:.6} s are {} apart (at {:.6} and {:.6} s), more than the \
                 largest gap interpolated across ({})",
                ms(b.0 - a.0),
                a.0,
                b.0,
                ms(cfg.max_gap_s)
            ));
        }
        Ok(interpolate(&a.1, &b.1, (t_s - a.0) / (b.0 - a.0)))
    }

    /// The frames from `frame` up to its root, `frame` first.
    fn ancestry(&self, frame: &str) -> Vec<String> {
        let mut chain = vec![frame.to_string()];
        let mut f = frame.to_string();
        while let Some(e) = self.edges.get(&f) {
            if chain.contains(&e.parent) || chain.len() > self.edges.len() {
                break;
            }
            chain.push(e.parent.clone());
            f = e.parent.clone();
        }
        chain
    }

    /// `T_ancestor_frame` at `t_s`, chaining the edges from `frame` up to `ancestor`.
    fn up_to(
        &self,
        frame: &str,
        ancestor: &str,
        t_s: f64,
        cfg: &TfConfig,
    ) -> std::result::Result<Isometry3<f64>, String> {
        let mut t = Isometry3::identity();
        let mut f = frame.to_string();
        while f != ancestor {
            let e = self.edges.get(&f).expect("on the ancestry");
            t = self.edge_at(&f, e, t_s, cfg)? * t;
            f = e.parent.clone();
        }
        Ok(t)
    }

    /// `T_target_source` at `t_s` seconds: maps coordinates in frame `source` into frame `target` (e.g.
    /// `lookup("base_link", "tool0", t)` is `T_base_ee`). The message says which frame is missing, which
    /// frames are not connected, or which edge does not cover `t_s`.
    pub fn lookup(
        &self,
        target: &str,
        source: &str,
        t_s: f64,
        cfg: &TfConfig,
    ) -> std::result::Result<Isometry3<f64>, String> {
        let (target, source) = (frame_name(target), frame_name(source));
        let known = self.frames();
        for f in [target, source] {
            if !known.iter().any(|k| k == f) {
                return Err(format!(
                    "frame {f:?} is not in the recording's /tf or /tf_static (its frames: {})",
                    if known.is_empty() {
                        "none".to_string()
                    } else {
                        known.join(", ")
                    }
                ));
            }
        }
        let up_t = self.ancestry(target);
        let up_s = self.ancestry(source);
        let Some(common) = up_s.iter().find(|f| up_t.contains(f)) else {
            return Err(format!(
                "frames {target:?} and {source:?} are not connected in the TF tree ({target:?} hangs from {:?}, \
                 {source:?} from {:?})",
                up_t.last().expect("non-empty"),
                up_s.last().expect("non-empty")
            ));
        };
        let t_common_source = self.up_to(source, common, t_s, cfg)?;
        let t_common_target = self.up_to(target, common, t_s, cfg)?;
        Ok(t_common_target.inverse() * t_common_source)
    }
}

/// Where robot poses come from in a TF tree: `T_base_ee` is the transform from `flange` into `base`.
#[derive(Clone, Copy, Debug)]
pub struct TfPoses<'a> {
    /// The transforms.
    pub buffer: &'a TfBuffer,
    /// The robot's base frame.
    pub base: &'a str,
    /// The flange (end-effector) frame.
    pub flange: &'a str,
    /// How lookups treat time.
    pub cfg: TfConfig,
}

impl PoseRows {
    /// One pose row per depth frame of `depth`, in its order: `T_base_ee` from `tf` at the frame's stamp,
    /// frame id `ids[k]`, and the stamp as the row's time; `format` is the pose format recorded for the rows
    /// (a new robot's pose file). `recording` names the file in errors, which name the depth frame and the TF
    /// problem.
    pub fn from_tf(
        tf: &TfPoses,
        depth: &StreamFrames,
        ids: &[String],
        recording: &Path,
        format: PoseFormat,
    ) -> Result<Self> {
        let TfPoses {
            buffer,
            base,
            flange,
            cfg,
        } = *tf;
        let cfg = &cfg;
        cfg.validate()?;
        if buffer.is_empty() {
            return Err(Error::format(
                recording,
                "no tf2_msgs/TFMessage on /tf or /tf_static: the robot poses cannot be taken from TF",
            ));
        }
        if ids.len() != depth.frames.len() {
            return Err(Error::InvalidInput(format!(
                "{} frame ids for {} depth frames",
                ids.len(),
                depth.frames.len()
            )));
        }
        let mut records = Vec::with_capacity(ids.len());
        let mut times = Vec::with_capacity(ids.len());
        let mut origins = Vec::with_capacity(ids.len());
        for (k, (f, id)) in depth.frames.iter().zip(ids).enumerate() {
            let pose = buffer.lookup(base, flange, f.t_s, cfg).map_err(|m| {
                Error::format(
                    recording,
                    format!(
                        "depth frame {} of {} (t = {:.6} s): T_{}_{} from TF: {m}",
                        k + 1,
                        depth.name,
                        f.t_s,
                        frame_name(base),
                        frame_name(flange)
                    ),
                )
            })?;
            records.push(PoseRecord {
                frame: id.clone(),
                pose,
                line: 0,
            });
            times.push(f.t_s);
            origins.push(format!(
                "{}: TF {} -> {} at t = {:.6} s",
                recording.display(),
                frame_name(base),
                frame_name(flange),
                f.t_s
            ));
        }
        Ok(PoseRows {
            path: recording.to_path_buf(),
            format,
            records,
            times_s: Some(times),
            origins: Some(origins),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{UnitQuaternion, Vector3};

    fn iso(x: f64, y: f64, z: f64, axis: Vector3<f64>, angle: f64) -> Isometry3<f64> {
        Isometry3::from_parts(
            Translation3::new(x, y, z),
            UnitQuaternion::from_axis_angle(&nalgebra::Unit::new_normalize(axis), angle),
        )
    }

    #[test]
    fn chains_through_a_common_ancestor_and_interpolates() {
        let mut b = TfBuffer::new();
        let world_base = iso(1.0, 0.0, 0.0, Vector3::z(), 0.3);
        let world_cam = iso(0.0, 2.0, 1.0, Vector3::x(), -0.2);
        let l1 = |t: f64| iso(0.1 * t, 0.0, 0.5, Vector3::z(), 0.4 * t);
        let flange = iso(0.0, 0.0, 0.2, Vector3::y(), 0.1);
        b.insert("world", "base", 0.0, world_base, true);
        b.insert("/world", "camera", 5.0, world_cam, true);
        for t in [0.0, 0.1, 0.2] {
            b.insert("base", "link1", t, l1(t), false);
        }
        b.insert("link1", "flange", 0.0, flange, true);
        b.finish();
        let cfg = TfConfig::default();
        // At a sample: exactly the chain.
        let t = b.lookup("base", "flange", 0.1, &cfg).unwrap();
        let want = l1(0.1) * flange;
        assert!((t.to_matrix() - want.to_matrix()).abs().max() < 1e-12);
        // Between samples: the rotation about z interpolates linearly in angle, the translation in x.
        let t = b.lookup("/base", "flange", 0.15, &cfg).unwrap();
        let want = l1(0.15) * flange;
        assert!(
            (t.to_matrix() - want.to_matrix()).abs().max() < 1e-12,
            "{t} vs {want}"
        );
        // Through the common ancestor `world`: T_camera_flange = T_world_camera⁻¹ T_world_base T_base_flange.
        let t = b.lookup("camera", "flange", 0.05, &cfg).unwrap();
        let want = world_cam.inverse() * world_base * l1(0.05) * flange;
        assert!((t.to_matrix() - want.to_matrix()).abs().max() < 1e-12);
        // Just beyond the samples, within the tolerance: the end sample; beyond: an error naming the edge.
        let t = b.lookup("base", "flange", 0.21, &cfg).unwrap();
        assert!((t.to_matrix() - (l1(0.2) * flange).to_matrix()).abs().max() < 1e-12);
        let e = b.lookup("base", "flange", 0.3, &cfg).unwrap_err();
        assert!(
            e.contains("base -> link1") && e.contains("100.0 ms after the last"),
            "{e}"
        );
        let e = b.lookup("base", "flange", -0.05, &cfg).unwrap_err();
        assert!(e.contains("before the first"), "{e}");
    }

    #[test]
    fn missing_frames_gaps_and_inconsistent_trees_are_named() {
        let mut b = TfBuffer::new();
        b.insert("base", "link1", 0.0, Isometry3::identity(), false);
        b.insert("base", "link1", 1.0, Isometry3::identity(), false);
        b.insert("odd", "island", 0.0, Isometry3::identity(), true);
        b.insert("a", "twice", 0.0, Isometry3::identity(), true);
        b.insert("b", "twice", 0.0, Isometry3::identity(), true);
        b.finish();
        let cfg = TfConfig::default();
        let e = b.lookup("base", "tool0", 0.5, &cfg).unwrap_err();
        assert!(
            e.contains("\"tool0\"") && e.contains("base, island, link1"),
            "{e}"
        );
        let e = b.lookup("base", "island", 0.5, &cfg).unwrap_err();
        assert!(e.contains("not connected"), "{e}");
        let e = b.lookup("base", "link1", 0.5, &cfg).unwrap_err();
        assert!(
            e.contains("1000.0 ms apart") && e.contains("250.0 ms"),
            "{e}"
        );
        let wide = TfConfig {
            max_gap_s: 2.0,
            ..cfg
        };
        assert!(b.lookup("base", "link1", 0.5, &wide).is_ok());
        let e = b.lookup("a", "twice", 0.0, &cfg).unwrap_err();
        assert!(e.contains("both \"a\" and \"b\""), "{e}");
    }
}
