//! The AVX2+FMA micro-kernel of [`DirectKernel::Avx2Fma`](super::DirectKernel::Avx2Fma),
//! for x86-64 CPUs without AVX-512 (SPEC.md §7.7). x86-64 only; callers check AVX2 and FMA at run
//! time.
//!
//! With 16 ymm registers a strip is [`AVX2_STRIP`] output pixels x 16 output channels (one half of
//! the 32): 12 accumulators, two weight registers and one broadcast. Each strip runs twice, once
//! per channel half. Per step: 2 weight loads, 6 broadcasts, 12 FMAs. Every output value starts
//! from the bias and accumulates `(ky, kx, c)` in lexicographic order with one FMA per product,
//! exactly as the AVX-512 kernel does, so the two kernels give the same bits.

use std::arch::x86_64::{
    __m256, _mm256_add_ps, _mm256_fmadd_ps, _mm256_loadu_ps, _mm256_max_ps, _mm256_set1_ps,
    _mm256_setzero_ps, _mm256_storeu_ps,
};

use super::{interior_columns, tap_range, Activation, PackedConv2d, Store, Taps, AVX512_C_OUT, CONV_KERNEL};

/// Output pixels per strip of this kernel.
pub const AVX2_STRIP: usize = 6;

/// f32 lanes of a ymm register.
const LANES: usize = 8;

/// Output channels per strip pass (two ymm registers).
const HALF: usize = 16;

/// `P` output pixels x output channels `16 h .. 16 h + 16` of a strip (see [`Store`]); `PS` is the
/// pixel stride as a constant, or 0 to read it from `t.pix_stride`.
///
/// # Safety
/// As `avx512::strip` (the same `Taps` / `Store` contract for `P` pixels x 32 channels), and
/// the CPU has AVX2 and FMA; `h < 2`.
#[target_feature(enable = "avx2,fma")]
unsafe fn strip_half<const P: usize, const PS: usize>(t: &Taps, bias: *const f32, o: &Store, h: usize) {
    let ps = if PS == 0 { t.pix_stride } else { PS };
    let off = h * HALF;
    // SAFETY: bias holds 32 floats and off + 16 <= 32 (caller contract).
    let (b0, b1) = unsafe { (_mm256_loadu_ps(bias.add(off)), _mm256_loadu_ps(bias.add(off + LANES))) };
    let mut acc: [[__m256; 2]; P] = [[b0, b1]; P];
    for ky in 0..t.n_ky {
        // SAFETY: offsets stay inside the ranges of the caller contract.
        let (row, wrow) =
            unsafe { (t.input.add(ky * t.row_stride), t.weights.add(ky * t.w_row_stride + off)) };
        for j in 0..t.run {
            // SAFETY: weight row `wrow + 32 j .. + 16` and input values `row + p ps + j` for p < P
            // are inside the caller contract's ranges.
            unsafe {
                let w = wrow.add(j * AVX512_C_OUT);
                let (w0, w1) = (_mm256_loadu_ps(w), _mm256_loadu_ps(w.add(LANES)));
                let x = row.add(j);
                for (p, a) in acc.iter_mut().enumerate() {
                    let v = _mm256_set1_ps(*x.add(p * ps));
                    a[0] = _mm256_fmadd_ps(v, w0, a[0]);
                    a[1] = _mm256_fmadd_ps(v, w1, a[1]);
                }
            }
        }
    }
    let zero = _mm256_setzero_ps();
    for (p, a) in acc.iter().enumerate() {
        let (mut v0, mut v1) =
            if o.relu { (_mm256_max_ps(a[0], zero), _mm256_max_ps(a[1], zero)) } else { (a[0], a[1]) };
        // SAFETY: pixel p's destination floats off .. off + 16 (and skip values) are in the contract.
        unsafe {
            let at = p * o.stride + off;
            if !o.skip.is_null() {
                let s = o.skip.add(at);
                v0 = _mm256_add_ps(_mm256_loadu_ps(s), v0);
                v1 = _mm256_add_ps(_mm256_loadu_ps(s.add(LANES)), v1);
            }
            _mm256_storeu_ps(o.ptr.add(at), v0);
            _mm256_storeu_ps(o.ptr.add(at + LANES), v1);
        }
    }
}

