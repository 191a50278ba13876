//! Depth images: 16-bit PNG I/O and deprojection to camera-frame points.

use super::intrinsics::Intrinsics;
use crate::error::{Error, Result};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::io::BufReader;
use std::path::Path;

/// A depth image: `width × height` raw 16-bit depth units, row-major from the top-left pixel.
///
/// Multiply a value by the camera's `depth_scale` to get metres along the optical axis; 0 means no data.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct DepthImage {
    /// Width, pixels.
    pub width: u32,
    /// Height, pixels.
    pub height: u32,
    /// Raw depth units, `width * height` values, row-major.
    pub data: Vec<u16>,
}

impl DepthImage {
    /// An all-zero (no data) image.
    pub fn zeros(width: u32, height: u32) -> Self {
        DepthImage {
            width,
            height,
            data: vec![0; width as usize * height as usize],
        }
    }

    /// The raw value at column `u`, row `v`.
    #[inline]
    pub fn get(&self, u: u32, v: u32) -> u16 {
        self.data[v as usize * self.width as usize + u as usize]
    }

    /// Number of non-zero pixels.
    pub fn valid_count(&self) -> usize {
        self.data.iter().filter(|&&d| d != 0).count()
    }
}

fn describe(color: png::ColorType, depth: png::BitDepth) -> String {
    let bits = match depth {
        png::BitDepth::One => 1,
        png::BitDepth::Two => 2,
        png::BitDepth::Four => 4,
        png::BitDepth::Eight => 8,
        png::BitDepth::Sixteen => 16,
    };
    let kind = match color {
        png::ColorType::Grayscale => "greyscale",
        png::ColorType::Rgb => "RGB colour",
        png::ColorType::Indexed => "palette colour",
        png::ColorType::GrayscaleAlpha => "greyscale+alpha",
        png::ColorType::Rgba => "RGBA colour",
    };
    format!("{bits}-bit {kind}")
}

/// The most a deflate stream expands (about 1032:1), with room for the zlib and PNG framing.
const DEFLATE_MAX_RATIO: u64 = 1100;

fn open_depth_png<R: std::io::BufRead + std::io::Seek>(
    path: &Path,
    input: R,
    file_len: u64,
) -> Result<(png::Reader<R>, u32, u32)> {
    let mut decoder = png::Decoder::new(input);
    decoder.set_transformations(png::Transformations::IDENTITY);
    let reader = decoder
        .read_info()
        .map_err(|e| Error::format(path, format!("not a readable PNG: {e}")))?;
    let info = reader.info();
    let (w, h, ct, bd) = (info.width, info.height, info.color_type, info.bit_depth);
    if ct != png::ColorType::Grayscale || bd != png::BitDepth::Sixteen {
        return Err(Error::format(
            path,
            format!(
                "expected a 16-bit greyscale depth PNG, found a {} PNG ({w}x{h}); depth images must store \
                 raw 16-bit depth units",
                describe(ct, bd)
            ),
        ));
    }
    super::intrinsics::check_image_size(w, h)
        .map_err(|m| Error::format(path, format!("PNG header (IHDR width, height): {m}")))?;
    let raw = h as u64 * (1 + 2 * w as u64);
    if raw > file_len.saturating_mul(DEFLATE_MAX_RATIO) {
        return Err(Error::format(
            path,
            format!(
                "PNG header (IHDR width, height) says {w}x{h} pixels ({raw} bytes), which {file_len} bytes of \
                 compressed data cannot hold: the file is truncated or corrupt"
            ),
        ));
    }
    Ok((reader, w, h))
}

fn open_depth_png_file(path: &Path) -> Result<(png::Reader<BufReader<std::fs::File>>, u32, u32)> {
    let file = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
    let len = file.metadata().map_err(|e| Error::io(path, e))?.len();
    open_depth_png(path, BufReader::new(file), len)
}

/// Reads only the header of a depth PNG and checks it is 16-bit greyscale of a sane size (see
/// [`crate::camera::intrinsics::check_image_size`]); returns `(width, height)`.
pub fn read_depth_png_header(path: impl AsRef<Path>) -> Result<(u32, u32)> {
    let (_, w, h) = open_depth_png_file(path.as_ref())?;
    Ok((w, h))
}

/// Reads a 16-bit single-channel (greyscale) PNG depth image.
///
/// Any other PNG kind (8-bit, colour, alpha, palette), a size beyond the limits or one the file's length
/// cannot hold is an error naming the file and what was found.
pub fn read_depth_png(path: impl AsRef<Path>) -> Result<DepthImage> {
    let path = path.as_ref();
    let (reader, w, h) = open_depth_png_file(path)?;
    decode_depth_png(path, reader, w, h)
}

