//! Whether a result can be trusted, and why not.
//!
//! A registration or calibration that is wrong but looks confident is the worst thing this tool can
//! produce. Each result carries a [`Trust`]: `trusted` is true only when every check passed; otherwise
//! `reasons` says which failed and `suggestions` what to try. The checks of a registration are here
//! ([`assess_registration`]); a calibration adds its own (priors, free space, each robot's own frames).

use crate::error::{Error, Result};
use crate::registration::pipeline::Registration;
use crate::registration::quality::{Degeneracy, WeakDirection};
use serde::{Deserialize, Serialize};

/// Thresholds of the quality gate.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TrustConfig {
    /// Smallest fitness (fraction of source points with a target point within the final correspondence
    /// distance) of a trusted result (default 0.1).
    pub min_fitness: f64,
    /// Smallest overlap estimated by the trimmed ICP (default 0.1).
    pub min_overlap: f64,
    /// Smallest surface agreement ([`Registration::surface_agreement`]: the fraction of source points on a
    /// target surface, within half a voxel and 30° of normal) (default 0.1). Measured: registrations of one
    /// scene reach 0.36–0.66 (3DMatch, LiDAR, the sample pair); unrelated scenes 0.007–0.21.
    pub min_surface_agreement: f64,
    /// Require ICP to meet its convergence tolerances (default true).
    pub require_converged: bool,
    /// Fewest feature correspondences consistent with the global stage's answer (default 20). Measured
    /// (`register`, default settings): scenes registered onto themselves 67–482 (3DMatch 4→1, 4→0, 1→0,
    /// LiDAR, the sample pair); unrelated scenes 7–14; two uniform random clouds 28 (and ambiguous).
    pub min_global_inliers: usize,
}

impl Default for TrustConfig {
    fn default() -> Self {
        TrustConfig {
            min_fitness: 0.1,
            min_overlap: 0.1,
            min_surface_agreement: 0.1,
            require_converged: true,
            min_global_inliers: 20,
        }
    }
}

impl TrustConfig {
    /// Checks that every threshold is a fraction in [0, 1].
    pub fn validate(&self) -> Result<()> {
        for (field, v) in [
            ("trust.min_fitness", self.min_fitness),
            ("trust.min_overlap", self.min_overlap),
            ("trust.min_surface_agreement", self.min_surface_agreement),
        ] {
            if !(0.0..=1.0).contains(&v) {
                return Err(Error::Config {
                    field: field.into(),
                    msg: format!("must be a fraction in [0, 1], got {v}"),
                });
            }
        }
        Ok(())
    }
}

/// The verdict on a result.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct Trust {
    /// True when every check passed.
    pub trusted: bool,
    /// Each failed check, in words (empty when trusted).
    pub reasons: Vec<String>,
    /// What to try, one line each, without repeats.
    pub suggestions: Vec<String>,
}

impl Trust {
    /// A verdict with no failed check yet.
    pub fn new() -> Self {
        Trust {
            trusted: true,
            reasons: Vec::new(),
            suggestions: Vec::new(),
        }
    }

    /// Records a failed check and what to try.
    pub fn fail(&mut self, reason: impl Into<String>, suggestion: impl Into<String>) {
        self.trusted = false;
        self.reasons.push(reason.into());
        let s = suggestion.into();
        if !s.is_empty() && !self.suggestions.contains(&s) {
            self.suggestions.push(s);
        }
    }

    /// Adds another verdict's failed checks.
    pub fn merge(&mut self, other: &Trust) {
        for r in &other.reasons {
            self.trusted = false;
            if !self.reasons.contains(r) {
                self.reasons.push(r.clone());
            }
        }
        for s in &other.suggestions {
            if !self.suggestions.contains(s) {
                self.suggestions.push(s.clone());
            }
        }
    }
}

/// Below this fraction of its step a weak direction's hold-test gap is called loosely held rather than
/// unconstrained: ICP closed more than seven eighths of the distance between its two starts (a noisy bare
/// plane's free directions close at most about three quarters of it, docs/accuracy.md).
const LOOSE_BELOW_FRACTION: f64 = 0.25;

