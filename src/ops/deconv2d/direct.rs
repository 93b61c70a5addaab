//! Transposed convolution as four direct (implicit-GEMM) parity convolutions, AVX-512F or
//! AVX2+FMA (the 3x3 convolution's strip kernels, SPEC.md §7.7; the same bits either way).
//!
//! Each output parity `(q_y, q_x)` is an ordinary small convolution of the input (SPEC.md §7.3,
//! [`super::fast`]): output pixel `(2m + q_y, 2n + q_x)` sums input pixels `(m + d_y, n + d_x)` for
//! the parity's taps `d` (increasing), against [`PackedDeconv2d`]'s `[t_y][t_x][c_in][c_out]`
//! weights. For a fixed tap row the taps `(d_x, c)` read `n_dx c_in` *contiguous* input values
//! against as many contiguous weight rows, which is exactly the 3x3 direct convolution's strip
//! kernel (`ops::conv2d::direct::avx512`, 14 pixels x 32 channels in 28 zmm accumulators) with
//! stride 1 and an output pixel stride of two pixels. The U-Net sum `skip + deconv(x)` can be fused
//! into the store (one f32 addition per value, the same bits as a separate `add`).
//!
//! Borders: tap rows outside the input are dropped for the whole output row; the columns whose taps
//! leave the input (at most the first and the last of each parity) run one pixel at a time with the
//! narrowed tap range. A dropped tap is an exact zero in the definition.
//!
//! Order: every value starts from the bias and accumulates `(t_y, t_x, c)` lexicographically with
//! one FMA per product, whatever the strip or thread: a `K + 1`-term f32 sum under §7.5's budget,
//! bit-identical for any thread count. Parallel over input rows (output row pairs).

use rayon::prelude::*;

use super::fast::{PackedDeconv2d, PARITIES};
use crate::error::{Error, Result};
use crate::ops::conv2d::direct::{DirectKernel, AVX512_C_OUT};
use crate::ops::expect_len;
use crate::ops::geometry::Deconv2dGeometry;
use crate::runtime::CpuFeatureLevel;

/// Whether [`deconv2d_direct`] can run `geom` on this CPU: `c_out = 32` and AVX-512F or AVX2+FMA.
pub fn supported(geom: &Deconv2dGeometry) -> bool {
    supported_at(geom, CpuFeatureLevel::get())
}

/// [`supported`] at the CPU-feature level `level`.
pub fn supported_at(geom: &Deconv2dGeometry, level: CpuFeatureLevel) -> bool {
    select_at(geom, level) != DirectKernel::Portable
}

/// The strip kernel [`deconv2d_direct`] runs for `geom` on this CPU: AVX-512F, else AVX2+FMA (both
/// for `c_out = 32`, SPEC.md §7.7), else [`DirectKernel::Portable`], meaning none (use
/// [`Deconv2dImpl::ParityGemm`](super::Deconv2dImpl::ParityGemm)).
pub fn select(geom: &Deconv2dGeometry) -> DirectKernel {
    select_at(geom, CpuFeatureLevel::get())
}

/// [`select`] at the CPU-feature level `level` (a backend passes its own).
pub fn select_at(geom: &Deconv2dGeometry, level: CpuFeatureLevel) -> DirectKernel {
    DirectKernel::ALL.into_iter().find(|&k| kernel_supports(k, geom, level)).unwrap_or(DirectKernel::Portable)
}

/// Whether the SIMD strip kernel `kernel` can run `geom` at `level`.
fn kernel_supports(kernel: DirectKernel, geom: &Deconv2dGeometry, level: CpuFeatureLevel) -> bool {
    kernel != DirectKernel::Portable && geom.c_out() == AVX512_C_OUT && kernel.cpu_has_at(level)
}

/// Valid taps `lo .. hi` (indices into the parity's increasing tap offsets `ds`) for input index
/// `i`: those with `0 <= i + d < n`.
fn valid_taps(ds: &[isize], i: usize, n: usize) -> (usize, usize) {
    let ok = |d: isize| i.checked_add_signed(d).is_some_and(|j| j < n);
    let lo = ds.iter().position(|&d| ok(d)).unwrap_or(ds.len());
    let hi = ds.iter().rposition(|&d| ok(d)).map_or(lo, |p| p + 1);
    (lo, hi.max(lo))
}

/// Transposed convolution (SPEC.md §7.3) of a channels-last input `[h, w, c_in]` into `out`
/// (`[2h, 2w, 32]`, fully overwritten); with `skip` (same shape as `out`), `out = skip + deconv`.
/// Runs [`select`]'s kernel.
///
/// # Errors
/// [`Error::InvalidArgument`] if a slice has the wrong length, or if this CPU or geometry cannot
/// run it ([`supported`]): callers choose
/// [`Deconv2dImpl::ParityGemm`](super::Deconv2dImpl::ParityGemm) there.
pub fn deconv2d_direct(
    packed: &PackedDeconv2d,
    input: &[f32],
    skip: Option<&[f32]>,
    out: &mut [f32],
) -> Result<()> {
    deconv2d_direct_with(select(packed.geometry()), packed, input, skip, out)
}

