//! Disparity maps: scaled 8/16-bit PNGs (Middlebury 2001/2003, palette PNGs included) and PFM
//! (Middlebury 2014, ETH3D). Disparity is in pixels; 0 means unknown.

use std::path::Path;

use image::DynamicImage;
use ndarray::Array2;

use super::DisparityEncoding;
use crate::error::{Error, Result};

/// Load a disparity map in pixels; unknown pixels are 0.
///
/// # Errors
/// [`Error::Io`] if unreadable; [`Error::BadFile`] if undecodable, not grey, or (PFM) malformed.
pub fn load_disparity(path: &Path, encoding: DisparityEncoding) -> Result<Array2<f32>> {
    match encoding {
        DisparityEncoding::Pfm => read_pfm(path),
        DisparityEncoding::ScaledPng { scale } => {
            if !(scale > 0.0 && scale.is_finite()) {
                return Err(Error::bad_file(path, format!("disparity scale {scale} must be positive")));
            }
            let img = image::ImageReader::open(path)
                .map_err(|e| Error::io(path, e))?
                .with_guessed_format()
                .map_err(|e| Error::io(path, e))?
                .decode()
                .map_err(|e| Error::bad_file(path, format!("cannot decode disparity image: {e}")))?;
            let (w, h) = (img.width() as usize, img.height() as usize);
            let values: Vec<f32> = match img {
                DynamicImage::ImageLuma8(b) => b.into_raw().into_iter().map(f32::from).collect(),
                DynamicImage::ImageLuma16(b) => b.into_raw().into_iter().map(f32::from).collect(),
                // Palette PNGs decode to RGB; accept them only when the palette is grey.
                DynamicImage::ImageRgb8(b) => {
                    let raw = b.into_raw();
                    if raw.chunks_exact(3).any(|p| p[0] != p[1] || p[1] != p[2]) {
                        return Err(Error::bad_file(
                            path,
                            "disparity image is in colour; expected grey levels",
                        ));
                    }
                    raw.chunks_exact(3).map(|p| f32::from(p[0])).collect()
                }
                other => {
                    return Err(Error::bad_file(
                        path,
                        format!("disparity image must be grey, got {:?}", other.color()),
                    ))
                }
            };
            let data = values.into_iter().map(|v| (v as f64 / scale) as f32).collect();
            Array2::from_shape_vec((h, w), data).map_err(|e| Error::bad_file(path, e.to_string()))
        }
    }
}

/// Read a single-channel PFM (`Pf`) file. Rows are stored bottom-to-top; a negative scale means
/// little-endian. Non-finite values (ETH3D's "inf") become 0.
///
/// # Errors
/// [`Error::BadFile`] for a colour PFM, a malformed header or a short payload.
pub fn read_pfm(path: &Path) -> Result<Array2<f32>> {
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    let mut fields = Vec::new();
    let mut pos = 0;
    // Three whitespace-separated header tokens, then exactly one whitespace byte.
    while fields.len() < 4 && pos < bytes.len() {
        while pos < bytes.len() && bytes[pos].is_ascii_whitespace() {
            pos += 1;
        }
        let start = pos;
        while pos < bytes.len() && !bytes[pos].is_ascii_whitespace() && pos - start < 32 {
            pos += 1;
        }
        fields.push(String::from_utf8_lossy(&bytes[start..pos]).into_owned());
    }
    pos += 1;
    if fields.len() < 4 {
        return Err(Error::bad_file(path, "PFM header is incomplete"));
    }
    match fields[0].as_str() {
        "Pf" => {}
        "PF" => {
            return Err(Error::bad_file(path, "colour PFM (PF); expected a single-channel disparity (Pf)"))
        }
        other => return Err(Error::bad_file(path, format!("not a PFM file (magic {other:?})"))),
    }
    let parse = |s: &str, what: &str| -> Result<usize> {
        s.parse::<usize>()
            .ok()
            .filter(|&v| v > 0 && v <= 1 << 16)
            .ok_or_else(|| Error::bad_file(path, format!("PFM {what} {s:?} is not a size in 1..=65536")))
    };
    let (w, h) = (parse(&fields[1], "width")?, parse(&fields[2], "height")?);
    let scale: f64 = fields[3]
        .parse()
        .map_err(|_| Error::bad_file(path, format!("PFM scale {:?} is not a number", fields[3])))?;
    if scale == 0.0 || !scale.is_finite() {
        return Err(Error::bad_file(path, format!("PFM scale {scale} must be non-zero")));
    }
    let need = w * h * 4;
    let payload = bytes.get(pos..pos + need).ok_or_else(|| {
        Error::bad_file(
            path,
            format!(
                "PFM payload is truncated: {w}x{h} needs {need} bytes, file has {}",
                bytes.len().saturating_sub(pos)
            ),
        )
    })?;
    let little = scale < 0.0;
    let mut out = Array2::<f32>::zeros((h, w));
    for (i, c) in payload.chunks_exact(4).enumerate() {
        let b = [c[0], c[1], c[2], c[3]];
        let v = if little { f32::from_le_bytes(b) } else { f32::from_be_bytes(b) };
        let (row, col) = (h - 1 - i / w, i % w);
        out[[row, col]] = if v.is_finite() && v > 0.0 { v } else { 0.0 };
    }
    Ok(out)
}
