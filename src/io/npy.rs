//! NumPy `.npy` (format 1.x/2.x): a C-order N×3 array of little-endian float32 or float64 (one point per row;
//! a transposed 3×N array is refused with a hint).

use crate::error::{Error, Result};
use crate::geometry::PointCloud;
use std::path::Path;

pub(super) fn read(path: &Path, bytes: &[u8]) -> Result<PointCloud> {
    let err = |m: &str| Error::format(path, m.to_string());
    if bytes.len() < 10 || &bytes[..6] != b"\x93NUMPY" {
        return Err(err("not a .npy file (bad magic)"));
    }
    let (hlen, hstart): (usize, usize) = match bytes[6] {
        1 => (u16::from_le_bytes([bytes[8], bytes[9]]) as usize, 10),
        2 | 3 if bytes.len() >= 12 => (
            u32::from_le_bytes(bytes[8..12].try_into().unwrap()) as usize,
            12,
        ),
        _ => return Err(err("unsupported .npy version")),
    };
    let header = bytes
        .get(hstart..hstart.saturating_add(hlen))
        .ok_or_else(|| err("header truncated"))?;
    let header = std::str::from_utf8(header).map_err(|_| err("header is not text"))?;
    let field = |key: &str| -> Option<&str> {
        let i = header.find(&format!("'{key}'"))?;
        Some(header[i + key.len() + 2..].trim_start_matches([':', ' ']))
    };
    let descr = field("descr").ok_or_else(|| err("header has no descr"))?;
    let size = if descr.starts_with("'<f4'") {
        4
    } else if descr.starts_with("'<f8'") {
        8
    } else {
        return Err(err(
            "only little-endian float32/float64 arrays are supported",
        ));
    };
    if field("fortran_order").is_some_and(|v| v.starts_with("True")) {
        return Err(err("Fortran-order arrays are not supported"));
    }
    let shape = field("shape").ok_or_else(|| err("header has no shape"))?;
    let inner = shape
        .trim_start_matches('(')
        .split(')')
        .next()
        .unwrap_or("");
    let dims: Vec<usize> = inner
        .split(',')
        .filter(|s| !s.trim().is_empty())
        .map(|s| s.trim().parse::<usize>())
        .collect::<std::result::Result<_, _>>()
        .map_err(|_| err("bad shape"))?;
    let (n, k) = match dims.as_slice() {
        [n, 3] => (*n, 3),
        [3, m] => {
            return Err(err(&format!(
                "shape (3, {m}): expected (N, 3), one point per row; this looks like a transposed array \
                 (save `a.T` or use `np.ascontiguousarray(a.T)`)"
            )))
        }
        _ => {
            return Err(err(&format!(
                "shape {dims:?}: expected (N, 3), one x y z point per row"
            )))
        }
    };
    let data = &bytes[hstart + hlen..];
    let need = n.checked_mul(k).and_then(|v| v.checked_mul(size));
    if need.is_none_or(|b| data.len() < b) {
        return Err(err(&format!(
            "data truncated: shape ({n}, {k}) needs {} bytes, found {}",
            need.map_or("more than 2^64".to_string(), |b| b.to_string()),
            data.len()
        )));
    }
    let val = |i: usize| -> f32 {
        let b = &data[i * size..(i + 1) * size];
        if size == 4 {
            f32::from_le_bytes(b.try_into().unwrap())
        } else {
            f64::from_le_bytes(b.try_into().unwrap()) as f32
        }
    };
    Ok(PointCloud::from_points(
        (0..n)
            .map(|i| [val(i * k), val(i * k + 1), val(i * k + 2)])
            .collect(),
    ))
}
