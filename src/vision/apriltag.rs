//! AprilTag 3's own detector for the AprilTag families: the C library that the `apriltag-sys` crate builds
//! from its bundled source (AprilTag 3.4.5; `.cargo/config.toml` sets `APRILTAG_SYS_METHOD=raw,static` so
//! that a system `libapriltag` of another version is never linked instead).
//!
//! # Conventions of the C library, and what this module returns
//!
//! * *Pixels*: AprilTag puts the centre of pixel `(i, j)` at `(i + 0.5, j + 0.5)` (its line fit adds 0.5
//!   "for pixel center bias", `apriltag_quad_thresh.c`; edge refinement subtracts it again before sampling).
//!   The crate's convention is OpenCV's, centre of pixel `(i, j)` at `(i, j)`, so every coordinate is
//!   returned as `x_opencv = x_apriltag − 0.5`, `y_opencv = y_apriltag − 0.5`. Measured: on synthetic
//!   markers with known corners (unit tests in `markers.rs`) the converted corners are within 0.015 px;
//!   on the AprilTag regression images they agree with OpenCV's contour-refined corners to a median of
//!   (−0.07, +0.02) px (tests/markers_real.rs), where the unconverted ones would be off by +0.5 px.
//! * *Corner order*: `p[k]` is the homography image of tag point `(−1, 1)`, `(1, 1)`, `(1, −1)`,
//!   `(−1, −1)` for `k = 0..3`, in AprilTag's tag frame whose `y` points *down* its tag image:
//!   bottom-left, bottom-right, top-right, top-left of AprilTag's own image. OpenCV draws the AprilTag
//!   families turned by a half turn, so this is top-right, top-left, bottom-left, bottom-right of the
//!   marker as OpenCV draws it (counter-clockwise on the screen), which
//!   [`CornerOrder::AprilTag`](super::markers::CornerOrder::AprilTag) names.
//!
//! The unsafe code is confined to this file: every C object is owned by a guard that frees it.

use super::image::GreyImage;
use crate::cell::MarkerDictionary;
use crate::error::{Error, Result};
use apriltag_sys as sys;
use nalgebra::Point2;
use serde::{Deserialize, Serialize};

// tag36h10 is compiled into the bundled library, but apriltag-sys 0.4 generates no binding for it.
extern "C" {
    fn tag36h10_create() -> *mut sys::apriltag_family_t;
    fn tag36h10_destroy(tf: *mut sys::apriltag_family_t);
}

/// Settings of AprilTag's detector (its `apriltag_detector_t` fields).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct AprilTagConfig {
    /// Quad detection on an image decimated by this factor (AprilTag's `quad_decimate`). Default 1 (full
    /// resolution; small tags of ~15 px need it). Larger is faster for large tags; corners are then
    /// refined on the full image when `refine_edges` is set.
    pub quad_decimate: f32,
    /// Gaussian blur of the quad detection image, pixels (AprilTag's `quad_sigma`; negative sharpens).
    /// Default 0.
    pub quad_sigma: f32,
    /// Refine each tag edge on the full-resolution gradient (AprilTag's `refine_edges`). Default true:
    /// sub-pixel edges, whose intersections are the corners.
    pub refine_edges: bool,
    /// Sharpening of the decoded bit image (AprilTag's `decode_sharpening`). Default 0.25.
    pub decode_sharpening: f64,
    /// Most bit errors corrected when decoding (AprilTag's `bits_corrected`), at most 3. Default 2 (the
    /// decode table is built once per thread and family: ~40 ms for tag36h11 at 2 bits, over 1 s at 3).
    pub max_hamming: u32,
    /// Detections whose decision margin (AprilTag's mean bit contrast, grey levels) is below this are
    /// dropped. Default 0 (keep all that decode).
    pub min_decision_margin: f64,
}

impl Default for AprilTagConfig {
    fn default() -> Self {
        AprilTagConfig {
            quad_decimate: 1.0,
            quad_sigma: 0.0,
            refine_edges: true,
            decode_sharpening: 0.25,
            max_hamming: 2,
            min_decision_margin: 0.0,
        }
    }
}

/// One tag as AprilTag reports it, converted to the crate's pixel convention.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct AprilTagHit {
    /// The tag id.
    pub id: u32,
    /// Corners in AprilTag's order (see the module documentation), pixels, OpenCV convention.
    pub corners: [Point2<f64>; 4],
}

