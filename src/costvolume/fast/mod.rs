//! The fast kernel.
//!
//! Per reference pixel `u`, `p(ρ) = R K⁻¹ u̇ + ρ t` is affine in `ρ`: `a = R K⁻¹ u̇` is computed
//! once ([`Warp::point`] at `ρ = 0`) and each hypothesis costs three multiply-adds, a projection and
//! a bounds check, with exactly the `f64` expressions of [`Warp::apply_volume`] and `sample_bilinear`, so
//! validity (and hence every count) matches the reference bit for bit. A branch-free loop over the
//! hypotheses fills validity, corner offset and four `f32` bilinear weights (it vectorises, division
//! included); the channel loop then reads the
//! four corner vectors contiguously (channels last), shares the weights across channels, and keeps
//! [`LANES`] independent `f32` partial sums that are folded by a fixed pairwise tree. The lane
//! structure is explicit, so the bits do not depend on which vector width the compiler picks: the
//! AVX-512 build of the same function and the baseline build agree exactly.
//!
//! Rows are processed in parallel (rayon); each row's `W·K` cells belong to one task.

use nalgebra::Vector3;
use rayon::prelude::*;

use crate::geometry::{PinholeCamera, Warp};
use crate::runtime::CpuFeatureLevel;

#[cfg(target_arch = "x86_64")]
mod avx512;
mod portable;

#[cfg(test)]
use portable::l1_distance;
use portable::row_any;

/// Width of the channel loop's partial sums (one AVX-512 register of `f32`).
const LANES: usize = 16;

/// Cameras and warp of one live frame.
pub(super) struct Geometry<'a> {
    /// The reference camera (the volume's rows and columns).
    pub camera: &'a PinholeCamera,
    /// The live frame's camera (its features' size; projection and bounds).
    pub live: &'a PinholeCamera,
    pub warp: &'a Warp,
    /// `t_nr`.
    pub t: Vector3<f64>,
}

/// Reference and live features, `[H, W, C]` row-major.
pub(super) struct Slices<'a> {
    pub reference: &'a [f32],
    pub live: &'a [f32],
    pub channels: usize,
    /// Per-frame truncation `τ` (SPEC.md §9.13): a frame adds `min(l1, τ)`.
    pub truncation: f32,
}

/// Per-hypothesis scratch of one pixel (length `K` each): validity, the flat offset of the
/// top-left corner's first channel, and the bilinear weights `(1-a)(1-b), a(1-b), (1-a)b, ab`
/// rounded to `f32`. Filled by a branch-free loop over `k` that the compiler vectorises.
#[derive(Clone, Debug, Default)]
struct Scratch {
    ok: Vec<bool>,
    offset: Vec<usize>,
    w: [Vec<f32>; 4],
}

impl Scratch {
    fn new(k: usize) -> Self {
        Self { ok: vec![false; k], offset: vec![0; k], w: std::array::from_fn(|_| vec![0.0; k]) }
    }
}

/// Which kernel [`CostVolumeImpl::Fast`](super::CostVolumeImpl::Fast) runs on this CPU:
/// `"avx512-blocks"` (AVX-512 F/BW/VL/DQ: the 16-hypothesis block kernels for RGB and 16·N
/// channels, the per-hypothesis row kernel otherwise), `"avx512"` (AVX-512F only: the row kernel),
/// `"avx2"` (AVX2 and FMA: the row kernel compiled for them) or `"portable"`. Maps too large for
/// 32-bit gather offsets fall back to the row kernel.
pub fn fast_kernel_name() -> &'static str {
    fast_kernel_name_at(CpuFeatureLevel::get())
}

/// [`fast_kernel_name`] for a volume handed `level`.
pub fn fast_kernel_name_at(level: CpuFeatureLevel) -> &'static str {
    #[cfg(target_arch = "x86_64")]
    if level.avx512_bw_vl_dq() {
        return "avx512-blocks";
    }
    if level.avx512f() {
        "avx512"
    } else if level.avx2_fma() {
        "avx2"
    } else {
        "portable"
    }
}

/// The row kernel compiled for AVX2 and FMA (the compiler's vectorisation of the same lanes and
/// expressions; Rust never fuses a product and a sum on its own, so the bits are the portable
/// build's).
///
/// # Safety
/// The CPU has AVX2 and FMA.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn row_avx2(
    geo: &Geometry,
    feats: &Slices,
    rhos: &[f64],
    y: usize,
    sum_row: &mut [f32],
    count_row: &mut [u16],
    scratch: &mut Scratch,
) {
    row_any(geo, feats, rhos, y, sum_row, count_row, scratch);
}

/// Add one live frame into `sums` / `counts` (`[H, W, K]`), with the SIMD builds `level` allows.
pub(super) fn add_frame(
    geo: &Geometry,
    feats: &Slices,
    rhos: &[f64],
    sums: &mut [f32],
    counts: &mut [u16],
    level: CpuFeatureLevel,
) {
    let (w, k_count) = (geo.camera.width, rhos.len());
    let row_cells = w * k_count;
    let use_avx512 = level.avx512f();
    let use_avx2 = level.avx2_fma();
    #[cfg(target_arch = "x86_64")]
    let use_blocks = level.avx512_bw_vl_dq()
        && avx512::fits_i32(w, geo.camera.height, feats.channels)
        && avx512::fits_i32(geo.live.width, geo.live.height, feats.channels);
    // The block kernel loads whole 64-byte channel chunks of 16·N-channel maps: from a
    // cache-line-aligned copy no load straddles two lines (a copy changes no value).
    #[cfg(target_arch = "x86_64")]
    let aligned;
    #[cfg(target_arch = "x86_64")]
    let feats = if use_blocks
        && feats.channels.is_multiple_of(16)
        && !(feats.live.as_ptr() as usize).is_multiple_of(64)
    {
        aligned = avx512::AlignedCopy::new(feats.live);
        &Slices {
            reference: feats.reference,
            live: aligned.as_slice(),
            channels: feats.channels,
            truncation: feats.truncation,
        }
    } else {
        feats
    };
    // Byte-valued RGB (every value an integer 0..=255, as decoded images are): one packed word per
    // pixel, so the block kernel gathers 4 words per hypothesis instead of 12 floats (same values).
    #[cfg(target_arch = "x86_64")]
    let packed =
        if use_blocks { avx512::PackedRgb::new(feats.live, feats.channels, geo.live.width) } else { None };
    sums.par_chunks_mut(row_cells).zip(counts.par_chunks_mut(row_cells)).enumerate().for_each_init(
        || Scratch::new(k_count),
        |scratch, (y, (sum_row, count_row))| {
            #[cfg(target_arch = "x86_64")]
            if use_blocks {
                // SAFETY: `avx512_bw_vl_dq()` checked the CPU features, `fits_i32` the offsets; `packed`
                // is this frame's live map.
                unsafe { avx512::row(geo, feats, packed.as_ref(), rhos, y, sum_row, count_row) };
                return;
            }
            #[cfg(target_arch = "x86_64")]
            if use_avx512 {
                // SAFETY: `avx512f()` reported AVX-512F on this CPU.
                unsafe { avx512::row_generic(geo, feats, rhos, y, sum_row, count_row, scratch) };
                return;
            }
            #[cfg(target_arch = "x86_64")]
            if use_avx2 {
                // SAFETY: `avx2_fma()` reported AVX2 and FMA on this CPU.
                unsafe { row_avx2(geo, feats, rhos, y, sum_row, count_row, scratch) };
                return;
            }
            let _ = (use_avx512, use_avx2);
            row_any(geo, feats, rhos, y, sum_row, count_row, scratch);
        },
    );
}