/// `P` pixels x 32 channels: both channel halves.
///
/// # Safety
/// As [`strip_half`].
#[target_feature(enable = "avx2,fma")]
unsafe fn strip<const P: usize, const PS: usize>(t: &Taps, bias: *const f32, o: &Store) {
    // SAFETY: forwarded caller contract, h ∈ {0, 1}.
    unsafe {
        strip_half::<P, PS>(t, bias, o, 0);
        strip_half::<P, PS>(t, bias, o, 1);
    }
}

/// A strip of `n <= AVX2_STRIP` pixels; full strips take the network's pixel strides as constants.
///
/// # Safety
/// As [`strip`] with `P = n`.
#[target_feature(enable = "avx2,fma")]
pub(crate) unsafe fn any_strip(n: usize, t: &Taps, bias: *const f32, o: &Store) {
    // SAFETY: forwarded caller contract; PS equals t.pix_stride in every specialised arm.
    unsafe {
        match (n, t.pix_stride) {
            (AVX2_STRIP, 3) => strip::<AVX2_STRIP, 3>(t, bias, o),
            (AVX2_STRIP, 6) => strip::<AVX2_STRIP, 6>(t, bias, o),
            (AVX2_STRIP, 32) => strip::<AVX2_STRIP, 32>(t, bias, o),
            (AVX2_STRIP, 35) => strip::<AVX2_STRIP, 35>(t, bias, o),
            (AVX2_STRIP, 64) => strip::<AVX2_STRIP, 64>(t, bias, o),
            (AVX2_STRIP, 70) => strip::<AVX2_STRIP, 70>(t, bias, o),
            (AVX2_STRIP, _) => strip::<AVX2_STRIP, 0>(t, bias, o),
            (1, _) => strip::<1, 0>(t, bias, o),
            (2, _) => strip::<2, 0>(t, bias, o),
            (3, _) => strip::<3, 0>(t, bias, o),
            (4, _) => strip::<4, 0>(t, bias, o),
            (5, _) => strip::<5, 0>(t, bias, o),
            _ => unreachable!("strip of {n} pixels"),
        }
    }
}

/// Output row `y` of the convolution; `input` holds the image's rows from `row0` on.
///
/// # Safety
/// The CPU has AVX2 and FMA; otherwise as `avx512::conv_row`.
#[target_feature(enable = "avx2,fma")]
pub(super) unsafe fn conv_row(
    packed: &PackedConv2d,
    input: &[f32],
    row0: usize,
    y: usize,
    activation: Activation,
    out_row: &mut [f32],
) {
    let geom = packed.geometry();
    let (h, w, s) = (geom.h(), geom.w(), geom.stride());
    debug_assert_eq!(geom.c_out(), AVX512_C_OUT);
    debug_assert_eq!(out_row.len(), geom.w_out() * AVX512_C_OUT);
    let relu = activation == Activation::Relu;
    let (ky_lo, ky_hi) = tap_range(y, s, h);
    let bias = packed.bias().as_ptr();
    let taps = |x0: usize, kx_lo: usize, kx_hi: usize| {
        Taps::of(packed, input, row0, y, (ky_lo, ky_hi), x0, (kx_lo, kx_hi))
    };
    let store = Store { ptr: out_row.as_mut_ptr(), stride: AVX512_C_OUT, skip: std::ptr::null(), relu };
    let (x_lo, x_hi) = interior_columns(geom);
    for x in (0..x_lo).chain(x_hi..geom.w_out()) {
        let (kx_lo, kx_hi) = tap_range(x, s, w);
        // SAFETY: as in `avx512::conv_row`: tap_range keeps every read inside the image rows
        // held by `input`, pixel x is inside `out_row`; AVX2 and FMA per the caller.
        unsafe { any_strip(1, &taps(x, kx_lo, kx_hi), bias, &store.at(x)) };
    }
    let mut x = x_lo;
    while x < x_hi {
        let n = AVX2_STRIP.min(x_hi - x);
        // SAFETY: pixels x .. x + n are interior (whole window inside the image) and inside
        // `out_row`; AVX2 and FMA per the caller.
        unsafe { any_strip(n, &taps(x, 0, CONV_KERNEL), bias, &store.at(x)) };
        x += n;
    }
}
