//! The AVX-512F micro-kernel of [`DirectKernel::Avx512F`](super::DirectKernel::Avx512F):
//! a strip of `P <= STRIP` output pixels of one row x 32 output channels in `2 P` zmm accumulators
//! (layout and loop order in [`super`]). x86-64 only; callers check AVX-512F at run time.

use std::arch::x86_64::{
    __m512, _mm512_add_ps, _mm512_fmadd_ps, _mm512_loadu_ps, _mm512_max_ps, _mm512_set1_ps,
    _mm512_setzero_ps, _mm512_storeu_ps,
};

use super::{
    interior_columns, tap_range, Activation, PackedConv2d, Store, Taps, AVX512_C_OUT, CONV_KERNEL,
    CONV_PADDING, STRIP,
};

/// f32 lanes of a zmm register.
const LANES: usize = 16;

/// Computes `P` output pixels x 32 channels into `o` (see [`Store`]).
///
/// `PS` is the pixel stride `s c_in` as a constant (so that every broadcast is a fixed offset from
/// one pointer), or 0 to read it from `t.pix_stride`.
///
/// # Safety
/// The CPU has AVX-512F. For every `ky < n_ky`, `p < P`, `j < run`, the input value
/// `t.input + ky row_stride + p pix_stride + j` is readable, as are `t.weights + ky w_row_stride
/// + 32 j .. + 32` and `bias .. bias + 32`; `o.ptr + p o.stride .. + 32` is writable for `p < P`
/// and aliases none of them; if `o.skip` is not null, `o.skip + p o.stride .. + 32` is readable.
#[target_feature(enable = "avx512f")]
unsafe fn strip<const P: usize, const PS: usize>(t: &Taps, bias: *const f32, o: &Store) {
    let ps = if PS == 0 { t.pix_stride } else { PS };
    // SAFETY: bias holds 32 floats (caller contract).
    let (b0, b1) = unsafe { (_mm512_loadu_ps(bias), _mm512_loadu_ps(bias.add(LANES))) };
    let mut acc: [[__m512; 2]; P] = [[b0, b1]; P];
    for ky in 0..t.n_ky {
        // SAFETY: offsets stay inside the ranges of the caller contract.
        let (row, wrow) = unsafe { (t.input.add(ky * t.row_stride), t.weights.add(ky * t.w_row_stride)) };
        for j in 0..t.run {
            // SAFETY: weight rows `wrow + 32 j .. + 32` and input values `row + p ps + j` for
            // p < P are inside the caller contract's ranges.
            unsafe {
                let w = wrow.add(j * AVX512_C_OUT);
                let (w0, w1) = (_mm512_loadu_ps(w), _mm512_loadu_ps(w.add(LANES)));
                let x = row.add(j);
                for (p, a) in acc.iter_mut().enumerate() {
                    let v = _mm512_set1_ps(*x.add(p * ps));
                    a[0] = _mm512_fmadd_ps(v, w0, a[0]);
                    a[1] = _mm512_fmadd_ps(v, w1, a[1]);
                }
            }
        }
    }
    let zero = _mm512_setzero_ps();
    for (p, a) in acc.iter().enumerate() {
        let (mut v0, mut v1) =
            if o.relu { (_mm512_max_ps(a[0], zero), _mm512_max_ps(a[1], zero)) } else { (a[0], a[1]) };
        // SAFETY: pixel p's 32 destination floats (and skip values) are in the caller contract.
        unsafe {
            if !o.skip.is_null() {
                let s = o.skip.add(p * o.stride);
                v0 = _mm512_add_ps(_mm512_loadu_ps(s), v0);
                v1 = _mm512_add_ps(_mm512_loadu_ps(s.add(LANES)), v1);
            }
            _mm512_storeu_ps(o.ptr.add(p * o.stride), v0);
            _mm512_storeu_ps(o.ptr.add(p * o.stride + LANES), v1);
        }
    }
}

/// A full strip of [`STRIP`] pixels, with the pixel stride as a constant for the network's shapes.
///
/// # Safety
/// As [`strip`] with `P = STRIP`.
#[target_feature(enable = "avx512f")]
pub(crate) unsafe fn full_strip(t: &Taps, bias: *const f32, o: &Store) {
    // SAFETY: forwarded caller contract; PS equals t.pix_stride in every specialised arm.
    unsafe {
        match t.pix_stride {
            3 => strip::<STRIP, 3>(t, bias, o),
            6 => strip::<STRIP, 6>(t, bias, o),
            32 => strip::<STRIP, 32>(t, bias, o),
            35 => strip::<STRIP, 35>(t, bias, o),
            64 => strip::<STRIP, 64>(t, bias, o),
            70 => strip::<STRIP, 70>(t, bias, o),
            _ => strip::<STRIP, 0>(t, bias, o),
        }
    }
}

