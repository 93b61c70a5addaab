//! Direct (implicit-GEMM) convolution on channels-last input: no im2col matrix, no scratch.
//!
//! The weights are the ones [`PackedConv2d`] already holds, `[ky][kx][c][c_out]` with `c_out`
//! contiguous (the GEMM's `B [9 c_in, c_out]`). For one output pixel and tap row `ky`, the taps
//! `(kx, c)` read `3 c_in` *contiguous* input values (the channels-last row `s x - 1 ..= s x + 1`)
//! against `3 c_in` contiguous weight rows, so the inner loop is a single run of `3 c_in` steps:
//!
//! ```text
//! acc[p][o] = b[o]
//! for ky in valid rows:             input row  s y + ky - 1
//!   for j in 0 .. n_kx c_in:        input col  s (x0 + p) + kx_lo - 1, channel j (contiguous)
//!     acc[p][o] += in[..][j] · W[ky][kx_lo c_in + j][o]      for every pixel p of the strip
//! out[p][o] = act(acc[p][o])
//! ```
//!
//! Kernels ([`DirectKernel`]):
//! - [`DirectKernel::Avx512F`] (x86-64 with AVX-512F, `c_out = 32` only): a strip of
//!   [`STRIP`] output pixels of one row times all 32 output channels lives in `2 · STRIP` zmm
//!   accumulators; each step loads two weight vectors and broadcasts one input value per pixel into
//!   two FMAs. The pixel stride `s c_in` is a compile-time constant for the network's shapes
//!   (`c_in ∈ {3, 32, 35}`, `s ∈ {1, 2}`), so every broadcast is one addressing mode off one pointer.
//! - [`DirectKernel::Portable`] (everywhere, any `c_out`): the same loops in plain Rust, one pixel at
//!   a time, vectorised by the compiler over `c_out`.
//!
//! Borders: zero padding never reaches the hot loop. Rows outside the image are dropped from the
//! `ky` range of the whole output row; the columns whose 3x3 window leaves the image (at most
//! the first and the last output pixel of a row) run one at a time with a narrowed `kx` range.
//! A skipped tap contributes an exact zero to the reference sum, so this only changes the sign of
//! a zero result.
//!
//! Determinism: each output value is summed by one task, starting from the bias, over
//! `(ky, kx, c)` in lexicographic order, whatever the strip, block or thread. Work is split over
//! blocks of output rows ([`rows_per_block`]).

use rayon::prelude::*;

use super::PackedConv2d;

#[cfg(target_arch = "x86_64")]
pub(crate) mod avx2;
#[cfg(target_arch = "x86_64")]
pub(crate) mod avx512;
mod portable;
use crate::error::{Error, Result};
use crate::ops::geometry::{Conv2dGeometry, CONV_KERNEL, CONV_PADDING};
use crate::ops::{expect_len, Activation};
use crate::runtime::CpuFeatureLevel;

/// Output pixels per strip of the AVX-512 micro-kernel: `2 · 14 = 28` accumulators, two weight
/// registers and one broadcast fill 31 of the 32 zmm registers.
pub const STRIP: usize = 14;

/// Output channels of the AVX-512 micro-kernel (two zmm registers of f32).
pub const AVX512_C_OUT: usize = 32;

/// FLOPs per parallel work unit to aim for (about 10 µs on one core): enough units for two threads
/// to balance even on the coarsest maps (60 x 80 output: 30 units), few enough that rayon's per-unit
/// cost stays negligible. A unit reads `s (rows - 1) + 3` input rows (250 KB for 640 x 32 channels),
/// which stay in the 2 MB L2.
const TARGET_BLOCK_FLOPS: usize = 2_000_000;