/// [`deconv2d_direct`] with a chosen strip kernel ([`DirectKernel::Avx512F`] or
/// [`DirectKernel::Avx2Fma`]; tests run both on one machine). Both give the same bits.
///
/// # Errors
/// As [`deconv2d_direct`], and if this CPU cannot run `kernel` (never a silent fallback).
pub fn deconv2d_direct_with(
    kernel: DirectKernel,
    packed: &PackedDeconv2d,
    input: &[f32],
    skip: Option<&[f32]>,
    out: &mut [f32],
) -> Result<()> {
    let geom = packed.geometry();
    let [h_out, w_out, c_out] = geom.output_shape();
    expect_len("deconv2d input", input.len(), geom.input_shape().iter().product())?;
    expect_len("deconv2d output", out.len(), h_out * w_out * c_out)?;
    if let Some(s) = skip {
        expect_len("deconv2d skip", s.len(), out.len())?;
    }
    if !kernel_supports(kernel, geom, CpuFeatureLevel::get()) {
        return Err(Error::invalid_argument(
            "deconv2d direct kernel",
            format!("{} cannot run c_out = {c_out} on this CPU; use ParityGemm", kernel.name()),
        ));
    }
    let pair_len = PARITIES * w_out * c_out;
    let offsets = [packed.offsets(0), packed.offsets(1)];
    out.par_chunks_mut(pair_len).enumerate().for_each(|(m, pair)| {
        let skip = skip.map(|s| &s[m * pair_len..(m + 1) * pair_len]);
        #[cfg(target_arch = "x86_64")]
        // SAFETY: `kernel_supports` checked the CPU features and c_out = 32; lengths checked above.
        unsafe {
            row_pair(kernel, packed, &offsets, input, m, skip, pair)
        };
        #[cfg(not(target_arch = "x86_64"))]
        let _ = (m, skip, pair, &offsets);
    });
    Ok(())
}

/// Output rows `2m`, `2m + 1` (`pair`, and `skip` alike: `2 · 2w · 32` floats); `offsets[q]` are
/// parity `q`'s input offsets ([`PackedDeconv2d::offsets`]).
///
/// # Safety
/// The CPU runs `kernel` (AVX-512F, or AVX2 and FMA), `c_out = 32`, slice lengths as
/// [`deconv2d_direct`] checks.
#[cfg(target_arch = "x86_64")]
unsafe fn row_pair(
    kernel: DirectKernel,
    packed: &PackedDeconv2d,
    offsets: &[Vec<isize>; PARITIES],
    input: &[f32],
    m: usize,
    skip: Option<&[f32]>,
    pair: &mut [f32],
) {
    use crate::ops::conv2d::direct::{Store, StripFn, Taps};
    let (width, run_strip): (usize, StripFn) = match kernel {
        DirectKernel::Avx512F => {
            (crate::ops::conv2d::direct::STRIP, crate::ops::conv2d::direct::avx512::any_strip)
        }
        _ => (crate::ops::conv2d::direct::avx2::AVX2_STRIP, crate::ops::conv2d::direct::avx2::any_strip),
    };
    let geom = packed.geometry();
    let (h, w, c_in, w_out) = (geom.h(), geom.w(), geom.c_in(), geom.w_out());
    let c = AVX512_C_OUT;
    let bias = packed.bias().as_ptr();
    for (qy, dys) in offsets.iter().enumerate() {
        let (ty_lo, ty_hi) = valid_taps(dys, m, h);
        for (qx, dxs) in offsets.iter().enumerate() {
            let weights = packed.parity_weights(qy, qx);
            let n_tx = dxs.len();
            // Taps of input columns n .. with tap columns tx_lo .. tx_hi inside the image.
            let taps = |n: usize, tx_lo: usize, tx_hi: usize| -> Taps {
                let iy = m.wrapping_add_signed(dys[ty_lo]);
                let ix = n.wrapping_add_signed(dxs[tx_lo]);
                Taps {
                    input: input[(iy * w + ix) * c_in..].as_ptr(),
                    row_stride: w * c_in,
                    pix_stride: c_in,
                    n_ky: ty_hi - ty_lo,
                    run: (tx_hi - tx_lo) * c_in,
                    weights: weights[(ty_lo * n_tx + tx_lo) * c_in * c..].as_ptr(),
                    w_row_stride: n_tx * c_in * c,
                }
            };
            let base = (qy * w_out + qx) * c;
            let store = Store {
                ptr: pair.as_mut_ptr().wrapping_add(base),
                stride: PARITIES * c,
                skip: skip.map_or(std::ptr::null(), |s| s.as_ptr().wrapping_add(base)),
                relu: false,
            };
            // Interior columns: every tap column inside the input.
            let n_lo = dxs.iter().map(|&d| (-d).max(0) as usize).max().unwrap_or(0).min(w);
            let n_hi = w.saturating_sub(dxs.iter().map(|&d| d.max(0) as usize).max().unwrap_or(0)).max(n_lo);
            for n in (0..n_lo).chain(n_hi..w) {
                let (tx_lo, tx_hi) = valid_taps(dxs, n, w);
                // SAFETY: valid taps keep every read inside the h x w input; weights inside the
                // parity's packed matrix; pixel (2m + qy, 2n + qx) inside `pair` (and `skip`).
                unsafe { run_strip(1, &taps(n, tx_lo, tx_hi), bias, &store.at(n)) };
            }
            let mut n = n_lo;
            while n < n_hi {
                let len = width.min(n_hi - n);
                let t = taps(n, 0, n_tx);
                // SAFETY: pixels n .. n + len are interior, so all their taps are inside the input;
                // their outputs are inside `pair`; the kernel's CPU features per the caller.
                unsafe { run_strip(len, &t, bias, &store.at(n)) };
                n += len;
            }
        }
    }
}
