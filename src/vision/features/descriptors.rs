//! Descriptor rows, float (SIFT, compared by L2 distance) or binary (ORB, AKAZE, Hamming distance), in a
//! form that can be pooled over many images and sliced without OpenCV.

use super::FeatureKind;
use crate::error::{Error, Result};
use opencv::core::Mat;
use opencv::prelude::*;

/// One descriptor per keypoint, row-major: `width` `f32` values per row for SIFT, `width` bytes per row
/// (`8 · width` bits) for ORB and AKAZE.
#[derive(Clone, Debug, PartialEq)]
pub struct Descriptors {
    kind: FeatureKind,
    /// Values per row; 0 while there are no rows yet (taken from the first rows appended).
    width: usize,
    rows: Rows,
}

#[derive(Clone, Debug, PartialEq)]
enum Rows {
    Float(Vec<f32>),
    Binary(Vec<u8>),
}

impl Descriptors {
    /// No rows, of `kind`.
    pub fn empty(kind: FeatureKind) -> Self {
        Descriptors {
            kind,
            width: 0,
            rows: if kind.is_binary() {
                Rows::Binary(Vec::new())
            } else {
                Rows::Float(Vec::new())
            },
        }
    }

    /// Float descriptors of `kind` (which must be a float kind: SIFT), `width` values per row,
    /// row-major. Errors when the length is not a multiple of `width` or a value is not finite.
    pub fn from_f32(kind: FeatureKind, width: usize, values: Vec<f32>) -> Result<Self> {
        if kind.is_binary() {
            return Err(Error::InvalidInput(format!(
                "{kind} descriptors are binary, not float"
            )));
        }
        check_shape(width, values.len())?;
        if values.iter().any(|v| !v.is_finite()) {
            return Err(Error::InvalidInput(
                "float descriptors must be finite".into(),
            ));
        }
        Ok(Descriptors {
            kind,
            width: if values.is_empty() { 0 } else { width },
            rows: Rows::Float(values),
        })
    }

    /// Binary descriptors of `kind` (ORB or AKAZE), `width` bytes per row, row-major. Errors when the
    /// length is not a multiple of `width`.
    pub fn from_bytes(kind: FeatureKind, width: usize, bytes: Vec<u8>) -> Result<Self> {
        if !kind.is_binary() {
            return Err(Error::InvalidInput(format!(
                "{kind} descriptors are float, not binary"
            )));
        }
        check_shape(width, bytes.len())?;
        Ok(Descriptors {
            kind,
            width: if bytes.is_empty() { 0 } else { width },
            rows: Rows::Binary(bytes),
        })
    }

    /// Number of rows (descriptors).
    pub fn len(&self) -> usize {
        match (&self.rows, self.width) {
            (_, 0) => 0,
            (Rows::Float(v), w) => v.len() / w,
            (Rows::Binary(v), w) => v.len() / w,
        }
    }

    /// True when there are no rows.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The detector the descriptors come from (which fixes the distance: L2 or Hamming).
    pub fn kind(&self) -> FeatureKind {
        self.kind
    }

    /// Values per row: `f32`s for float descriptors, bytes for binary ones; 0 when there are no rows.
    pub fn width(&self) -> usize {
        self.width
    }

    /// Appends `other`'s rows after these. Errors when the kinds differ or both have rows of different
    /// widths.
    pub fn append(&mut self, other: &Descriptors) -> Result<()> {
        if self.kind != other.kind {
            return Err(Error::InvalidInput(format!(
                "cannot pool {} descriptors with {} descriptors",
                other.kind, self.kind
            )));
        }
        if other.is_empty() {
            return Ok(());
        }
        if self.width != 0 && self.width != other.width {
            return Err(Error::InvalidInput(format!(
                "cannot pool {} descriptors of {} values with rows of {} values",
                self.kind, other.width, self.width
            )));
        }
        self.width = other.width;
        match (&mut self.rows, &other.rows) {
            (Rows::Float(a), Rows::Float(b)) => a.extend_from_slice(b),
            (Rows::Binary(a), Rows::Binary(b)) => a.extend_from_slice(b),
            _ => unreachable!("the kind fixes the row type"),
        }
        Ok(())
    }

    /// The rows at `idx`, in that order (repeats allowed); panics on an index out of range.
    pub fn select(&self, idx: &[usize]) -> Descriptors {
        let n = self.len();
        let w = self.width;
        for &i in idx {
            assert!(i < n, "descriptor index {i} out of range ({n} rows)");
        }
        let rows = match &self.rows {
            Rows::Float(v) => Rows::Float(
                idx.iter()
                    .flat_map(|&i| &v[i * w..(i + 1) * w])
                    .copied()
                    .collect(),
            ),
            Rows::Binary(v) => Rows::Binary(
                idx.iter()
                    .flat_map(|&i| &v[i * w..(i + 1) * w])
                    .copied()
                    .collect(),
            ),
        };
        Descriptors {
            kind: self.kind,
            width: if idx.is_empty() { 0 } else { w },
            rows,
        }
    }

    /// Row `i` of float descriptors (`None` for binary ones or out of range).
    pub fn float_row(&self, i: usize) -> Option<&[f32]> {
        match &self.rows {
            Rows::Float(v) if i < self.len() => Some(&v[i * self.width..(i + 1) * self.width]),
            _ => None,
        }
    }

    /// Row `i` of binary descriptors (`None` for float ones or out of range).
    pub fn binary_row(&self, i: usize) -> Option<&[u8]> {
        match &self.rows {
            Rows::Binary(v) if i < self.len() => Some(&v[i * self.width..(i + 1) * self.width]),
            _ => None,
        }
    }