/// Why a degenerate registration is not trusted, true of what was measured, one reason per kind of weak
/// direction, each with its figures:
/// - "unconstrained": the geometry leaves it free (its relative strength below
///   [`Degeneracy::free_below`], a bare plane's level) and ICP started off along it stayed as far off as
///   along a bare plane ([`Degeneracy::is_free`]), or it was judged by its eigenvalue alone (no hold test);
/// - "constrains only weakly": the geometry does constrain it (above a bare plane's level, or ICP came
///   back further than a bare plane lets it) but ICP started off along it stayed off: the basin is too
///   flat for the refinement, not free;
/// - "held only loosely": ICP came most of the way back, not to one answer.
fn degeneracy_reasons(d: &Degeneracy, unit: &str) -> Vec<String> {
    let item = |w: &WeakDirection| {
        let strength = format!("{:.1e} of the strongest direction", w.relative_strength);
        match w.hold_description(unit) {
            Some(h) => format!("{}, {strength}: {h}", w.label()),
            None => format!("{}, {strength}", w.label()),
        }
    };
    let group = |pick: &dyn Fn(&WeakDirection) -> bool| -> Option<String> {
        let items: Vec<String> = d.weak.iter().filter(|w| pick(w)).map(item).collect();
        (!items.is_empty()).then(|| items.join("; "))
    };
    let loose = |w: &WeakDirection| w.hold.is_some_and(|h| h.fraction() < LOOSE_BELOW_FRACTION);
    let mut out = Vec::new();
    let free = |w: &WeakDirection| !loose(w) && (w.hold.is_none() || d.is_free(w));
    if let Some(items) = group(&free) {
        // Only a direction the hold test ran on says what ICP did.
        let tested = d.weak.iter().any(|w| free(w) && w.hold.is_some());
        out.push(format!(
            "the geometry leaves motion unconstrained ({items}): {}so the result may slide along it",
            if tested {
                "ICP started off along it stayed off, "
            } else {
                ""
            }
        ));
    }
    if let Some(items) = group(&|w| !loose(w) && w.hold.is_some() && !d.is_free(w)) {
        out.push(format!(
            "the geometry constrains the result only weakly ({items}): ICP started off along it stayed off, so the result may lie anywhere between"
        ));
    }
    if let Some(items) = group(&|w| loose(w)) {
        out.push(format!(
            "the geometry holds the result only loosely ({items}): ICP started off either way along it did not come back to one answer, so the result may lie anywhere between"
        ));
    }
    out
}

