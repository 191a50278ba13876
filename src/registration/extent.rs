//! Checks of two clouds' extents before registration: a voxel that swallows the clouds, and clouds in
//! different units.

use crate::error::{Error, Result};
use crate::geometry::PointCloud;

/// Ratio of bounding-box diagonals beyond which two clouds are taken to be in different units.
const UNITS_RATIO: f64 = 20.0;

/// What [`check_extents`] found that the user should hear about.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ExtentNotes {
    /// The clouds seem to be in different units (millimetres vs metres).
    pub units: Option<String>,
    /// The voxel is a large fraction of the clouds' extent.
    pub big_voxel: Option<String>,
}

/// Errors when `voxel` is at least the smaller cloud's bounding-box diagonal (every cloud would shrink to a
/// few voxels); otherwise notes a units mismatch (extents differing more than 20x) and a voxel above 1/20
/// of the smaller extent.
pub fn check_extents(
    source: &PointCloud,
    target: &PointCloud,
    voxel: Option<f64>,
) -> Result<ExtentNotes> {
    let (es, et) = (source.extent(), target.extent());
    if let Some(v) = voxel {
        if v >= es.min(et) {
            return Err(Error::InvalidInput(format!(
                "voxel {v} exceeds the extent of the clouds (bounding-box diagonal: SOURCE {es:.6}, \
                 TARGET {et:.6}, cloud units): every cloud would shrink to a few voxels; choose a voxel \
                 well below the extent, or leave --voxel out to choose it from the data"
            )));
        }
    }
    let big_voxel = voxel.filter(|v| *v > es.min(et) / UNITS_RATIO).map(|v| {
        format!(
            "voxel {v} is a large fraction of the clouds' extent (bounding-box diagonal: SOURCE {es:.6}, \
             TARGET {et:.6}): the downsampled clouds keep little geometry; try a smaller --voxel"
        )
    });
    Ok(ExtentNotes {
        units: scale_mismatch(es, et),
        big_voxel,
    })
}

/// The warning when two clouds' extents differ by more than 20x: most likely one is in millimetres and the
/// other in metres.
pub fn scale_mismatch(source_extent: f64, target_extent: f64) -> Option<String> {
    let (lo, hi) = if source_extent < target_extent {
        (source_extent, target_extent)
    } else {
        (target_extent, source_extent)
    };
    // Written so that NaN extents give no warning.
    if !(lo > 0.0 && hi / lo > UNITS_RATIO) {
        return None;
    }
    Some(format!(
        "the extents of SOURCE ({source_extent:.6}) and TARGET ({target_extent:.6}) differ {:.0}x \
         (bounding-box diagonals, cloud units): are they in different units (millimetres vs metres)? \
         Registration is rigid and does not change scale; convert one cloud first",
        hi / lo
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cube(side: f32) -> PointCloud {
        PointCloud::from_points(
            (0..8)
                .map(|i| {
                    [
                        (i & 1) as f32 * side,
                        ((i >> 1) & 1) as f32 * side,
                        ((i >> 2) & 1) as f32 * side,
                    ]
                })
                .collect(),
        )
    }

    #[test]
    fn units_mismatch_and_voxels() {
        let (m, mm) = (cube(1.0), cube(1000.0));
        assert!(check_extents(&m, &mm, None).unwrap().units.is_some());
        assert_eq!(check_extents(&m, &m, None).unwrap(), ExtentNotes::default());
        assert!(check_extents(&m, &m, Some(2.0)).is_err());
        assert!(check_extents(&m, &m, Some(0.5))
            .unwrap()
            .big_voxel
            .is_some());
        assert!(scale_mismatch(0.0, 1.0).is_none());
        assert!(scale_mismatch(f64::NAN, 1.0).is_none());
    }
}
