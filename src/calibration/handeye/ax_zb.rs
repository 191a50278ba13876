//! Closed forms of the robot-world hand-eye problem from single frames: Shah (2013) and Li et al. (2010).
//!
//! For every frame `T_base_ee_i · T_ee_cam · T_cam_board_i = T_base_board`. In the literature's form
//! `Aᵢ X = Z Bᵢ` this is `Aᵢ = T_base_ee_i`, `X = T_ee_cam`, `Z = T_base_board` and
//! `Bᵢ = T_board_cam_i = T_cam_board_i⁻¹`. Both methods give X and Z at once.

use super::ax_xb::nearest_rotation;
use super::HandEyeFrame;
use crate::error::{Error, Result};
use nalgebra::{
    DMatrix, DVector, Isometry3, Matrix3, Matrix6, Translation3, UnitQuaternion, Vector6,
};

fn degenerate(what: &str) -> Error {
    Error::Failed(format!(
        "{what}: the frames do not determine the hand-eye transform (are all rotations about one axis?)"
    ))
}

fn rot(q: &UnitQuaternion<f64>) -> Matrix3<f64> {
    q.to_rotation_matrix().into_inner()
}

/// `kron(a, b)` for 3x3 matrices, as a 9x9 block written into `out` at `(row, col)` with `sign`.
fn put_kron(
    out: &mut DMatrix<f64>,
    row: usize,
    col: usize,
    a: &Matrix3<f64>,
    b: &Matrix3<f64>,
    sign: f64,
) {
    for i in 0..3 {
        for j in 0..3 {
            for k in 0..3 {
                for l in 0..3 {
                    out[(row + 3 * i + k, col + 3 * j + l)] += sign * a[(i, j)] * b[(k, l)];
                }
            }
        }
    }
}

/// Column-major 3x3 matrix from a 9-vector slice.
fn unvec(v: &[f64]) -> Matrix3<f64> {
    Matrix3::from_column_slice(v)
}

/// Both translations given both rotations: least squares over
/// `R_Aᵢ t_X − t_Z = R_Z t_Bᵢ − t_Aᵢ` (`Bᵢ = T_board_cam_i`).
pub(crate) fn translations_given_rotations(
    frames: &[HandEyeFrame],
    r_x: &UnitQuaternion<f64>,
    r_z: &UnitQuaternion<f64>,
    what: &str,
) -> Result<(Isometry3<f64>, Isometry3<f64>)> {
    let mut h = Matrix6::<f64>::zeros();
    let mut g = Vector6::<f64>::zeros();
    for f in frames {
        let b = f.t_cam_board.inverse();
        let ra = rot(&f.t_base_ee.rotation);
        let mut c = nalgebra::Matrix3x6::<f64>::zeros();
        c.fixed_view_mut::<3, 3>(0, 0).copy_from(&ra);
        c.fixed_view_mut::<3, 3>(0, 3)
            .copy_from(&(-Matrix3::identity()));
        let rhs = r_z * b.translation.vector - f.t_base_ee.translation.vector;
        h += c.transpose() * c;
        g += c.transpose() * rhs;
    }
    let svd = h.svd(true, true);
    let s = svd.singular_values;
    if s.min() <= 1e-12 * s.max() {
        return Err(degenerate(what));
    }
    let t = svd.solve(&g, 0.0).map_err(|_| degenerate(what))?;
    Ok((
        Isometry3::from_parts(Translation3::new(t[0], t[1], t[2]), *r_x),
        Isometry3::from_parts(Translation3::new(t[3], t[4], t[5]), *r_z),
    ))
}

/// Scales the 18-vector `(vec R_X, vec R_Z)` so that `det R_X = 1`, and projects both onto SO(3).
fn rotations_from_null_vector(
    v: &[f64],
    what: &str,
) -> Result<(UnitQuaternion<f64>, UnitQuaternion<f64>)> {
    let mx = unvec(&v[0..9]);
    let mz = unvec(&v[9..18]);
    let det = mx.determinant();
    if !det.is_finite() || det.abs() < 1e-12 {
        return Err(degenerate(what));
    }
    let alpha = det.signum() / det.abs().cbrt();
    let rx = nearest_rotation(&(mx * alpha)).ok_or_else(|| degenerate(what))?;
    let rz = nearest_rotation(&(mz * alpha)).ok_or_else(|| degenerate(what))?;
    Ok((rx, rz))
}

