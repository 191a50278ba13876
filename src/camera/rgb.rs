//! 8-bit RGB images (colour frames of a camera) and writing them as PNG.

use crate::error::{Error, Result};
use std::path::Path;

/// An 8-bit RGB image, row-major from the top-left pixel.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct RgbImage {
    /// Width, pixels.
    pub width: u32,
    /// Height, pixels.
    pub height: u32,
    /// `width * height * 3` bytes, R G B per pixel.
    pub data: Vec<u8>,
}

impl RgbImage {
    /// The grey value (Rec. 601 luma) of every pixel.
    pub fn to_grey(&self) -> Vec<u8> {
        self.data
            .chunks_exact(3)
            .map(|c| {
                ((299 * c[0] as u32 + 587 * c[1] as u32 + 114 * c[2] as u32 + 500) / 1000) as u8
            })
            .collect()
    }
}

/// Writes an 8-bit RGB PNG atomically.
pub fn write_rgb_png(path: impl AsRef<Path>, img: &RgbImage) -> Result<()> {
    let path = path.as_ref();
    if img.data.len() != img.width as usize * img.height as usize * 3 {
        return Err(Error::InvalidInput(format!(
            "{}: colour image has {} bytes for {}x{} pixels",
            path.display(),
            img.data.len(),
            img.width,
            img.height
        )));
    }
    crate::io::write_atomically(path, |w| {
        let mut enc = png::Encoder::new(w, img.width, img.height);
        enc.set_color(png::ColorType::Rgb);
        enc.set_depth(png::BitDepth::Eight);
        enc.set_compression(png::Compression::Fast);
        let mut writer = enc.write_header().map_err(std::io::Error::other)?;
        writer
            .write_image_data(&img.data)
            .map_err(std::io::Error::other)?;
        writer.finish().map_err(std::io::Error::other)
    })
}
