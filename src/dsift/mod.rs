//! Dense SIFT (SPEC.md §9a.2): at every pixel a 128-d SIFT descriptor (Lowe 2004; vlfeat's
//! `vl_dsift`) of the grey image, as a hand-crafted per-pixel baseline for the cost volume (the
//! paper's "DenseSIFT", §4 and the supplementary feature comparison).
//!
//! Symbols (SPEC.md §9a.2): `I = (R + G + B) / 3` the grey image; `g = (g_x, g_y)` its central
//! differences; `m = |g|`, `θ = atan2(g_y, g_x) ∈ [0, 2π)`; `s` the cell size in pixels (`bin_size`,
//! default 4: a 4x4 grid of cells covers 16x16 pixels); cell centres `c_j = (j - 1.5) s`, `j = 0..4`;
//! `σ = 2 s` (half the 4 s window); `tri(t) = max(0, 1 - |t|)`;
//! `k_j(d) = exp(-d² / (2σ²)) · tri((d - c_j) / s)` the weight of a sample at offset `d` along one
//! axis for cell `j`. The histogram of pixel `p`, cell row `i`, cell column `j`, orientation `o`:
//!
//! `h[i, j, o](p) = Σ_{d} k_j(d_x) k_i(d_y) · m(p + d) · w_o(θ(p + d))`
//!
//! with `w_o` the linear split of `θ` between its two nearest of 8 orientation bins (bin `o` centred
//! at `o · 45°`). Channel `c = (4 i + j) · 8 + o` (orientation fastest, then the cell column, then the
//! cell row: vlfeat's order). Then Lowe's normalisation (unit length, clip at 0.2, unit length again),
//! faded to zero in windows whose gradients are weaker than `min_contrast`, and scaled by `scale`:
//!
//! `d = scale · min(1, ‖h‖₁ / (W₁ τ)) · v / ‖v‖₂`,  `v = min(h / ‖h‖₂, 0.2)`,  `W₁ = (Σ_d Σ_j k_j(d))²`
//!
//! (`‖h‖₁ / W₁` is the window's weighted mean gradient magnitude in grey levels per pixel; `d = 0`
//! where `h = 0`). Samples outside the image have zero gradient; at the image's edge the missing
//! neighbour of a central difference is the edge pixel itself (edge replication).
//!
//! Two implementations, both always compiled ([`DsiftImpl`]): [`mod@reference`] (per pixel, per window
//! sample, f64: the oracle) and [`fast`] (orientation planes, then two separable passes of the
//! 1-D weights `k_j`, f32, rows in parallel; bit-identical for any thread count).

pub mod fast;
pub mod reference;

use ndarray::{Array3, ArrayView3};

use crate::error::{Error, Result};

/// Spatial cells along each axis.
pub const CELLS: usize = 4;
/// Orientation bins over `[0, 2π)`.
pub const ORIENTATIONS: usize = 8;
/// Descriptor length, `4 · 4 · 8`.
pub const CHANNELS: usize = CELLS * CELLS * ORIENTATIONS;
/// Lowe's clip of the unit-length descriptor's components.
pub const CLIP: f64 = 0.2;
/// Default cell size in pixels (vlfeat's `dsift` default bin size: a 16x16 window).
pub const DEFAULT_BIN_SIZE: usize = 4;
/// Default contrast `τ`, grey levels per pixel: below this weighted mean gradient magnitude the
/// descriptor fades linearly to zero (sensor noise of a few grey levels gives about 1-2).
pub const DEFAULT_MIN_CONTRAST: f64 = 2.0;
/// Default output scale: vlfeat's factor for its 8-bit SIFT descriptors (components at most
/// `0.2 · 512 ≈ 102` after the clip; not rounded here). The L1 distance of two descriptors is then
/// up to a few thousand, against RGB's 0-765.
pub const DEFAULT_SCALE: f64 = 512.0;
/// Largest cell size accepted.
pub const MAX_BIN_SIZE: usize = 32;

/// Parameters of the descriptor.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DsiftParams {
    /// Cell size `s`, pixels.
    pub bin_size: usize,
    /// Contrast `τ`, grey levels per pixel (positive).
    pub min_contrast: f64,
    /// Factor applied to the normalised descriptor (positive).
    pub scale: f64,
}

impl Default for DsiftParams {
    fn default() -> Self {
        Self::DEFAULT
    }
}

impl DsiftParams {
    /// `s = 4`, `τ = 2`, scale 512.
    pub const DEFAULT: Self =
        Self { bin_size: DEFAULT_BIN_SIZE, min_contrast: DEFAULT_MIN_CONTRAST, scale: DEFAULT_SCALE };