/// Shah's Kronecker-product method: the rotations from the null vector of the stacked
/// `(I ⊗ R_Aᵢ) vec R_X − (R_Bᵢᵀ ⊗ I) vec R_Z = 0`, then both translations by linear least squares.
/// Returns `(T_ee_cam, T_base_board)`.
pub fn shah(frames: &[HandEyeFrame]) -> Result<(Isometry3<f64>, Isometry3<f64>)> {
    let n = frames.len();
    if n < 3 {
        return Err(degenerate("Shah"));
    }
    let mut k = DMatrix::<f64>::zeros(9 * n, 18);
    let id = Matrix3::identity();
    for (i, f) in frames.iter().enumerate() {
        let ra = rot(&f.t_base_ee.rotation);
        let rb = rot(&f.t_cam_board.rotation).transpose(); // R of T_board_cam
        put_kron(&mut k, 9 * i, 0, &id, &ra, 1.0);
        put_kron(&mut k, 9 * i, 9, &rb.transpose(), &id, -1.0);
    }
    let svd = k.svd(false, true);
    let vt = svd.v_t.ok_or_else(|| degenerate("Shah"))?;
    let s = &svd.singular_values;
    let mut idx: Vec<usize> = (0..s.len()).collect();
    idx.sort_by(|&i, &j| s[i].total_cmp(&s[j]));
    if s[idx[1]] <= 1e-9 * s.max() {
        return Err(degenerate("Shah"));
    }
    let v: Vec<f64> = vt.row(idx[0]).iter().cloned().collect();
    let (rx, rz) = rotations_from_null_vector(&v, "Shah")?;
    translations_given_rotations(frames, &rx, &rz, "Shah")
}

/// Li, Wang and Wu's method: rotations and translations together as one linear least-squares system in
/// `(vec R_X, vec R_Z, t_X, t_Z)`, then the rotations projected onto SO(3) and the translations solved
/// again with them fixed. Returns `(T_ee_cam, T_base_board)`.
pub fn li(frames: &[HandEyeFrame]) -> Result<(Isometry3<f64>, Isometry3<f64>)> {
    let n = frames.len();
    if n < 3 {
        return Err(degenerate("Li"));
    }
    let mut k = DMatrix::<f64>::zeros(12 * n, 24);
    let mut rhs = DVector::<f64>::zeros(12 * n);
    let id = Matrix3::identity();
    for (i, f) in frames.iter().enumerate() {
        let ra = rot(&f.t_base_ee.rotation);
        let b = f.t_cam_board.inverse();
        let rb = rot(&b.rotation);
        let tb = b.translation.vector;
        let r = 12 * i;
        put_kron(&mut k, r, 0, &id, &ra, 1.0);
        put_kron(&mut k, r, 9, &rb.transpose(), &id, -1.0);
        // R_A t_X − t_Z − (t_Bᵀ ⊗ I) vec R_Z = −t_A
        for row in 0..3 {
            for c in 0..3 {
                k[(r + 9 + row, 18 + c)] = ra[(row, c)];
            }
            k[(r + 9 + row, 21 + row)] = -1.0;
            for j in 0..3 {
                k[(r + 9 + row, 9 + 3 * j + row)] -= tb[j];
            }
            rhs[r + 9 + row] = -f.t_base_ee.translation.vector[row];
        }
    }
    let svd = k.svd(true, true);
    let s = &svd.singular_values;
    if s.min() <= 1e-10 * s.max() {
        return Err(degenerate("Li"));
    }
    let sol = svd.solve(&rhs, 0.0).map_err(|_| degenerate("Li"))?;
    let v: Vec<f64> = sol.iter().cloned().collect();
    let mx = unvec(&v[0..9]);
    let mz = unvec(&v[9..18]);
    let rx = nearest_rotation(&mx).ok_or_else(|| degenerate("Li"))?;
    let rz = nearest_rotation(&mz).ok_or_else(|| degenerate("Li"))?;
    translations_given_rotations(frames, &rx, &rz, "Li")
}
