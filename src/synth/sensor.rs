//! The camera of the realistic style ([`Style::Real`](super::Style::Real)), on top of
//! [`Photometric`]: random intrinsics, a white-balance cast, per-frame auto-exposure jitter,
//! signal-dependent (shot) noise, motion blur over a short shutter interval, and a JPEG round trip
//! at a per-frame quality. All of it is drawn from the scene seed or hashed from the frame index,
//! and touches colour only: depth stays the exact ray-cast depth at the frame's pose.
//!
//! A recorded value is `q(g_i j_i V(x, y) w_c L + b_i + sqrt(σ² + k·max(v, 0)) n)` (`v` the value
//! before noise), then the whole frame goes through JPEG encode/decode at quality `Q_i`.

use image::codecs::jpeg::JpegEncoder;
use ndarray::Array3;

use super::photometric::{Exposure, Photometric, PhotometricConfig};
use crate::error::{Error, Result};
use crate::image::RgbImage;
use crate::util::rng::{hash64, hash_unit, SplitMix64};

/// Focal length range, pixels at a 640-pixel-wide image (scaled by `width / 640`).
pub const FOCAL_RANGE_640: (f64, f64) = (300.0, 700.0);
/// Principal-point jitter, as a fraction of the image width (cx) and height (cy).
pub const PRINCIPAL_JITTER: f64 = 0.03;
/// JPEG quality range (inclusive).
pub const JPEG_QUALITY: (u8, u8) = (70, 95);
/// Largest shutter interval, as a fraction of the time between frames.
pub const MAX_SHUTTER: f64 = 0.5;

/// Random pinhole intrinsics `(fx, fy, cx, cy)` for a `width × height` image.
pub fn random_intrinsics(rng: &mut SplitMix64, width: usize, height: usize) -> (f64, f64, f64, f64) {
    let (w, h) = (width as f64, height as f64);
    let f = rng.range(FOCAL_RANGE_640.0, FOCAL_RANGE_640.1) * w / 640.0;
    let cx = (w - 1.0) / 2.0 + PRINCIPAL_JITTER * w * rng.range(-1.0, 1.0);
    let cy = (h - 1.0) / 2.0 + PRINCIPAL_JITTER * h * rng.range(-1.0, 1.0);
    (f, f, cx, cy)
}

/// Random camera-response strengths for the realistic style.
pub fn random_photometric(rng: &mut SplitMix64) -> PhotometricConfig {
    PhotometricConfig {
        gain_amplitude: rng.range(0.1, 0.3),
        bias_amplitude: rng.range(0.0, 4.0),
        vignetting: rng.range(0.15, 0.6),
        noise_sigma: rng.range(0.5, 2.0),
    }
}

/// The realistic-style sensor of one sequence.
#[derive(Clone, Debug, PartialEq)]
pub struct Sensor {
    /// Per-channel gain of the white-balance cast.
    pub white_balance: [f64; 3],
    /// Shot-noise variance per grey level (`k`).
    pub shot_noise: f64,
    /// Half-width of the per-frame auto-exposure jitter `j_i ∈ [1 - a, 1 + a]`.
    pub exposure_jitter: f64,
    /// Shutter interval, fraction of the time between frames (0: no motion blur).
    pub shutter: f64,
    key: u64,
}

impl Sensor {
    /// Draw a sensor from `rng`.
    pub fn random(rng: &mut SplitMix64) -> Self {
        let cast = rng.range(0.0, 0.08);
        let white_balance = [0; 3].map(|_| 1.0 + cast * rng.range(-1.0, 1.0));
        Self {
            white_balance,
            shot_noise: rng.range(0.01, 0.1),
            exposure_jitter: rng.range(0.0, 0.06),
            shutter: rng.range(0.0, MAX_SHUTTER),
            key: rng.next_u64(),
        }
    }

    /// Frame `i`'s auto-exposure factor `j_i`.
    pub fn exposure_factor(&self, i: usize) -> f64 {
        1.0 + self.exposure_jitter * (2.0 * hash_unit(self.key, i as u64, 1, 0) - 1.0)
    }

    /// Frame `i`'s JPEG quality, uniform in [`JPEG_QUALITY`].
    pub fn jpeg_quality(&self, i: usize) -> u8 {
        let span = (JPEG_QUALITY.1 - JPEG_QUALITY.0) as u64 + 1;
        JPEG_QUALITY.0 + (hash64(self.key, i as u64, 2, 0) % span) as u8
    }

    /// Centre of shutter time stratum `k` of `n`, in frames: the strata split
    /// `[-shutter/2, shutter/2]` evenly.
    #[inline]
    pub fn time_offset(&self, k: usize, n: usize) -> f64 {
        self.shutter * ((k as f64 + 0.5) / n as f64 - 0.5)
    }

    /// Per-pixel cyclic shift of the `n` time strata over the sub-pixel samples, so that time does
    /// not follow the sample's position in the pixel.
    #[inline]
    pub fn time_shift(&self, pixel: usize, n: usize) -> usize {
        (hash64(self.key, pixel as u64, 3, 0) % n as u64) as usize
    }

    /// The recorded 8-bit value of radiance `l` in `channel` (see the module docs).
    #[inline]
    #[allow(clippy::too_many_arguments)]
    pub fn record(
        &self,
        p: &Photometric,
        l: f64,
        channel: usize,
        e: &Exposure,
        j: f64,
        vig: f64,
        n: f64,
    ) -> f32 {
        let v = e.gain * j * vig * self.white_balance[channel] * l + e.bias;
        let sigma = (p.config.noise_sigma * p.config.noise_sigma + self.shot_noise * v.max(0.0)).sqrt();
        (v + sigma * n).round().clamp(0.0, 255.0) as f32
    }
}

/// Encode `rgb` (values `0..=255`) as JPEG at `quality` and decode it again.
///
/// # Errors
/// [`Error::InvalidArgument`] if the codec fails (it does not for a valid image).
pub fn jpeg_round_trip(rgb: &RgbImage, quality: u8) -> Result<RgbImage> {
    let (h, w, _) = rgb.dim();
    let raw: Vec<u8> = rgb.iter().map(|&v| v.round().clamp(0.0, 255.0) as u8).collect();
    let fail = |e: image::ImageError| Error::invalid_argument("JPEG round trip", e.to_string());
    let mut bytes = Vec::new();
    JpegEncoder::new_with_quality(&mut bytes, quality)
        .encode(&raw, w as u32, h as u32, image::ExtendedColorType::Rgb8)
        .map_err(fail)?;
    let back = image::load_from_memory_with_format(&bytes, image::ImageFormat::Jpeg).map_err(fail)?.to_rgb8();
    let data: Vec<f32> = back.into_raw().into_iter().map(f32::from).collect();
    Array3::from_shape_vec((h, w, 3), data)
        .map_err(|e| Error::invalid_argument("JPEG round trip", e.to_string()))
}