/// A strip of `n < STRIP` pixels (row tails and border pixels), runtime pixel stride.
///
/// # Safety
/// As [`strip`] with `P = n`.
#[target_feature(enable = "avx512f")]
pub(crate) unsafe fn short_strip(n: usize, t: &Taps, bias: *const f32, o: &Store) {
    // SAFETY: forwarded caller contract with P = n.
    unsafe {
        match n {
            1 => strip::<1, 0>(t, bias, o),
            2 => strip::<2, 0>(t, bias, o),
            3 => strip::<3, 0>(t, bias, o),
            4 => strip::<4, 0>(t, bias, o),
            5 => strip::<5, 0>(t, bias, o),
            6 => strip::<6, 0>(t, bias, o),
            7 => strip::<7, 0>(t, bias, o),
            8 => strip::<8, 0>(t, bias, o),
            9 => strip::<9, 0>(t, bias, o),
            10 => strip::<10, 0>(t, bias, o),
            11 => strip::<11, 0>(t, bias, o),
            12 => strip::<12, 0>(t, bias, o),
            13 => strip::<13, 0>(t, bias, o),
            _ => unreachable!("short strip of {n} pixels"),
        }
    }
}

/// A strip of `n <= STRIP` pixels: [`full_strip`] or [`short_strip`].
///
/// # Safety
/// As [`strip`] with `P = n`.
#[target_feature(enable = "avx512f")]
pub(crate) unsafe fn any_strip(n: usize, t: &Taps, bias: *const f32, o: &Store) {
    // SAFETY: forwarded caller contract.
    unsafe {
        if n == STRIP {
            full_strip(t, bias, o)
        } else {
            short_strip(n, t, bias, o)
        }
    }
}

/// Output row `y` (`w_out · 32` floats) of the convolution. `input` holds the image's rows from
/// `row0` on (`row0 = 0`: the whole image; the staged concatenation of `super::direct_concat` passes
/// a window of rows).
///
/// # Safety
/// The CPU has AVX-512F, `c_out = 32`, `input` holds input rows `row0 .. ` (`w c_in` floats each)
/// up to at least the last row that output row `y` reads, `out_row` holds `w_out · 32` floats and
/// `y < h_out`.
#[target_feature(enable = "avx512f")]
pub(super) unsafe fn conv_row(
    packed: &PackedConv2d,
    input: &[f32],
    row0: usize,
    y: usize,
    activation: Activation,
    out_row: &mut [f32],
) {
    let geom = packed.geometry();
    let (h, w, c_in, s) = (geom.h(), geom.w(), geom.c_in(), geom.stride());
    debug_assert_eq!(geom.c_out(), AVX512_C_OUT);
    debug_assert!(input.len() >= (s * y + CONV_KERNEL - CONV_PADDING).min(h) * w * c_in - row0 * w * c_in);
    debug_assert_eq!(out_row.len(), geom.w_out() * AVX512_C_OUT);
    let relu = activation == Activation::Relu;
    let (ky_lo, ky_hi) = tap_range(y, s, h);
    let bias = packed.bias().as_ptr();
    // Taps of output pixels x0 .. x0 + n, all with the tap columns kx_lo .. kx_hi inside the image.
    let taps = |x0: usize, kx_lo: usize, kx_hi: usize| {
        Taps::of(packed, input, row0, y, (ky_lo, ky_hi), x0, (kx_lo, kx_hi))
    };
    let store = Store { ptr: out_row.as_mut_ptr(), stride: AVX512_C_OUT, skip: std::ptr::null(), relu };
    let (x_lo, x_hi) = interior_columns(geom);
    // Border columns: one pixel each, narrowed kx range.
    for x in (0..x_lo).chain(x_hi..geom.w_out()) {
        let (kx_lo, kx_hi) = tap_range(x, s, w);
        // SAFETY: tap_range keeps rows s y + ky - 1 and columns s x + kx - 1 of every read inside
        // the h x w image, so all reads are in `input`; the weight rows are inside the 9 c_in x 32
        // packed matrix; pixel x of the row is inside `out_row`; AVX-512F per the caller.
        unsafe { short_strip(1, &taps(x, kx_lo, kx_hi), bias, &store.at(x)) };
    }
    // Interior columns: full strips, then one short strip.
    let mut x = x_lo;
    while x < x_hi {
        let n = STRIP.min(x_hi - x);
        let t = taps(x, 0, CONV_KERNEL);
        let o = store.at(x);
        // SAFETY: every pixel x .. x + n is interior, so its full 3x3 window (rows within the ky
        // range) is inside `input`; pixels x .. x + n < w_out are inside `out_row`; weights and
        // bias as above; AVX-512F per the caller.
        unsafe {
            if n == STRIP {
                full_strip(&t, bias, &o);
            } else {
                short_strip(n, &t, bias, &o);
            }
        }
        x += n;
    }
}
