//! Reading the `--json` output of `depthcal calibrate` and `depthcal register` against a known truth: the
//! errors, the covariance's σ and the normalised errors, `trusted` and the reasons.
//!
//! Normalised errors: with `Σ` the JSON `covariance` (6x6, `[rx, ry, rz (rad), tx, ty, tz (m)]`, left
//! increment in the target (reference base) frame, i.e. `T = exp(δ) · T_true`), the error increment is
//! `δ = [log(R_est · R_trueᵀ), t_est − R_est · R_trueᵀ · t_true]`, the rotation vector and the translation of
//! `T_est · T_true⁻¹`. `n_rot = |δ_rot| / sqrt(trace Σ_rot)`, `n_trans = |δ_trans| / sqrt(trace Σ_trans)`
//! and `mahalanobis = sqrt(δᵀ Σ⁻¹ δ)` (6 degrees of freedom: about sqrt(6) ≈ 2.4 on average when Σ is
//! honest).
#![allow(dead_code)]

use super::depthcal;
use nalgebra::{Isometry3, Matrix4, Matrix6, Rotation3, Translation3, UnitQuaternion, Vector6};
use std::path::Path;

/// One `calibrate --json` (or `register --json`) run and what was read from it.
#[derive(Debug)]
pub struct Outcome {
    pub code: i32,
    pub json: Option<serde_json::Value>,
    pub stderr: String,
    /// `error_vs_truth` from the JSON (degrees, mm), else computed here from `transform`.
    pub rot_deg: Option<f64>,
    pub trans_mm: Option<f64>,
    /// Root of the trace of the rotation (degrees) and translation (mm) covariance blocks.
    pub sigma_rot_deg: Option<f64>,
    pub sigma_trans_mm: Option<f64>,
    pub n_rot: Option<f64>,
    pub n_trans: Option<f64>,
    pub mahalanobis: Option<f64>,
    pub trusted: Option<bool>,
    pub degenerate: Option<bool>,
    /// The JSON `reasons` (why the result is not trusted).
    pub reasons: Vec<String>,
    /// Axis of the rotation error `R_est · R_trueᵀ` in the target frame.
    pub err_axis: Option<nalgebra::Vector3<f64>>,
    pub secs: f64,
}

impl Outcome {
    /// Within 0.1° and 2 mm of the truth.
    pub fn right(&self) -> bool {
        self.rot_deg.is_some_and(|r| r < 0.1) && self.trans_mm.is_some_and(|t| t < 2.0)
    }

    /// `sqrt(δᵀ Σ⁻¹ δ / 6)`: about 1 when the covariance is honest.
    pub fn z(&self) -> Option<f64> {
        self.mahalanobis.map(|m| m / 6f64.sqrt())
    }