    /// Checks the parameters.
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] for a cell size outside `1..=32` or a contrast or scale that is not
    /// positive and finite.
    pub fn validate(&self) -> Result<()> {
        if !(1..=MAX_BIN_SIZE).contains(&self.bin_size) {
            return Err(Error::invalid_argument(
                "dsift bin size",
                format!("{}: expected 1..={MAX_BIN_SIZE}", self.bin_size),
            ));
        }
        for (name, v) in [("dsift contrast", self.min_contrast), ("dsift scale", self.scale)] {
            if !(v > 0.0 && v.is_finite()) {
                return Err(Error::invalid_argument(name, format!("{v}: must be positive")));
            }
        }
        Ok(())
    }

    /// `σ = 2 s`, pixels.
    pub fn sigma(&self) -> f64 {
        2.0 * self.bin_size as f64
    }

    /// Centre of cell `j` (`0..4`) relative to the pixel, `(j - 1.5) s`.
    pub fn cell_centre(&self, j: usize) -> f64 {
        (j as f64 - 1.5) * self.bin_size as f64
    }

    /// The largest offset with a non-zero weight: the largest integer `R < 2.5 s` (9 for `s = 4`,
    /// a 19x19 support).
    pub fn radius(&self) -> usize {
        (5 * self.bin_size - 1) / 2
    }

    /// The spatial weight of a sample at offset `d` from the cell centre, `tri(d / s)`.
    pub fn tri(&self, d: f64) -> f64 {
        (1.0 - d.abs() / self.bin_size as f64).max(0.0)
    }

    /// The 1-D Gaussian `exp(-d² / (2σ²))`.
    pub fn gauss(&self, d: f64) -> f64 {
        let s = self.sigma();
        (-(d * d) / (2.0 * s * s)).exp()
    }

    /// `k_j(d) = exp(-d² / (2σ²)) · tri((d - c_j) / s)`, f64.
    pub fn axis_weight(&self, j: usize, d: i64) -> f64 {
        let d = d as f64;
        self.gauss(d) * self.tri(d - self.cell_centre(j))
    }

    /// The non-zero taps of `k_j`: `(d, k_j(d))` for increasing `d`.
    pub fn taps(&self, j: usize) -> Vec<(i64, f64)> {
        let r = self.radius() as i64;
        (-r..=r).map(|d| (d, self.axis_weight(j, d))).filter(|&(_, k)| k > 0.0).collect()
    }

    /// `W₁ = (Σ_d Σ_j k_j(d))²`: `‖h‖₁` of a window whose every sample has gradient magnitude 1.
    pub fn unit_field_weight(&self) -> f64 {
        let r = self.radius() as i64;
        let one: f64 = (-r..=r).map(|d| (0..CELLS).map(|j| self.axis_weight(j, d)).sum::<f64>()).sum();
        one * one
    }
}

/// Which dense-SIFT implementation to run. Both are always compiled and tested.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum DsiftImpl {
    /// Per pixel, per window sample, f64, one thread: the oracle. Keep it naive.
    Reference,
    /// Orientation planes, two separable passes, f32, rows in parallel.
    Fast,
}

/// Dense SIFT of an RGB image.
///
/// # Shapes
/// `rgb`: `[H, W, 3]` (0-255, any real values accepted); output `[H, W, 128]`, channels-last, f32,
/// channel `(4 i + j) · 8 + o`.
///
/// # Errors
/// [`Error::InvalidArgument`] for an image that is not `[H >= 1, W >= 1, 3]` or bad parameters.
pub fn dense_sift(rgb: ArrayView3<f32>, params: &DsiftParams, imp: DsiftImpl) -> Result<Array3<f32>> {
    params.validate()?;
    let (h, w, c) = rgb.dim();
    if c != 3 || h == 0 || w == 0 {
        return Err(Error::invalid_argument(
            "image",
            format!("shape {:?}, expected [H >= 1, W >= 1, 3]", rgb.shape()),
        ));
    }
    Ok(match imp {
        DsiftImpl::Reference => reference::dense_sift_reference(rgb, params),
        DsiftImpl::Fast => fast::dense_sift_fast(rgb, params),
    })
}

/// The orientation split of an angle coordinate `t = θ · 8 / (2π)` in `[0, 8]`: bins `(o0, o1)` and
/// weights `(1 - f, f)`, `o0 = floor(t) mod 8`, `o1 = (o0 + 1) mod 8`, `f = t - floor(t)`.
pub(crate) fn orientation_split(t: f64) -> (usize, usize, f64) {
    let fl = t.floor();
    let o0 = (fl as i64).rem_euclid(ORIENTATIONS as i64) as usize;
    (o0, (o0 + 1) % ORIENTATIONS, t - fl)
}

/// Bytes of one [`dense_sift`] ([`DsiftImpl::Fast`]) of an `h x w` image at its peak: the grey sum
/// (4 bytes a pixel), the orientation planes (32), the horizontal pass (128) and the output (512).
pub fn extraction_bytes(h: usize, w: usize) -> u64 {
    crate::memory::product(&[h as u64, w as u64, 4 + 32 + 128 + 4 * CHANNELS as u64])
}