/// A micro-kernel of [`Conv2dImpl::Direct`](super::Conv2dImpl::Direct).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum DirectKernel {
    /// x86-64 AVX-512F intrinsics, strips of [`STRIP`] pixels x 32 output channels, FMA. Only for
    /// `c_out = 32` on a CPU with AVX-512F (detected at run time).
    Avx512F,
    /// x86-64 AVX2 + FMA intrinsics (for CPUs without AVX-512), strips of
    /// 6 pixels x 16 output channels, run once per
    /// channel half. Only for `c_out = 32`. The same bits as [`DirectKernel::Avx512F`].
    Avx2Fma,
    /// Plain Rust, one pixel at a time, any `c_out`, every target (no FMA contraction).
    Portable,
}

impl DirectKernel {
    /// Every kernel, for tests.
    pub const ALL: [DirectKernel; 3] = [DirectKernel::Avx512F, DirectKernel::Avx2Fma, DirectKernel::Portable];

    /// The kernel [`conv2d_direct`] runs for `geom` on this CPU: the first of AVX-512F, AVX2+FMA
    /// (both for `c_out = 32`) and portable that it supports.
    pub fn select(geom: &Conv2dGeometry) -> DirectKernel {
        Self::select_at(geom, CpuFeatureLevel::get())
    }

    /// [`DirectKernel::select`] at the CPU-feature level `level` (a backend passes its own).
    pub fn select_at(geom: &Conv2dGeometry, level: CpuFeatureLevel) -> DirectKernel {
        DirectKernel::ALL.into_iter().find(|k| k.supports_at(geom, level)).unwrap_or(DirectKernel::Portable)
    }

    /// `Ok` if this kernel can run `geom` on this CPU ([`DirectKernel::supports`]).
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] naming the kernel otherwise.
    pub fn check(self, geom: &Conv2dGeometry) -> Result<()> {
        if self.supports(geom) {
            return Ok(());
        }
        Err(Error::invalid_argument(
            "conv2d direct kernel",
            format!("{} cannot run c_out = {} on this CPU", self.name(), geom.c_out()),
        ))
    }

    /// Output row `y` with this kernel; `input` holds the image's rows from `row0` on.
    ///
    /// # Safety
    /// [`DirectKernel::check`] passed for `packed`'s geometry, `input` holds every row output row
    /// `y` reads (from `row0` on), and `out_row` holds `w_out · c_out` floats.
    pub(super) unsafe fn conv_row(
        self,
        packed: &PackedConv2d,
        input: &[f32],
        row0: usize,
        y: usize,
        activation: Activation,
        out_row: &mut [f32],
    ) {
        match self {
            #[cfg(target_arch = "x86_64")]
            // SAFETY: `check` found AVX-512F and c_out = 32; rows per the caller.
            DirectKernel::Avx512F => unsafe { avx512::conv_row(packed, input, row0, y, activation, out_row) },
            #[cfg(target_arch = "x86_64")]
            // SAFETY: `check` found AVX2, FMA and c_out = 32; rows per the caller.
            DirectKernel::Avx2Fma => unsafe { avx2::conv_row(packed, input, row0, y, activation, out_row) },
            _ => portable::conv_row(packed, input, row0, y, activation, out_row),
        }
    }

    /// Whether this kernel can run `geom` on this CPU.
    pub fn supports(self, geom: &Conv2dGeometry) -> bool {
        self.supports_at(geom, CpuFeatureLevel::get())
    }

    /// [`DirectKernel::supports`] at the CPU-feature level `level`.
    pub fn supports_at(self, geom: &Conv2dGeometry, level: CpuFeatureLevel) -> bool {
        self == DirectKernel::Portable || (geom.c_out() == AVX512_C_OUT && self.cpu_has_at(level))
    }

    /// Whether this CPU has the instructions of this kernel's strips (the portable kernel: always).
    /// The SIMD strips compute 32 output channels; [`DirectKernel::supports`] adds that condition,
    /// and the transposed convolution's strips (`nn::deconv2d::direct`) use the same two.
    pub fn cpu_has(self) -> bool {
        self.cpu_has_at(CpuFeatureLevel::get())
    }

    /// [`DirectKernel::cpu_has`] at the CPU-feature level `level` (which also checks the CPU).
    pub fn cpu_has_at(self, level: CpuFeatureLevel) -> bool {
        match self {
            DirectKernel::Avx512F => level.avx512f(),
            DirectKernel::Avx2Fma => level.avx2_fma(),
            DirectKernel::Portable => true,
        }
    }

    /// A short name, for logs and for tests that check which kernel ran.
    pub fn name(self) -> &'static str {
        match self {
            DirectKernel::Avx512F => "avx512f-14x32",
            DirectKernel::Avx2Fma => "avx2-6x16",
            DirectKernel::Portable => "portable",
        }
    }
}

