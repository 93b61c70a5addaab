//! The per-pixel feature kernels of the fast loss (SPEC.md §13.1): the costs of all in-image
//! hypotheses of one reference pixel, and the backward of those costs into the reference pixel and
//! the live map. Two implementations with the same operation order (16 channel lanes, products
//! and sums unfused, a fixed tree for the lane reduction), so they give the same bits: a portable
//! one, an AVX-512 one and an AVX2 one (x86-64, chosen at run time by [`loss_kernels`]: the
//! highest the CPU and the requested level have, when `C % 16 == 0`).

use crate::runtime::CpuFeatureLevel;

#[cfg(target_arch = "x86_64")]
mod avx2;
#[cfg(target_arch = "x86_64")]
mod avx512;
mod portable;

/// Channel lanes of one vector (an AVX-512 register of f32).
pub(super) const LANES: usize = 16;

/// The bilinear sample of one in-image hypothesis: the live rows `y0, y1`, the columns `x0, x1`
/// times `C` (offsets into a row), and the corner weights `[(y0,x0), (y0,x1), (y1,x0), (y1,x1)]`.
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct Tap {
    /// Index of the hypothesis (bin).
    pub bin: u32,
    /// Live rows of the top and bottom corners.
    pub y: [u32; 2],
    /// Offsets of the left and right corners inside a row (`x * C`).
    pub xc: [usize; 2],
    /// Corner weights.
    pub w: [f32; 4],
}

impl Tap {
    /// The four corners as (row, offset in row), in weight order.
    #[inline(always)]
    pub fn corners(&self) -> [(usize, usize); 4] {
        let (y0, y1) = (self.y[0] as usize, self.y[1] as usize);
        let [x0, x1] = self.xc;
        [(y0, x0), (y0, x1), (y1, x0), (y1, x1)]
    }
}

/// Which build of the loss kernels runs (the same bits from each).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LossKernels {
    /// Plain Rust.
    Portable,
    /// AVX2, two 8-lane registers per 16 channel lanes (x86-64).
    Avx2,
    /// AVX-512F, one register per 16 channel lanes (x86-64).
    Avx512,
}