/// The registration checks: converged, not degenerate, not ambiguous, enough fitness, overlap and surface
/// agreement. `unit` names the clouds' length unit in messages (e.g. "m").
pub fn assess_registration(r: &Registration, cfg: &TrustConfig, unit: &str) -> Trust {
    let mut t = Trust::new();
    if cfg.require_converged && !r.converged {
        t.fail(
            "ICP did not meet its convergence tolerances within the iteration budget",
            "start from a closer initial guess (--init), or check that the clouds show the same scene",
        );
    }
    for reason in degeneracy_reasons(&r.degeneracy, unit) {
        t.fail(
            reason,
            "capture views with more 3-D structure in the shared part (objects of different orientations, not a bare plane)",
        );
    }
    if let Some(a) = &r.ambiguity {
        let sp = if unit.is_empty() { "" } else { " " };
        t.fail(
            format!(
                "ambiguous: a second answer {:.2}° / {:.4}{sp}{unit} away scores {:.0}% of the best",
                a.rotation_deg,
                a.translation,
                a.score_ratio * 1e2
            ),
            "give an initial guess (--init), a crop box around the shared part, or more distinctive shared geometry",
        );
    }
    // NaN (nothing measured) fails too.
    let below = |v: f64, min: f64| v.is_nan() || v < min;
    if below(r.fitness, cfg.min_fitness) || below(r.overlap, cfg.min_overlap) {
        t.fail(
            format!(
                "the clouds share too little: fitness {:.3} (at least {}), overlap {:.3} (at least {})",
                r.fitness, cfg.min_fitness, r.overlap, cfg.min_overlap
            ),
            "check that both clouds show the same scene in the same unit, or capture more of the shared part",
        );
    }
    if let Some(g) = r
        .global
        .as_ref()
        .filter(|g| g.inliers < cfg.min_global_inliers)
    {
        t.fail(
            format!(
                "only {} of {} feature matches agree with the answer (at least {}): the clouds may not show the same scene",
                g.inliers, g.correspondences, cfg.min_global_inliers
            ),
            "check that both clouds show the same scene in the same unit, or give an initial guess (--init)",
        );
    }
    if below(r.surface_agreement, cfg.min_surface_agreement) {
        t.fail(
            format!(
                "the aligned surfaces do not coincide: {:.1}% of the source lies on a target surface (at least {:.0}%)",
                r.surface_agreement * 1e2,
                cfg.min_surface_agreement * 1e2
            ),
            "check that both clouds show the same scene in the same unit; a different scene cannot be registered",
        );
    }
    t
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::registration::quality::HoldTest;

    fn yaw(hold: Option<(f64, f64)>) -> WeakDirection {
        let mut w = WeakDirection {
            kind: "rotation",
            axis: [0.0, 0.0, 1.0],
            relative_strength: 3e-4,
            motion_per_unit: [0.0, 0.0, 2.0, 0.0, 0.0, 0.0],
            center: [0.0; 3],
            radius: 0.5,
            hold: None,
        };
        w.hold = hold.map(|(step, gap)| HoldTest::new(&w, step, gap));
        w
    }

    fn reason(weak: Vec<WeakDirection>) -> String {
        degeneracy_reasons(
            &Degeneracy {
                condition: 3e-4,
                weak,
                held: Vec::new(),
                free_below: 6e-4,
            },
            "m",
        )
        .join(" | ")
    }

    /// The reason names what was measured: ends far apart along a direction as weak as a bare plane's are
    /// "unconstrained"; ends far apart along one the geometry does constrain (above a bare plane's level)
    /// are "constrains only weakly", never "unconstrained"; ends that came most of the way back are "held
    /// only loosely"; an untested direction (eigenvalue alone) is "unconstrained" without figures. Each
    /// kind gets its own reason.
    #[test]
    fn the_degeneracy_reason_says_what_the_hold_test_measured() {
        // One finest voxel of 7 mm at a 0.5 m radius: 0.80° of yaw.
        let loose = reason(vec![yaw(Some((0.007, 0.0011)))]);
        assert!(loose.contains("only loosely"), "{loose}");
        assert!(
            loose.contains("±0.80° off") && loose.contains("0.126° apart"),
            "{loose}"
        );
        assert!(!loose.contains("unconstrained"), "{loose}");
        let free = reason(vec![yaw(Some((0.007, 0.011)))]);
        assert!(
            free.contains("unconstrained")
                && free.contains("1.261° apart")
                && free.contains("3.0e-4 of the strongest"),
            "{free}"
        );
        // The same ends along a yaw the geometry constrains (ten times a bare plane's strength).
        let mut held_by_geometry = yaw(Some((0.007, 0.011)));
        held_by_geometry.relative_strength = 3e-3;
        let weakly = reason(vec![held_by_geometry]);
        assert!(
            weakly.contains("constrains the result only weakly") && weakly.contains("1.261° apart"),
            "{weakly}"
        );
        assert!(!weakly.contains("unconstrained"), "{weakly}");
        // As weak as a bare plane's, but ICP closed more of the distance than a plane lets it (ends 0.3 of
        // the step apart): pulled back by something, so weakly constrained, not free.
        let pulled = reason(vec![yaw(Some((0.007, 0.0021)))]);
        assert!(
            pulled.contains("constrains the result only weakly")
                && !pulled.contains("unconstrained"),
            "{pulled}"
        );
        // At a plane's gap (half the step and more) it is free.
        let plane = reason(vec![yaw(Some((0.007, 0.0035)))]);
        assert!(plane.contains("unconstrained"), "{plane}");
        // One loose and one free direction: each is named for what it is.
        let both = reason(vec![yaw(Some((0.007, 0.0011))), yaw(Some((0.007, 0.011)))]);
        assert!(
            both.contains("unconstrained") && both.contains("only loosely"),
            "{both}"
        );
        let untested = reason(vec![yaw(None)]);
        assert!(
            untested.contains("unconstrained")
                && !untested.contains("apart")
                && !untested.contains("ICP started off"),
            "{untested}"
        );
    }
}