/// A tag family object and its destructor.
struct Family {
    ptr: *mut sys::apriltag_family_t,
    destroy: unsafe extern "C" fn(*mut sys::apriltag_family_t),
}

impl Family {
    fn new(dict: MarkerDictionary) -> Result<Self> {
        type Ctor = unsafe extern "C" fn() -> *mut sys::apriltag_family_t;
        type Dtor = unsafe extern "C" fn(*mut sys::apriltag_family_t);
        let (create, destroy): (Ctor, Dtor) = match dict {
            MarkerDictionary::AprilTag16h5 => (sys::tag16h5_create, sys::tag16h5_destroy),
            MarkerDictionary::AprilTag25h9 => (sys::tag25h9_create, sys::tag25h9_destroy),
            MarkerDictionary::AprilTag36h10 => (tag36h10_create, tag36h10_destroy),
            MarkerDictionary::AprilTag36h11 => (sys::tag36h11_create, sys::tag36h11_destroy),
            d => {
                return Err(Error::InvalidInput(format!(
                    "AprilTag's detector reads the AprilTag families only, not {d} (use the OpenCV detector)"
                )))
            }
        };
        // SAFETY: the family constructors take no arguments and return an owned object or null.
        let ptr = unsafe { create() };
        if ptr.is_null() {
            return Err(Error::Failed(format!(
                "AprilTag: cannot create the {dict} family"
            )));
        }
        Ok(Family { ptr, destroy })
    }
}

impl Drop for Family {
    fn drop(&mut self) {
        // SAFETY: `ptr` came from the matching constructor and is freed once; the detector that used it
        // is dropped before (see `detect`).
        unsafe { (self.destroy)(self.ptr) }
    }
}

struct Detector(*mut sys::apriltag_detector_t);

impl Drop for Detector {
    fn drop(&mut self) {
        // SAFETY: created by apriltag_detector_create, freed once.
        unsafe { sys::apriltag_detector_destroy(self.0) }
    }
}

struct Image(*mut sys::image_u8_t);

impl Drop for Image {
    fn drop(&mut self) {
        // SAFETY: created by image_u8_create, freed once.
        unsafe { sys::image_u8_destroy(self.0) }
    }
}

struct Detections(*mut sys::zarray_t);

impl Drop for Detections {
    fn drop(&mut self) {
        // SAFETY: returned by apriltag_detector_detect, freed once with its detections.
        unsafe { sys::apriltag_detections_destroy(self.0) }
    }
}

impl AprilTagConfig {
    /// Checks the settings; the error names the field (`apriltag.…`).
    pub fn validate(&self) -> Result<()> {
        let cfg = self;
        let bad = |field: &str, msg: &str| {
            Err(Error::Config {
                field: format!("apriltag.{field}"),
                msg: msg.into(),
            })
        };
        if !(cfg.quad_decimate >= 1.0 && cfg.quad_decimate <= 16.0) {
            return bad("quad_decimate", "must be between 1 and 16");
        }
        if !cfg.quad_sigma.is_finite() || cfg.quad_sigma.abs() > 10.0 {
            return bad("quad_sigma", "must be between -10 and 10 pixels");
        }
        if !(0.0..=10.0).contains(&cfg.decode_sharpening) {
            return bad("decode_sharpening", "must be between 0 and 10");
        }
        if cfg.max_hamming > 3 {
            return bad(
                "max_hamming",
                "AprilTag corrects at most 3 bits (its decode table grows too large beyond)",
            );
        }
        if !cfg.min_decision_margin.is_finite() {
            return bad("min_decision_margin", "must be a number");
        }
        Ok(())
    }
}

/// A detector with its family added; the detector is declared first so that it is dropped (and lets go
/// of the family's decode table) before the family.
struct Prepared {
    det: Detector,
    family: Family,
    dict: MarkerDictionary,
    max_hamming: u32,
}

impl Prepared {
    fn new(dict: MarkerDictionary, max_hamming: u32) -> Result<Self> {
        let family = Family::new(dict)?;
        // SAFETY: plain constructor; null on allocation failure.
        let det = Detector(unsafe { sys::apriltag_detector_create() });
        if det.0.is_null() {
            return Err(Error::Failed("AprilTag: cannot create a detector".into()));
        }
        // SAFETY: both objects are valid; the family outlives the detector (field order of `Prepared`).
        unsafe { sys::apriltag_detector_add_family_bits(det.0, family.ptr, max_hamming as i32) };
        Ok(Prepared {
            det,
            family,
            dict,
            max_hamming,
        })
    }
}