/// Parses the bytes of a depth PNG (as [`read_depth_png`]); `name` names it in errors.
pub fn parse_depth_png(bytes: &[u8], name: impl AsRef<Path>) -> Result<DepthImage> {
    let path = name.as_ref();
    let (reader, w, h) = open_depth_png(path, std::io::Cursor::new(bytes), bytes.len() as u64)?;
    decode_depth_png(path, reader, w, h)
}

fn decode_depth_png<R: std::io::BufRead + std::io::Seek>(
    path: &Path,
    mut reader: png::Reader<R>,
    w: u32,
    h: u32,
) -> Result<DepthImage> {
    let size = reader
        .output_buffer_size()
        .ok_or_else(|| Error::format(path, "PNG image is too large"))?;
    let mut buf = vec![0u8; size];
    let out = reader
        .next_frame(&mut buf)
        .map_err(|e| Error::format(path, format!("corrupt PNG data: {e}")))?;
    let row = out.line_size;
    if row < 2 * w as usize || buf.len() < row * h as usize {
        return Err(Error::format(
            path,
            format!(
                "PNG frame of {} bytes per row does not hold {w}x{h} 16-bit pixels",
                row
            ),
        ));
    }
    let mut data = Vec::with_capacity(w as usize * h as usize);
    for r in 0..h as usize {
        let line = &buf[r * row..r * row + 2 * w as usize];
        data.extend(
            line.chunks_exact(2)
                .map(|b| u16::from_be_bytes([b[0], b[1]])),
        );
    }
    Ok(DepthImage {
        width: w,
        height: h,
        data,
    })
}

/// Writes a 16-bit greyscale PNG depth image, atomically (temporary file, then rename).
pub fn write_depth_png(path: impl AsRef<Path>, img: &DepthImage) -> Result<()> {
    let path = path.as_ref();
    if img.data.len() != img.width as usize * img.height as usize
        || img.width == 0
        || img.height == 0
    {
        return Err(Error::InvalidInput(format!(
            "{}: depth image has {} values for {}x{} pixels",
            path.display(),
            img.data.len(),
            img.width,
            img.height
        )));
    }
    let mut bytes = Vec::with_capacity(img.data.len() * 2);
    for d in &img.data {
        bytes.extend_from_slice(&d.to_be_bytes());
    }
    crate::io::write_atomically(path, |w| {
        let mut enc = png::Encoder::new(w, img.width, img.height);
        enc.set_color(png::ColorType::Grayscale);
        enc.set_depth(png::BitDepth::Sixteen);
        enc.set_compression(png::Compression::Fast);
        let mut writer = enc.write_header().map_err(std::io::Error::other)?;
        writer
            .write_image_data(&bytes)
            .map_err(std::io::Error::other)?;
        writer.finish().map_err(std::io::Error::other)
    })
}

/// Options for turning a depth image into points. Depths are in metres after `depth_scale`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct DeprojectConfig {
    /// Nearest depth kept, metres (default 0.1). Zero depth (no data) is always dropped.
    pub min_depth_m: f64,
    /// Farthest depth kept, metres (default 10.0).
    pub max_depth_m: f64,
    /// Flying-pixel filter: a pixel is dropped when one of its 8 neighbours (with data) differs in depth by
    /// more than this fraction of the pixel's own depth (default 0.03, i.e. 3 cm at 1 m; 0 disables). This
    /// removes the mixed pixels at depth discontinuities and a one-pixel band on both sides of each edge,
    /// while keeping surfaces seen at up to ~85° incidence (at ~600 px focal length).
    pub max_depth_jump: f64,
}

impl Default for DeprojectConfig {
    fn default() -> Self {
        DeprojectConfig {
            min_depth_m: 0.1,
            max_depth_m: 10.0,
            max_depth_jump: 0.03,
        }
    }
}

impl DeprojectConfig {
    /// Checks the ranges; the error names the field.
    pub fn validate(&self) -> Result<()> {
        let bad = |field: &str, msg: String| {
            Err(Error::Config {
                field: format!("deproject.{field}"),
                msg,
            })
        };
        if !(self.min_depth_m.is_finite() && self.min_depth_m >= 0.0) {
            return bad(
                "min_depth_m",
                format!("must be ≥ 0, found {}", self.min_depth_m),
            );
        }
        if self.max_depth_m.is_nan() || self.max_depth_m <= self.min_depth_m {
            return bad(
                "max_depth_m",
                format!(
                    "must exceed min_depth_m ({}), found {}",
                    self.min_depth_m, self.max_depth_m
                ),
            );
        }
        if !(self.max_depth_jump.is_finite() && self.max_depth_jump >= 0.0) {
            return bad(
                "max_depth_jump",
                format!("must be ≥ 0, found {}", self.max_depth_jump),
            );
        }
        Ok(())
    }
}

