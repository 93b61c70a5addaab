//! Reading and writing PNG images with errors that name the file.

use std::path::Path;

use image::{DynamicImage, ImageReader};
use ndarray::{Array2, Array3};

use super::{DepthMap, RgbImage};
use crate::error::{Error, Result};
use crate::io::write_atomic;

fn open(path: &Path) -> Result<DynamicImage> {
    let reader = ImageReader::open(path).map_err(|e| Error::io(path, e))?;
    let reader = reader.with_guessed_format().map_err(|e| Error::io(path, e))?;
    reader.decode().map_err(|e| Error::bad_file(path, format!("cannot decode image: {e}")))
}

/// Width and height from the file header, without decoding the pixels.
///
/// # Errors
/// [`Error::Io`] if the file cannot be read, [`Error::BadFile`] if it is not an image.
pub fn read_dimensions(path: &Path) -> Result<(usize, usize)> {
    let reader = ImageReader::open(path).map_err(|e| Error::io(path, e))?;
    let reader = reader.with_guessed_format().map_err(|e| Error::io(path, e))?;
    let (w, h) = reader
        .into_dimensions()
        .map_err(|e| Error::bad_file(path, format!("cannot read image header: {e}")))?;
    Ok((w as usize, h as usize))
}

/// Load an 8-bit colour (RGB or RGBA, alpha dropped) or grey (replicated) image as `[H, W, 3]` in
/// `0..=255`.
///
/// # Errors
/// [`Error::Io`] if unreadable, [`Error::BadFile`] if undecodable (e.g. truncated) or 16-bit.
pub fn load_rgb(path: &Path) -> Result<RgbImage> {
    let img = open(path)?;
    let rgb = match &img {
        DynamicImage::ImageRgb8(_)
        | DynamicImage::ImageRgba8(_)
        | DynamicImage::ImageLuma8(_)
        | DynamicImage::ImageLumaA8(_) => img.to_rgb8(),
        other => {
            return Err(Error::bad_file(
                path,
                format!("colour image must be 8-bit RGB, RGBA or grey, got {:?}", other.color()),
            ))
        }
    };
    let (w, h) = (rgb.width() as usize, rgb.height() as usize);
    let data: Vec<f32> = rgb.into_raw().into_iter().map(f32::from).collect();
    Array3::from_shape_vec((h, w, 3), data)
        .map_err(|e| Error::bad_file(path, format!("bad image shape: {e}")))
}

/// Load a 16-bit single-channel depth PNG and convert it to metres: `z = value * metres_per_unit`
/// (TUM: 1/5000, millimetre formats: 1/1000). `0` stays `0` (invalid); so does `invalid_value`
/// when given (7-Scenes stores 65535 for "no depth").
///
/// # Errors
/// [`Error::BadFile`] if the image is not 16-bit grey (a common mistake is an 8-bit export).
pub fn load_depth_png(path: &Path, metres_per_unit: f64, invalid_value: Option<u16>) -> Result<DepthMap> {
    let img = open(path)?;
    let DynamicImage::ImageLuma16(buf) = img else {
        return Err(Error::bad_file(path, format!("depth image must be 16-bit grey, got {:?}", img.color())));
    };
    let (w, h) = (buf.width() as usize, buf.height() as usize);
    let data: Vec<f32> = buf
        .into_raw()
        .into_iter()
        .map(|v| if v == 0 || Some(v) == invalid_value { 0.0 } else { (v as f64 * metres_per_unit) as f32 })
        .collect();
    Array2::from_shape_vec((h, w), data).map_err(|e| Error::bad_file(path, format!("bad image shape: {e}")))
}

fn encode_png(path: &Path, img: DynamicImage) -> Result<Vec<u8>> {
    let mut bytes = Vec::new();
    img.write_to(&mut std::io::Cursor::new(&mut bytes), image::ImageFormat::Png)
        .map_err(|e| Error::bad_file(path, format!("cannot encode PNG: {e}")))?;
    Ok(bytes)
}

/// Save `[H, W, 3]` (values rounded and clamped to `0..=255`) as an 8-bit RGB PNG, atomically.
///
/// # Errors
/// [`Error::Io`] on a write failure; [`Error::InvalidArgument`] if the array is not `[H, W, 3]`.
pub fn save_rgb_png(path: &Path, rgb: &RgbImage) -> Result<()> {
    let (h, w, c) = rgb.dim();
    if c != 3 {
        return Err(Error::invalid_argument("image", format!("expected 3 channels, got {c}")));
    }
    let data: Vec<u8> = rgb.iter().map(|&v| v.round().clamp(0.0, 255.0) as u8).collect();
    let buf = image::RgbImage::from_raw(w as u32, h as u32, data)
        .ok_or_else(|| Error::invalid_argument("image", "buffer size does not match its shape"))?;
    write_atomic(path, &encode_png(path, DynamicImage::ImageRgb8(buf))?)
}

/// Save a depth map as a 16-bit PNG in millimetres (rounded; invalid and out-of-range values
/// become 0), atomically.
///
/// # Errors
/// [`Error::Io`] on a write failure.
pub fn save_depth_png_mm(path: &Path, depth: &DepthMap) -> Result<()> {
    let (h, w) = depth.dim();
    let data: Vec<u16> = depth
        .iter()
        .map(|&z| {
            let mm = (z as f64 * 1000.0).round();
            if super::is_valid_depth(z) && mm >= 1.0 && mm <= u16::MAX as f64 {
                mm as u16
            } else {
                0
            }
        })
        .collect();
    let buf = image::ImageBuffer::<image::Luma<u16>, Vec<u16>>::from_raw(w as u32, h as u32, data)
        .ok_or_else(|| Error::invalid_argument("depth", "buffer size does not match its shape"))?;
    write_atomic(path, &encode_png(path, DynamicImage::ImageLuma16(buf))?)
}