thread_local! {
    /// The last detector used on this thread: building a family's decode table (tag36h11 correcting 2
    /// bits: ~390,000 entries) takes longer than detecting the tags in a VGA image, so it is kept.
    static PREPARED: std::cell::RefCell<Option<Prepared>> = const { std::cell::RefCell::new(None) };
}

/// Every tag of family `dict` that AprilTag's detector finds in `img` (in the detector's order).
pub(crate) fn detect_apriltags(
    img: &GreyImage,
    dict: MarkerDictionary,
    cfg: &AprilTagConfig,
) -> Result<Vec<AprilTagHit>> {
    cfg.validate()?;
    PREPARED.with(|cell| {
        let mut slot = cell.borrow_mut();
        if !matches!(&*slot, Some(p) if p.dict == dict && p.max_hamming == cfg.max_hamming) {
            *slot = None;
            *slot = Some(Prepared::new(dict, cfg.max_hamming)?);
        }
        let p = slot.as_ref().expect("prepared above");
        detect_with(p, img, cfg)
    })
}

fn detect_with(p: &Prepared, img: &GreyImage, cfg: &AprilTagConfig) -> Result<Vec<AprilTagHit>> {
    let det = p.det.0;
    debug_assert!(!p.family.ptr.is_null());
    // SAFETY: `det` is a valid detector used by this thread only.
    unsafe {
        let d = &mut *det;
        d.nthreads = 1;
        d.quad_decimate = cfg.quad_decimate;
        d.quad_sigma = cfg.quad_sigma;
        d.refine_edges = cfg.refine_edges;
        d.decode_sharpening = cfg.decode_sharpening;
    }
    // SAFETY: image_u8_create returns an owned image (or null) with `stride >= width`.
    let im = Image(unsafe { sys::image_u8_create(img.width, img.height) });
    if im.0.is_null() {
        return Err(Error::Failed(format!(
            "AprilTag: cannot allocate a {}x{} image",
            img.width, img.height
        )));
    }
    let w = img.width as usize;
    // SAFETY: `buf` holds `height` rows of `stride` bytes; each row copy writes `width <= stride` bytes.
    unsafe {
        let m = &*im.0;
        for (r, row) in img.data.chunks_exact(w).enumerate() {
            let dst = m.buf.add(r * m.stride as usize);
            std::ptr::copy_nonoverlapping(row.as_ptr(), dst, w);
        }
    }
    // SAFETY: detector and image are valid; the result is an owned zarray of detection pointers.
    let found = Detections(unsafe { sys::apriltag_detector_detect(det, im.0) });
    if found.0.is_null() {
        return Err(Error::Failed(
            "AprilTag: the detector returned nothing".into(),
        ));
    }
    let mut out = Vec::new();
    // SAFETY: the zarray holds `size` elements of `el_sz` bytes, each a valid `*mut apriltag_detection_t`.
    unsafe {
        let z = &*found.0;
        for i in 0..z.size.max(0) as usize {
            let q = z.data.add(i * z.el_sz) as *const *const sys::apriltag_detection_t;
            let d = &**q;
            if d.id < 0 || (d.decision_margin as f64) < cfg.min_decision_margin {
                continue;
            }
            let c = |k: usize| Point2::new(d.p[k][0] - 0.5, d.p[k][1] - 0.5);
            out.push(AprilTagHit {
                id: d.id as u32,
                corners: [c(0), c(1), c(2), c(3)],
            });
        }
    }
    Ok(out)
}

/// AprilTag's own rendering of tag `id` of family `dict`: `total_width²` grey values (0 black, 255 white),
/// row-major, with the outer white frame; for cross-checking OpenCV's tables.
#[cfg(test)]
pub(crate) fn apriltag_image(dict: MarkerDictionary, id: u32) -> Result<(u32, Vec<u8>)> {
    let family = Family::new(dict)?;
    // SAFETY: `ncodes` is read from a valid family; `apriltag_to_image` asserts `id < ncodes`, checked here.
    unsafe {
        if id >= (*family.ptr).ncodes {
            return Err(Error::InvalidInput(format!("{dict} has no tag {id}")));
        }
        let im = Image(sys::apriltag_to_image(family.ptr, id));
        let m = &*im.0;
        let n = m.width as usize;
        let mut v = Vec::with_capacity(n * n);
        for r in 0..m.height as usize {
            let row = std::slice::from_raw_parts(m.buf.add(r * m.stride as usize), n);
            v.extend_from_slice(row);
        }
        Ok((n as u32, v))
    }
}