/// Per-pixel normalised rays `(X/Z, Y/Z)` of a camera, computed once per intrinsics (the distortion model is
/// inverted here, so deprojecting a frame is a multiply per pixel).
#[derive(Clone, Debug)]
pub struct RayTable {
    /// Width, pixels.
    pub width: u32,
    /// Height, pixels.
    pub height: u32,
    /// Metres per depth unit.
    pub depth_scale: f64,
    /// `(X/Z, Y/Z)` per pixel, row-major.
    pub rays: Vec<[f32; 2]>,
}

impl RayTable {
    /// Computes the rays of every pixel of `intr` (parallel over rows).
    pub fn new(intr: &Intrinsics) -> Self {
        let (w, h) = (intr.width as usize, intr.height as usize);
        let mut rays = vec![[0f32; 2]; w * h];
        rays.par_chunks_mut(w).enumerate().for_each(|(v, row)| {
            for (u, r) in row.iter_mut().enumerate() {
                let [x, y] = intr.pixel_ray([u as f64, v as f64]);
                *r = [x as f32, y as f32];
            }
        });
        RayTable {
            width: intr.width,
            height: intr.height,
            depth_scale: intr.depth_scale,
            rays,
        }
    }
}

/// Checks that a depth image has the size the intrinsics say; `what` names the image in the error.
pub fn check_size(img: &DepthImage, rays: &RayTable, what: &Path) -> Result<()> {
    if img.width != rays.width || img.height != rays.height {
        return Err(Error::format(
            what,
            format!(
                "depth image is {}x{} but the intrinsics say {}x{}",
                img.width, img.height, rays.width, rays.height
            ),
        ));
    }
    Ok(())
}

/// Deprojects one row into `out` (camera-frame points, metres).
///
/// The flying-pixel test is done with running minima/maxima: a pixel is flying when the largest depth in
/// its 3x3 neighbourhood exceeds `d + jump·d` or the smallest non-zero one is below `d − jump·d`.
pub(crate) fn deproject_row(
    img: &DepthImage,
    rays: &RayTable,
    cfg: &DeprojectConfig,
    v: usize,
    out: &mut Vec<[f32; 3]>,
) {
    let w = img.width as usize;
    let h = img.height as usize;
    let scale = rays.depth_scale;
    // Raw-unit limits, so the inner loop compares integers.
    let lo = (cfg.min_depth_m / scale).ceil().max(1.0);
    let hi = (cfg.max_depth_m / scale).floor();
    let lo = lo.min(u16::MAX as f64 + 1.0) as u32;
    let hi = hi.clamp(0.0, u16::MAX as f64) as u32;
    let jump = cfg.max_depth_jump as f32;
    let row = &img.data[v * w..(v + 1) * w];
    let ray_row = &rays.rays[v * w..(v + 1) * w];
    let scale = scale as f32;
    if jump > 0.0 {
        let up = &img.data[v.saturating_sub(1) * w..(v.saturating_sub(1) + 1) * w];
        let dn = &img.data[(v + 1).min(h - 1) * w..((v + 1).min(h - 1) + 1) * w];
        // Column-wise max and non-zero min over the three rows.
        let nz = |x: u16| if x == 0 { u16::MAX } else { x };
        let mut vmax = vec![0u16; w];
        let mut vmin = vec![0u16; w];
        for u in 0..w {
            vmax[u] = up[u].max(row[u]).max(dn[u]);
            vmin[u] = nz(up[u]).min(nz(row[u])).min(nz(dn[u]));
        }
        for u in 0..w {
            let d = row[u] as u32;
            if d < lo || d > hi {
                continue;
            }
            let (a, b) = (u.saturating_sub(1), (u + 1).min(w - 1));
            let mx = vmax[a].max(vmax[u]).max(vmax[b]) as f32;
            let mn = vmin[a].min(vmin[u]).min(vmin[b]) as f32;
            let df = d as f32;
            let limit = jump * df;
            if mx - df > limit || df - mn > limit {
                continue;
            }
            let z = df * scale;
            let r = ray_row[u];
            out.push([r[0] * z, r[1] * z, z]);
        }
    } else {
        for u in 0..w {
            let d = row[u] as u32;
            if d < lo || d > hi {
                continue;
            }
            let z = d as f32 * scale;
            let r = ray_row[u];
            out.push([r[0] * z, r[1] * z, z]);
        }
    }
}