    /// Reads the output of a run (`code`, stdout, stderr, seconds) against `truth`.
    pub fn parse(
        code: i32,
        out: &str,
        stderr: String,
        truth: &Isometry3<f64>,
        secs: f64,
    ) -> Outcome {
        let json: Option<serde_json::Value> = serde_json::from_str(out).ok();
        let mut o = Outcome {
            code,
            json: json.clone(),
            stderr,
            rot_deg: None,
            trans_mm: None,
            sigma_rot_deg: None,
            sigma_trans_mm: None,
            n_rot: None,
            n_trans: None,
            mahalanobis: None,
            trusted: None,
            degenerate: None,
            reasons: Vec::new(),
            err_axis: None,
            secs,
        };
        let Some(v) = json else {
            return o;
        };
        // Tolerant reading: every field may be absent or renamed by the engine changes under way.
        o.trusted = v
            .get("trusted")
            .and_then(|t| t.as_bool())
            .or_else(|| v.pointer("/quality/trusted").and_then(|t| t.as_bool()));
        o.degenerate = v.get("degenerate").and_then(|t| t.as_bool());
        o.reasons = v
            .get("reasons")
            .and_then(|r| r.as_array())
            .map(|r| {
                r.iter()
                    .filter_map(|x| x.as_str().map(String::from))
                    .collect()
            })
            .unwrap_or_default();
        let est = v.get("transform").and_then(matrix4);
        o.rot_deg = v
            .pointer("/error_vs_truth/rotation_deg")
            .and_then(|x| x.as_f64());
        o.trans_mm = v
            .pointer("/error_vs_truth/translation_m")
            .and_then(|x| x.as_f64())
            .map(|m| m * 1e3);
        if let Some(est) = est {
            let d = left_increment(&est, truth);
            let w = d.fixed_rows::<3>(0).into_owned();
            o.err_axis = (w.norm() > 1e-12).then(|| w / w.norm());
            if o.rot_deg.is_none() {
                o.rot_deg = Some(d.fixed_rows::<3>(0).norm().to_degrees());
            }
            if o.trans_mm.is_none() {
                o.trans_mm = Some((est.translation.vector - truth.translation.vector).norm() * 1e3);
            }
            if let Some(cov) = v.get("covariance").and_then(matrix6) {
                let tr_r: f64 = (0..3).map(|i| cov[(i, i)]).sum();
                let tr_t: f64 = (3..6).map(|i| cov[(i, i)]).sum();
                o.sigma_rot_deg = Some(tr_r.max(0.0).sqrt().to_degrees());
                o.sigma_trans_mm = Some(tr_t.max(0.0).sqrt() * 1e3);
                o.n_rot = Some(d.fixed_rows::<3>(0).norm() / tr_r.sqrt());
                o.n_trans = Some(d.fixed_rows::<3>(3).norm() / tr_t.sqrt());
                // Pseudo-inverse so a singular (degenerate) covariance still gives a number.
                let sym = (cov + cov.transpose()) * 0.5;
                if let Ok(inv) = sym.pseudo_inverse(1e-30) {
                    o.mahalanobis = Some((d.transpose() * inv * d)[(0, 0)].max(0.0).sqrt());
                }
            }
        }
        o
    }
}

/// A pose from a 4x4 JSON matrix (or an object with a `matrix` field).
pub fn matrix4(v: &serde_json::Value) -> Option<Isometry3<f64>> {
    let rows = v.get("matrix").unwrap_or(v).as_array()?;
    let mut m = Matrix4::zeros();
    for (r, row) in rows.iter().enumerate().take(4) {
        for (c, x) in row.as_array()?.iter().enumerate().take(4) {
            m[(r, c)] = x.as_f64()?;
        }
    }
    let rot = Rotation3::from_matrix(&m.fixed_view::<3, 3>(0, 0).into_owned());
    Some(Isometry3::from_parts(
        Translation3::new(m[(0, 3)], m[(1, 3)], m[(2, 3)]),
        UnitQuaternion::from_rotation_matrix(&rot),
    ))
}

/// A 6x6 matrix from JSON rows.
pub fn matrix6(v: &serde_json::Value) -> Option<Matrix6<f64>> {
    let rows = v.as_array()?;
    if rows.len() != 6 {
        return None;
    }
    let mut m = Matrix6::zeros();
    for (r, row) in rows.iter().enumerate() {
        let row = row.as_array()?;
        if row.len() != 6 {
            return None;
        }
        for (c, x) in row.iter().enumerate() {
            m[(r, c)] = x.as_f64()?;
        }
    }
    Some(m)
}

/// The left increment `δ = [log(R_e R_tᵀ), t_e − R_e R_tᵀ t_t]` with `T_est = exp(δ) · T_true`.
pub fn left_increment(est: &Isometry3<f64>, truth: &Isometry3<f64>) -> Vector6<f64> {
    let d = est * truth.inverse();
    let w = d.rotation.scaled_axis();
    let v = d.translation.vector;
    Vector6::new(w.x, w.y, w.z, v.x, v.y, v.z)
}

/// Runs `depthcal calibrate DIR --json --threads 2 EXTRA...` and reads its output against `truth`.
pub fn calibrate(dir: &Path, truth: &Isometry3<f64>, extra: &[&str]) -> Outcome {
    let dir = dir.to_str().unwrap();
    let mut args = vec!["calibrate", dir, "--json", "--threads", "2"];
    args.extend_from_slice(extra);
    let t0 = std::time::Instant::now();
    let (code, out, stderr) = depthcal(&args);
    Outcome::parse(code, &out, stderr, truth, t0.elapsed().as_secs_f64())
}

/// `x` with `prec` decimals, `-` when absent.
pub fn f(x: Option<f64>, prec: usize) -> String {
    x.map_or("-".into(), |v| format!("{v:.prec$}"))
}