/// Name of the kernel [`conv2d_direct`] runs for `geom` on this CPU ([`DirectKernel::select`]).
pub fn kernel_name(geom: &Conv2dGeometry) -> &'static str {
    DirectKernel::select(geom).name()
}

/// Output rows per parallel work unit (fixed by the geometry; results do not depend on it).
pub fn rows_per_block(geom: &Conv2dGeometry) -> usize {
    let row_flops = 2 * geom.k() * geom.w_out() * geom.c_out();
    TARGET_BLOCK_FLOPS.div_ceil(row_flops).clamp(1, geom.h_out())
}

/// Valid taps `k_lo .. k_hi` along one axis for output index `o`: those with input index
/// `s o + k - 1` inside `0 .. n`.
pub(crate) fn tap_range(o: usize, s: usize, n: usize) -> (usize, usize) {
    let centre = s * o; // Invariant: centre <= n - 1 since o < out_len(n).
    let lo = CONV_PADDING.saturating_sub(centre);
    let hi = CONV_KERNEL.min(n + CONV_PADDING - centre);
    (lo, hi)
}

/// Output columns `x_lo .. x_hi` whose whole 3x3 window is inside the image; the others (at most
/// one on each side) are border columns.
pub(crate) fn interior_columns(geom: &Conv2dGeometry) -> (usize, usize) {
    let (w, s, w_out) = (geom.w(), geom.stride(), geom.w_out());
    let x_lo = CONV_PADDING.min(w_out);
    // Interior: s x - 1 >= 0 and s x + 1 <= w - 1.
    let x_hi = if w >= 2 { w_out.min((w - 2) / s + 1) } else { 0 };
    (x_lo, x_hi.max(x_lo))
}

/// Direct convolution (SPEC.md §7.7) of a channels-last input slice `[h, w, c_in]` into `out`
/// (`[h_out, w_out, c_out]`, fully overwritten) with the best kernel for this CPU
/// ([`DirectKernel::select`]), parallel over blocks of output rows. Returns the kernel that ran.
///
/// # Errors
/// [`Error::InvalidArgument`] if `input` or `out` has the wrong length.
pub fn conv2d_direct(
    packed: &PackedConv2d,
    input: &[f32],
    activation: Activation,
    out: &mut [f32],
) -> Result<DirectKernel> {
    let kernel = DirectKernel::select(packed.geometry());
    conv2d_direct_with(kernel, packed, input, activation, out)?;
    Ok(kernel)
}

/// [`conv2d_direct`] with a chosen kernel (tests use it to cover every kernel on one machine).
///
/// # Errors
/// [`Error::InvalidArgument`] if `input` or `out` has the wrong length, or `kernel` cannot run
/// this geometry on this CPU ([`DirectKernel::supports`]).
pub fn conv2d_direct_with(
    kernel: DirectKernel,
    packed: &PackedConv2d,
    input: &[f32],
    activation: Activation,
    out: &mut [f32],
) -> Result<()> {
    let geom = packed.geometry();
    let [h_out, w_out, c_out] = geom.output_shape();
    expect_len("conv2d input", input.len(), geom.input_shape().iter().product())?;
    expect_len("conv2d output", out.len(), h_out * w_out * c_out)?;
    kernel.check(geom)?;
    let row_len = w_out * c_out;
    let rows = rows_per_block(geom);
    out.par_chunks_mut(rows * row_len).enumerate().for_each(|(b, block)| {
        for (i, out_row) in block.chunks_exact_mut(row_len).enumerate() {
            // SAFETY: `check` passed; the slice lengths were checked against the geometry above,
            // so `input` holds every image row from row 0.
            unsafe { kernel.conv_row(packed, input, 0, b * rows + i, activation, out_row) };
        }
    });
    Ok(())
}