/// Deprojects a depth image to camera-frame points (metres, `f32`), dropping zero depth, depths outside
/// `[min_depth_m, max_depth_m]` and flying pixels (see [`DeprojectConfig`]). Parallel over rows; the output is
/// in row-major pixel order whatever the thread count.
pub fn deproject(
    img: &DepthImage,
    rays: &RayTable,
    cfg: &DeprojectConfig,
) -> Result<Vec<[f32; 3]>> {
    cfg.validate()?;
    check_size(img, rays, Path::new("depth image"))?;
    let w = img.width as usize;
    let rows: Vec<Vec<[f32; 3]>> = (0..img.height as usize)
        .into_par_iter()
        .map(|v| {
            let mut out = Vec::with_capacity(w);
            deproject_row(img, rays, cfg, v, &mut out);
            out
        })
        .collect();
    let n = rows.iter().map(|r| r.len()).sum();
    let mut pts = Vec::with_capacity(n);
    for r in rows {
        pts.extend_from_slice(&r);
    }
    Ok(pts)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::DistortionModel;

    fn tmp(name: &str) -> std::path::PathBuf {
        let d = std::env::temp_dir().join(format!("depthcal-depth-{}-{name}", std::process::id()));
        std::fs::create_dir_all(&d).unwrap();
        d
    }

    #[test]
    fn png_round_trip_and_wrong_kinds() {
        let dir = tmp("png");
        let mut img = DepthImage::zeros(7, 5);
        for (i, d) in img.data.iter_mut().enumerate() {
            *d = (i as u16) * 1000 + 3;
        }
        let p = dir.join("d.png");
        write_depth_png(&p, &img).unwrap();
        assert_eq!(read_depth_png(&p).unwrap(), img);
        // An 8-bit greyscale PNG is refused with a clear message naming the file.
        let p8 = dir.join("eight.png");
        {
            let f = std::fs::File::create(&p8).unwrap();
            let mut enc = png::Encoder::new(std::io::BufWriter::new(f), 4, 3);
            enc.set_color(png::ColorType::Grayscale);
            enc.set_depth(png::BitDepth::Eight);
            let mut w = enc.write_header().unwrap();
            w.write_image_data(&[9u8; 12]).unwrap();
        }
        let e = read_depth_png(&p8).unwrap_err().to_string();
        assert!(
            e.contains("eight.png") && e.contains("8-bit greyscale"),
            "{e}"
        );
        let e = read_depth_png(dir.join("missing.png"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("missing.png"), "{e}");
        std::fs::write(dir.join("junk.png"), b"not a png").unwrap();
        assert!(read_depth_png(dir.join("junk.png")).is_err());
        let _ = std::fs::remove_dir_all(dir);
    }

    #[test]
    fn deprojection_filters_and_matches_the_model() {
        let mut intr = Intrinsics::pinhole(40, 30, 50.0, 52.0, 19.5, 14.5);
        intr.model = DistortionModel::BrownConrady;
        intr.coeffs = [0.1, -0.05, 0.001, 0.002, 0.0];
        let rays = RayTable::new(&intr);
        let mut img = DepthImage::zeros(40, 30);
        for v in 0..30 {
            for u in 0..40 {
                img.data[v * 40 + u] = if u < 20 { 1000 } else { 2000 };
            }
        }
        img.data[5 * 40 + 5] = 0; // hole
        img.data[6 * 40 + 5] = 50; // too near (5 cm)
        let cfg = DeprojectConfig::default();
        let pts = deproject(&img, &rays, &cfg).unwrap();
        // Dropped: the hole, the near pixel, columns 19 and 20 (both sides of the 1 m jump), and the 7 data
        // neighbours of the near pixel (it differs from them by > 3 %); the hole is no neighbour.
        let kept_expected = 40 * 30 - 2 - 2 * 30 - 7;
        assert_eq!(pts.len(), kept_expected);
        // Every point reprojects to an integer pixel with the right depth.
        for p in &pts {
            let px = intr.project([p[0] as f64, p[1] as f64, p[2] as f64]);
            assert!((px[0] - px[0].round()).abs() < 1e-3 && (px[1] - px[1].round()).abs() < 1e-3);
            let expect = if px[0].round() < 20.0 { 1.0 } else { 2.0 };
            assert!((p[2] as f64 - expect).abs() < 1e-6);
        }
        let no_filter = DeprojectConfig {
            max_depth_jump: 0.0,
            ..cfg.clone()
        };
        assert_eq!(
            deproject(&img, &rays, &no_filter).unwrap().len(),
            40 * 30 - 2
        );
        let wrong = DepthImage::zeros(41, 30);
        assert!(deproject(&wrong, &rays, &cfg).is_err());
    }
}
