//! Whether a result can be trusted, and why not.
//!
//! A registration or calibration that is wrong but looks confident is the worst thing this tool can
//! produce. Each result carries a [`Trust`]: `trusted` is true only when every check passed; otherwise
//! `reasons` says which failed and `suggestions` what to try. The checks of a registration are here
//! ([`assess_registration`]); a calibration adds its own (priors, free space, each robot's own frames).

use crate::error::{Error, Result};
use crate::registration::pipeline::Registration;
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
    if r.degeneracy.is_degenerate() {
        t.fail(
            format!(
                "the geometry leaves motion unconstrained ({}): ICP started off along it stayed off, so the result may slide along it",
                r.degeneracy.describe()
            ),
            "capture views with more 3-D structure in the shared part (objects of different orientations, not a bare plane)",
        );
    }
    if let Some(a) = &r.ambiguity {
        t.fail(
            format!(
                "ambiguous: a second answer {:.2}° / {:.4} {unit} away scores {:.0}% of the best",
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