/// The build of the loss kernels for `c` channels at the CPU-feature level `level`: AVX-512 when
/// the level (and the CPU) has AVX-512F, else AVX2 when it has AVX2 and FMA, else portable; the
/// two vector builds need `c` a multiple of 16.
pub fn loss_kernels(level: CpuFeatureLevel, c: usize) -> LossKernels {
    #[cfg(target_arch = "x86_64")]
    {
        if !c.is_multiple_of(LANES) {
            LossKernels::Portable
        } else if level.avx512f() {
            LossKernels::Avx512
        } else if level.avx2_fma() {
            LossKernels::Avx2
        } else {
            LossKernels::Portable
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        let _ = (level, c);
        LossKernels::Portable
    }
}

/// Whether the loss kernels use AVX-512 for `c` channels at the CPU-feature level `level`.
pub fn uses_avx512(level: CpuFeatureLevel, c: usize) -> bool {
    loss_kernels(level, c) == LossKernels::Avx512
}

/// The fixed lane reduction: halves added pairwise (for 16 lanes 8, 4, 2, 1), any lane count that
/// is a power of two. The f32 kernels' 16 lanes and `pixel_terms`' 8 f64 lanes share it.
#[inline(always)]
pub(super) fn lane_tree<T: Copy + std::ops::AddAssign, const N: usize>(mut acc: [T; N]) -> T {
    let mut n = N / 2;
    while n > 0 {
        for i in 0..n {
            let v = acc[i + n];
            acc[i] += v;
        }
        n /= 2;
    }
    acc[0]
}

/// Costs `E = Σ_c (f_u − Σ_t w_t f_l(corner_t))²` of every tap into `energies[j]`, and the
/// residuals `f_u − sample` into `resid[j*C..]`. `fl` is the live map, `row` its row length
/// (`W' * C`).
pub(super) fn costs(
    kernels: LossKernels,
    fu: &[f32],
    fl: &[f32],
    row: usize,
    taps: &[Tap],
    resid: &mut [f32],
    energies: &mut [f32],
) {
    match kernels {
        // SAFETY (both): `loss_kernels` checked the CPU feature and `C % 16 == 0`.
        #[cfg(target_arch = "x86_64")]
        LossKernels::Avx512 => unsafe { avx512::costs(fu, fl, row, taps, resid, energies) },
        #[cfg(target_arch = "x86_64")]
        LossKernels::Avx2 => unsafe { avx2::costs(fu, fl, row, taps, resid, energies) },
        _ => portable::costs(fu, fl, row, taps, resid, energies),
    }
}

/// Pixels per tile of [`LiveRows`].
pub(super) const TILE_PX: usize = 16;

/// The live-map gradient of one chunk of reference rows, in lazily allocated tiles of
/// [`TILE_PX`] pixels of one live row (empty while untouched). An epipolar line touches a few
/// pixels of most rows, so tiles keep a chunk's buffers (and the chunks' sum) near the pixels it
/// touched instead of whole rows.
pub(super) struct LiveRows {
    /// Row length `W' * C`.
    pub row: usize,
    /// Values per full tile (`TILE_PX * C`).
    pub tile: usize,
    /// Tiles per row (the last one may be shorter).
    pub per_row: usize,
    /// `log2(tile)` when `tile` is a power of two (the network's 32 channels: 512), so that the
    /// tile of an offset is a shift, not a division (the lookup runs four times per hypothesis).
    tile_shift: Option<u32>,
    /// `tiles[y * per_row + t]`: the gradient of tile `t` of live row `y`, or empty.
    pub tiles: Vec<Vec<f32>>,
}

impl LiveRows {
    /// No tile touched yet; `c` channels per pixel.
    pub fn new(height: usize, row: usize, c: usize) -> Self {
        let tile = TILE_PX * c;
        let per_row = row.div_ceil(tile).max(1);
        let tile_shift = tile.is_power_of_two().then(|| tile.trailing_zeros());
        LiveRows { row, tile, per_row, tile_shift, tiles: vec![Vec::new(); height * per_row] }
    }

    /// The `len` values at offset `x` of live row `y` (inside one pixel, so inside one tile), the
    /// tile allocated (zero) on first use.
    #[inline(always)]
    fn at_mut(&mut self, y: usize, x: usize, len: usize) -> &mut [f32] {
        let t = match self.tile_shift {
            Some(s) => x >> s,
            None => x / self.tile,
        };
        let start = t * self.tile;
        let r = &mut self.tiles[y * self.per_row + t];
        if r.is_empty() {
            *r = vec![0.0; self.tile.min(self.row - start)];
        }
        &mut r[x - start..x - start + len]
    }
}

/// Backward of the costs: for every tap `j` with `coef[j] ≠ 0` (the scaled `2 ∂loss/∂E_j`), in
/// order, `d_u += coef r_j` and `d_live(corner_t) += (−coef w_t) r_j`.
pub(super) fn backward(
    kernels: LossKernels,
    taps: &[Tap],
    coefs: &[f32],
    resid: &[f32],
    d_u: &mut [f32],
    live: &mut LiveRows,
) {
    match kernels {
        // SAFETY (both): `loss_kernels` checked the CPU feature and `C % 16 == 0`.
        #[cfg(target_arch = "x86_64")]
        LossKernels::Avx512 => unsafe { avx512::backward(taps, coefs, resid, d_u, live) },
        #[cfg(target_arch = "x86_64")]
        LossKernels::Avx2 => unsafe { avx2::backward(taps, coefs, resid, d_u, live) },
        _ => portable::backward(taps, coefs, resid, d_u, live),
    }
}
