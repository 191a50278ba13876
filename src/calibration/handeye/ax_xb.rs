//! Closed forms of AX = XB from motion pairs: Tsai-Lenz (1989), Park-Martin (1994), Daniilidis (1999).
//!
//! Each [`Motion`] holds `A = T_ee_i_ee_j = T_base_ee_i⁻¹ · T_base_ee_j` (the robot motion) and
//! `B = T_cam_i_cam_j = T_cam_board_i · T_cam_board_j⁻¹` (the camera motion); the unknown is
//! `X = T_ee_cam`, with `A · X = X · B` for every pair.

use super::{log_rotation, Motion};
use crate::error::{Error, Result};
use nalgebra::{
    DMatrix, Isometry3, Matrix3, Quaternion, Translation3, UnitQuaternion, Vector3, Vector4,
};

/// The skew-symmetric (cross-product) matrix of `v`.
pub(crate) fn skew(v: &Vector3<f64>) -> Matrix3<f64> {
    Matrix3::new(0.0, -v.z, v.y, v.z, 0.0, -v.x, -v.y, v.x, 0.0)
}

fn degenerate(what: &str) -> Error {
    Error::Failed(format!(
        "{what}: the motions do not determine the hand-eye transform (are all rotations about one axis?)"
    ))
}

/// Solves a small symmetric positive (semi)definite system, `None` when singular.
fn solve3(h: &Matrix3<f64>, g: &Vector3<f64>) -> Option<Vector3<f64>> {
    let svd = h.svd(true, true);
    let s = svd.singular_values;
    if s.max() <= 0.0 || s.min() <= 1e-12 * s.max() {
        return None;
    }
    svd.solve(g, 0.0).ok()
}

/// The translation of X given its rotation: least squares over `(R_A − I) t_X = R_X t_B − t_A`.
pub(crate) fn translation_given_rotation(
    motions: &[Motion],
    r_x: &UnitQuaternion<f64>,
    what: &str,
) -> Result<Isometry3<f64>> {
    let mut h = Matrix3::zeros();
    let mut g = Vector3::zeros();
    for m in motions {
        let c = m.a.rotation.to_rotation_matrix().into_inner() - Matrix3::identity();
        let rhs = r_x * m.b.translation.vector - m.a.translation.vector;
        h += c.transpose() * c;
        g += c.transpose() * rhs;
    }
    let t = solve3(&h, &g).ok_or_else(|| degenerate(what))?;
    Ok(Isometry3::from_parts(Translation3::from(t), *r_x))
}

/// Tsai-Lenz: the rotation from the modified Rodrigues (Gibbs) vectors `skew(Pa + Pb) · g = Pb − Pa`
/// (with `P = 2 sin(θ/2) · axis`), then the translation by least squares. Fails for a hand-eye rotation of
/// 180° (a limit of the Gibbs vector) and when the motions are degenerate.
pub fn tsai_lenz(motions: &[Motion]) -> Result<Isometry3<f64>> {
    let mut h = Matrix3::zeros();
    let mut g = Vector3::zeros();
    for m in motions {
        let pa = pos_w(&m.a.rotation).imag() * 2.0;
        let pb = pos_w(&m.b.rotation).imag() * 2.0;
        let s = skew(&(pa + pb));
        h += s.transpose() * s;
        g += s.transpose() * (pb - pa);
    }
    let gibbs = solve3(&h, &g).ok_or_else(|| degenerate("Tsai-Lenz"))?;
    let r_x = UnitQuaternion::new_normalize(Quaternion::new(1.0, gibbs.x, gibbs.y, gibbs.z));
    translation_given_rotation(motions, &r_x, "Tsai-Lenz")
}

fn pos_w(q: &UnitQuaternion<f64>) -> Quaternion<f64> {
    let q = *q.quaternion();
    if q.w < 0.0 {
        -q
    } else {
        q
    }
}

/// The proper rotation nearest to `m` ([`crate::geometry::transform::nearest_rotation`]) as a quaternion.
pub(crate) fn nearest_rotation(m: &Matrix3<f64>) -> Option<UnitQuaternion<f64>> {
    crate::geometry::transform::nearest_rotation(m)
        .map(|r| UnitQuaternion::from_rotation_matrix(&r))
}

/// Park-Martin: the rotation that best maps the camera rotation vectors `βᵢ = log R_Bᵢ` onto the robot
/// ones `αᵢ = log R_Aᵢ` (`α = R_X β`, solved as orthogonal Procrustes by SVD, which also works when only two
/// axis directions are present), then the translation by least squares.
pub fn park_martin(motions: &[Motion]) -> Result<Isometry3<f64>> {
    let mut m = Matrix3::zeros();
    for mo in motions {
        let alpha = log_rotation(&mo.a.rotation);
        let beta = log_rotation(&mo.b.rotation);
        m += alpha * beta.transpose();
    }
    let r_x = nearest_rotation(&m).ok_or_else(|| degenerate("Park-Martin"))?;
    translation_given_rotation(motions, &r_x, "Park-Martin")
}

/// The dual quaternion `(q, q')` of a rigid transform, `q' = ½ (0, t) · q`, with `q.w ≥ 0`.
fn dual_quaternion(t: &Isometry3<f64>) -> (Quaternion<f64>, Quaternion<f64>) {
    let q = pos_w(&t.rotation);
    let tv = t.translation.vector;
    let qd = Quaternion::new(0.0, tv.x, tv.y, tv.z) * q * 0.5;
    (q, qd)
}

