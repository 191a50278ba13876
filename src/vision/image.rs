//! 8-bit grey images: reading any format OpenCV decodes (PNG, JPEG, BMP, TIFF, ...), colour converted to
//! grey (ITU-R 601 luma).

use super::cv;
use crate::error::{Error, Result};
use opencv::core::Mat;
use opencv::prelude::*;
use std::path::Path;

/// An 8-bit grey image, row-major from the top-left pixel.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct GreyImage {
    /// Width, pixels.
    pub width: u32,
    /// Height, pixels.
    pub height: u32,
    /// `width · height` grey values.
    pub data: Vec<u8>,
}

impl GreyImage {
    /// An image from its grey values; errors when the length does not match the size.
    pub fn new(width: u32, height: u32, data: Vec<u8>) -> Result<Self> {
        if width == 0 || height == 0 || data.len() != width as usize * height as usize {
            return Err(Error::InvalidInput(format!(
                "grey image of {width}x{height} pixels needs {} values, found {}",
                width as usize * height as usize,
                data.len()
            )));
        }
        Ok(GreyImage {
            width,
            height,
            data,
        })
    }

    /// The grey value at pixel `(u, v)` (no bounds check beyond the slice's).
    pub fn at(&self, u: u32, v: u32) -> u8 {
        self.data[(v * self.width + u) as usize]
    }

    /// The image as an OpenCV `CV_8UC1` matrix (a copy).
    pub(crate) fn to_mat(&self) -> Result<Mat> {
        let m = Mat::new_rows_cols_with_data(self.height as i32, self.width as i32, &self.data)
            .map_err(|e| cv::error("wrapping a grey image", e))?;
        m.try_clone()
            .map_err(|e| cv::error("copying a grey image", e))
    }
}

/// Reads an image file as 8-bit grey (colour images are converted with the ITU-R 601 luma weights).
/// Errors name the file: missing, unreadable, or not an image OpenCV can decode.
pub fn read_grey_image(path: impl AsRef<Path>) -> Result<GreyImage> {
    let path = path.as_ref();
    if !path.is_file() {
        return Err(Error::io(
            path,
            std::io::Error::new(std::io::ErrorKind::NotFound, "no such image file"),
        ));
    }
    let name = path.to_str().ok_or_else(|| {
        Error::format(path, "the file name is not valid UTF-8, which OpenCV needs")
    })?;
    let m = opencv::imgcodecs::imread(name, opencv::imgcodecs::IMREAD_GRAYSCALE)
        .map_err(|e| Error::format(path, format!("cannot read the image: {e}")))?;
    if m.empty() {
        return Err(Error::format(
            path,
            "not an image OpenCV can decode (expected PNG, JPEG, BMP, TIFF, ...)",
        ));
    }
    let (w, h) = (m.cols() as u32, m.rows() as u32);
    let m = if m.is_continuous() {
        m
    } else {
        m.try_clone()
            .map_err(|e| Error::format(path, e.to_string()))?
    };
    let data = m
        .data_bytes()
        .map_err(|e| Error::format(path, format!("unexpected image layout: {e}")))?
        .to_vec();
    GreyImage::new(w, h, data).map_err(|e| Error::format(path, e.to_string()))
}