    /// All float values, row-major (`None` for binary descriptors).
    pub(crate) fn float_values(&self) -> Option<&[f32]> {
        match &self.rows {
            Rows::Float(v) => Some(v),
            Rows::Binary(_) => None,
        }
    }

    /// Rows `start..end` as an OpenCV matrix borrowing the data (`CV_32F` or `CV_8U`, `width` columns),
    /// `None` for an empty range.
    pub(crate) fn rows_mat(
        &self,
        start: usize,
        end: usize,
    ) -> Result<Option<opencv::boxed_ref::BoxedRef<'_, Mat>>> {
        if start >= end {
            return Ok(None);
        }
        let w = self.width;
        let (r, c) = (
            i32::try_from(end - start).map_err(|_| too_many(end - start))?,
            w as i32,
        );
        let m = match &self.rows {
            Rows::Float(v) => Mat::new_rows_cols_with_data(r, c, &v[start * w..end * w]),
            Rows::Binary(v) => Mat::new_rows_cols_with_data(r, c, &v[start * w..end * w]),
        }
        .map_err(|e| super::super::cv::error("wrapping descriptors", e))?;
        Ok(Some(m))
    }

    /// Descriptors of `kind` from an OpenCV matrix (`CV_32F` for float kinds, `CV_8U` for binary ones).
    pub(crate) fn from_mat(kind: FeatureKind, m: &Mat) -> Result<Self> {
        if m.rows() == 0 || m.empty() {
            return Ok(Descriptors::empty(kind));
        }
        let owned;
        let m = if m.is_continuous() {
            m
        } else {
            owned = m
                .try_clone()
                .map_err(|e| super::super::cv::error("copying descriptors", e))?;
            &owned
        };
        let width = m.cols() as usize;
        let cv_err = |e| super::super::cv::error("reading descriptors", e);
        if kind.is_binary() {
            if m.typ() != opencv::core::CV_8U {
                return Err(Error::Failed(format!(
                    "OpenCV returned {kind} descriptors of type {} instead of 8-bit",
                    m.typ()
                )));
            }
            Descriptors::from_bytes(kind, width, m.data_bytes().map_err(cv_err)?.to_vec())
        } else {
            if m.typ() != opencv::core::CV_32F {
                return Err(Error::Failed(format!(
                    "OpenCV returned {kind} descriptors of type {} instead of 32-bit float",
                    m.typ()
                )));
            }
            Descriptors::from_f32(kind, width, m.data_typed::<f32>().map_err(cv_err)?.to_vec())
        }
    }
}

fn too_many(n: usize) -> Error {
    Error::InvalidInput(format!("{n} descriptors are more than OpenCV can index"))
}

fn check_shape(width: usize, len: usize) -> Result<()> {
    if len > 0 && (width == 0 || !len.is_multiple_of(width)) {
        return Err(Error::InvalidInput(format!(
            "{len} descriptor values do not make rows of {width}"
        )));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn append_select_and_kinds() {
        let mut a = Descriptors::from_f32(FeatureKind::Sift, 2, vec![1.0, 2.0, 3.0, 4.0]).unwrap();
        let b = Descriptors::from_f32(FeatureKind::Sift, 2, vec![5.0, 6.0]).unwrap();
        assert_eq!((a.len(), a.width(), a.kind()), (2, 2, FeatureKind::Sift));
        a.append(&b).unwrap();
        assert_eq!(a.len(), 3);
        assert_eq!(a.float_row(2), Some(&[5.0f32, 6.0][..]));
        let s = a.select(&[2, 0, 2]);
        assert_eq!(s.len(), 3);
        assert_eq!(s.float_row(1), Some(&[1.0f32, 2.0][..]));
        assert!(a.select(&[]).is_empty());
        // Pooling into an empty set takes the width; a different width or kind is refused.
        let mut pool = Descriptors::empty(FeatureKind::Sift);
        assert!(pool.is_empty());
        pool.append(&a).unwrap();
        assert_eq!(pool, a);
        let c = Descriptors::from_f32(FeatureKind::Sift, 3, vec![0.0; 3]).unwrap();
        assert!(pool.append(&c).is_err());
        let orb = Descriptors::from_bytes(FeatureKind::Orb, 4, vec![7; 8]).unwrap();
        assert!(pool.append(&orb).is_err());
        let akaze = Descriptors::from_bytes(FeatureKind::Akaze, 4, vec![7; 8]).unwrap();
        let mut orb2 = orb.clone();
        assert!(orb2.append(&akaze).is_err());
        assert_eq!(orb.binary_row(1), Some(&[7u8; 4][..]));
        assert_eq!(orb.float_row(0), None);
        assert!(Descriptors::from_bytes(FeatureKind::Sift, 4, vec![0; 4]).is_err());
        assert!(Descriptors::from_f32(FeatureKind::Orb, 4, vec![0.0; 4]).is_err());
        assert!(Descriptors::from_f32(FeatureKind::Sift, 3, vec![0.0; 4]).is_err());
        assert!(Descriptors::from_f32(FeatureKind::Sift, 1, vec![f32::NAN]).is_err());
    }

    #[test]
    #[should_panic(expected = "out of range")]
    fn select_out_of_range_panics() {
        Descriptors::from_bytes(FeatureKind::Orb, 2, vec![0; 4])
            .unwrap()
            .select(&[2]);
    }
}