/// Daniilidis: the hand-eye dual quaternion from the two-dimensional null space of the stacked 6x8
/// screw-motion equations, fixed by the unit-norm and orthogonality constraints.
pub fn daniilidis(motions: &[Motion]) -> Result<Isometry3<f64>> {
    let n = motions.len();
    if n < 2 {
        return Err(degenerate("Daniilidis"));
    }
    let mut t = DMatrix::<f64>::zeros(6 * n, 8);
    for (k, m) in motions.iter().enumerate() {
        let (qa, qad) = dual_quaternion(&m.a);
        let (mut qb, mut qbd) = dual_quaternion(&m.b);
        // The scalar parts of A and B are equal for a consistent pair: pick B's sign to match.
        if qa.w * qb.w < 0.0 {
            qb = -qb;
            qbd = -qbd;
        }
        let (a, b) = (qa.imag(), qb.imag());
        let (ad, bd) = (qad.imag(), qbd.imag());
        let r = 6 * k;
        let put =
            |t: &mut DMatrix<f64>, row: usize, col: usize, d: &Vector3<f64>, s: &Vector3<f64>| {
                let sk = skew(s);
                for i in 0..3 {
                    t[(row + i, col)] = d[i];
                    for j in 0..3 {
                        t[(row + i, col + 1 + j)] = sk[(i, j)];
                    }
                }
            };
        put(&mut t, r, 0, &(a - b), &(a + b));
        put(&mut t, r + 3, 0, &(ad - bd), &(ad + bd));
        put(&mut t, r + 3, 4, &(a - b), &(a + b));
    }
    let svd = t.svd(false, true);
    let vt = svd.v_t.ok_or_else(|| degenerate("Daniilidis"))?;
    let s = &svd.singular_values;
    // Indices of the two smallest singular values.
    let mut idx: Vec<usize> = (0..s.len()).collect();
    idx.sort_by(|&i, &j| s[i].total_cmp(&s[j]));
    let (k1, k2, k3) = (idx[0], idx[1], idx[2]);
    if s[k3] <= 1e-9 * s.max() {
        return Err(degenerate("Daniilidis"));
    }
    let v1 = vt.row(k1).transpose();
    let v2 = vt.row(k2).transpose();
    let (u1, w1) = (
        Vector4::new(v1[0], v1[1], v1[2], v1[3]),
        Vector4::new(v1[4], v1[5], v1[6], v1[7]),
    );
    let (u2, w2) = (
        Vector4::new(v2[0], v2[1], v2[2], v2[3]),
        Vector4::new(v2[4], v2[5], v2[6], v2[7]),
    );
    // q = λ1 u1 + λ2 u2, q' = λ1 w1 + λ2 w2; q·q' = 0 and |q| = 1.
    let a = u1.dot(&w1);
    let b = u1.dot(&w2) + u2.dot(&w1);
    let c = u2.dot(&w2);
    let norm2 = |l1: f64, l2: f64| (u1 * l1 + u2 * l2).norm_squared();
    // Solve a l1² + b l1 l2 + c l2² = 0 for the direction (l1, l2); pick the root with the largest |q|.
    let mut candidates: Vec<(f64, f64)> = Vec::new();
    if a.abs() >= c.abs() {
        // l1 = s l2: a s² + b s + c = 0.
        for s in quadratic_roots(a, b, c) {
            candidates.push((s, 1.0));
        }
    } else {
        // l2 = s l1: c s² + b s + a = 0.
        for s in quadratic_roots(c, b, a) {
            candidates.push((1.0, s));
        }
    }
    let (l1, l2) = candidates
        .into_iter()
        .max_by(|p, q| norm2(p.0, p.1).total_cmp(&norm2(q.0, q.1)))
        .ok_or_else(|| degenerate("Daniilidis"))?;
    let scale = 1.0 / norm2(l1, l2).sqrt();
    let (l1, l2) = (l1 * scale, l2 * scale);
    let q = u1 * l1 + u2 * l2;
    let qd = w1 * l1 + w2 * l2;
    let q = Quaternion::new(q[0], q[1], q[2], q[3]);
    let qd = Quaternion::new(qd[0], qd[1], qd[2], qd[3]);
    let tq = qd * q.conjugate() * 2.0;
    let rot = UnitQuaternion::new_normalize(q);
    if !tq.coords.iter().all(|x| x.is_finite()) {
        return Err(degenerate("Daniilidis"));
    }
    Ok(Isometry3::from_parts(
        Translation3::new(tq.i, tq.j, tq.k),
        rot,
    ))
}

/// Real roots of `a x² + b x + c = 0` with `|a|` the largest leading coefficient (a discriminant slightly
/// below zero from round-off counts as zero).
fn quadratic_roots(a: f64, b: f64, c: f64) -> Vec<f64> {
    if a == 0.0 {
        return if b != 0.0 { vec![-c / b] } else { vec![] };
    }
    let disc = (b * b - 4.0 * a * c).max(0.0);
    let sq = disc.sqrt();
    // Numerically stable pair.
    let qv = -0.5 * (b + b.signum() * sq);
    let mut r = Vec::new();
    if qv != 0.0 {
        r.push(qv / a);
        r.push(c / qv);
    } else {
        r.push(0.0);
    }
    r
}