/// Where a strip's taps live: input and weights of its first valid tap, and the loop extents.
/// Shared with the transposed convolution's direct kernel (`nn::deconv2d::direct`), whose output
/// parities are small ordinary convolutions.
pub(crate) struct Taps {
    /// `in[s y + ky_lo - 1, s x0 + kx_lo - 1, 0]`.
    pub(crate) input: *const f32,
    /// Floats between input rows (`w c_in`).
    pub(crate) row_stride: usize,
    /// Floats between the strip's pixels (`s c_in`).
    pub(crate) pix_stride: usize,
    /// Valid tap rows.
    pub(crate) n_ky: usize,
    /// Contiguous input values (and weight rows) per tap row: `n_kx c_in`.
    pub(crate) run: usize,
    /// `W[ky_lo][kx_lo][0][0]`.
    pub(crate) weights: *const f32,
    /// Floats between weight tap rows (`3 c_in · 32`).
    pub(crate) w_row_stride: usize,
}

impl Taps {
    /// The taps of output pixels `x0 ..` of output row `y`: tap rows `ky_lo .. ky_hi` and tap columns
    /// `kx_lo .. kx_hi` (all inside the image), `input` holding the image's rows from `row0` on.
    pub(crate) fn of(
        packed: &PackedConv2d,
        input: &[f32],
        row0: usize,
        y: usize,
        (ky_lo, ky_hi): (usize, usize),
        x0: usize,
        (kx_lo, kx_hi): (usize, usize),
    ) -> Self {
        let geom = packed.geometry();
        let (w, c_in, s) = (geom.w(), geom.c_in(), geom.stride());
        let iy = s * y + ky_lo - CONV_PADDING - row0;
        let ix = s * x0 + kx_lo - CONV_PADDING;
        Taps {
            input: input[(iy * w + ix) * c_in..].as_ptr(),
            row_stride: w * c_in,
            pix_stride: s * c_in,
            n_ky: ky_hi - ky_lo,
            run: (kx_hi - kx_lo) * c_in,
            weights: packed.weights()[(ky_lo * CONV_KERNEL + kx_lo) * c_in * AVX512_C_OUT..].as_ptr(),
            w_row_stride: CONV_KERNEL * c_in * AVX512_C_OUT,
        }
    }
}

/// Where a strip's results go: pixel `p`'s 32 channels at `ptr + p stride`; with a non-null `skip`,
/// `skip + p stride`'s 32 values are added to them after the activation (the U-Net sum, one f32
/// addition, the same bits as a separate `add`).
pub(crate) struct Store {
    pub(crate) ptr: *mut f32,
    pub(crate) stride: usize,
    pub(crate) skip: *const f32,
    pub(crate) relu: bool,
}

impl Store {
    /// Pixel `p`'s destination, `p` pixels on.
    pub(crate) fn at(&self, p: usize) -> Store {
        Store {
            ptr: self.ptr.wrapping_add(p * self.stride),
            stride: self.stride,
            skip: if self.skip.is_null() { self.skip } else { self.skip.wrapping_add(p * self.stride) },
            relu: self.relu,
        }
    }
}

/// A strip kernel of `n` pixels (`avx512::any_strip` or `avx2::any_strip`), chosen once per call.
pub(crate) type StripFn = unsafe fn(usize, &Taps, *const f32, &Store);
