//! The AVX-512F kernel of [`WinogradKernel::Avx512F`](super::WinogradKernel::Avx512F), both
//! variants: one group of up to [`TILES`] tiles of a tile row, `c_out` a multiple of 32. The
//! transforms run across channels (16 per zmm, the last chunk masked); per 32 output channels, the
//! points' dot products over `c_in` run as the direct kernel's register block (tiles x 32 channels
//! in `2 n` accumulators, one broadcast per tile and channel, two FMAs), then the output transform. The same operations in the same order as the
//! portable kernel (module docs of [`super`]), so the same bits. x86-64 only; callers check
//! AVX-512F at run time.

use std::arch::x86_64::{
    __m512, __mmask16, _mm512_add_ps, _mm512_fmadd_ps, _mm512_loadu_ps, _mm512_mask_storeu_ps,
    _mm512_maskz_loadu_ps, _mm512_max_ps, _mm512_mul_ps, _mm512_set1_ps, _mm512_setzero_ps, _mm512_storeu_ps,
    _mm512_sub_ps,
};

use super::tiles::{Tile, MAX_M, MAX_POINTS, MAX_R};
use super::{window_rows, Group, PackedWinograd, Rows, Scratch, SIMD_C_OUT, TILES};
use crate::ops::Activation;

/// f32 lanes of a zmm register.
const LANES: usize = 16;

super::simd::simd_common!(
    "avx512f",
    __m512,
    LANES,
    _mm512_loadu_ps,
    _mm512_storeu_ps,
    _mm512_add_ps,
    _mm512_sub_ps,
    _mm512_mul_ps,
    _mm512_fmadd_ps,
    _mm512_set1_ps,
    _mm512_max_ps,
    _mm512_setzero_ps
);

/// One group of variant `T`: input transform into V, then per 32 output channels the dot
/// products into M and the output transform into `out` (the tile row's output rows, `min(M, h - M
/// ty) · w · c_out` floats in its layout).
///
/// # Safety
/// The CPU has AVX-512F; `packed` is a stride-1 geometry packed for `T` that
/// [`WinogradKernel::Avx512F`](super::WinogradKernel::Avx512F) supports; `input` holds the whole
/// `[h, w, c_in]` map; `out.rows` (and `out.skip`) hold `min(M, h - M ty) · w · c_out` floats; the
/// group's tiles exist (`tx0 + n <= ceil(w / M)`, `1 <= n <= TILES`); `scratch` was made for this
/// geometry and variant.
#[target_feature(enable = "avx512f")]
pub(super) unsafe fn group<T: Tile>(
    packed: &PackedWinograd,
    input: &[f32],
    g: Group,
    activation: Activation,
    scratch: &mut Scratch,
    mut out: Rows<'_>,
) {
    let (c_in, c_out) = (packed.geometry().c_in(), packed.geometry().c_out());
    let (v, m, zeros) = scratch.parts();
    debug_assert!(v.len() >= T::P * TILES * c_in && m.len() >= T::P * TILES * SIMD_C_OUT);
    debug_assert!(g.n >= 1 && g.n <= TILES && c_out.is_multiple_of(SIMD_C_OUT));
    // SAFETY: forwarded caller contract.
    unsafe {
        input_transform::<T>(packed, input, g, v, zeros);
        for og in 0..c_out / SIMD_C_OUT {
            dot_products(packed.transformed(), T::P, (c_in, c_out, og), g.n, v, m);
            output_transform::<T>(packed, g, activation, m, &mut out, og);
        }
    }
}

/// The first `lanes <= 16` floats at `p` (masked: nothing past them is read), zeros above.
///
/// # Safety
/// AVX-512F; `p .. p + lanes` readable.
#[inline]
#[target_feature(enable = "avx512f")]
unsafe fn load_chunk(p: *const f32, lanes: usize) -> __m512 {
    // SAFETY: masked-off lanes are not accessed.
    unsafe { _mm512_maskz_loadu_ps(chunk_mask(lanes), p) }
}

/// Stores the first `lanes <= 16` floats of `v` at `p` (masked when short).
///
/// # Safety
/// AVX-512F; `p .. p + lanes` writable.
#[inline]
#[target_feature(enable = "avx512f")]
unsafe fn store_chunk(p: *mut f32, lanes: usize, v: __m512) {
    // SAFETY: a full chunk is `p .. p + 16`; masked-off lanes are not accessed.
    unsafe {
        if lanes == LANES {
            _mm512_storeu_ps(p, v);
        } else {
            _mm512_mask_storeu_ps(p, chunk_mask(lanes), v);
        }
    }
}

/// The mask of the first `lanes <= 16` lanes.
#[inline]
fn chunk_mask(lanes: usize) -> __mmask16 {
    if lanes >= LANES {
        !0
    } else {
        (1u16 << lanes) - 1
    }
}

/// `M[ξ][t][o - 32 og] = Σ_c V[ξ][t][c] U[ξ][c][o]` (FMA chain from zero, `c` ascending) for the
/// group's `n` tiles, output channels `o` in `32 og .. 32 og + 32` and each of the `points` points.
///
/// # Safety
/// AVX-512F; `u` holds `points · c_in · c_out` floats, `v` `points · n · c_in`, `m` `points · n ·
/// 32`; `32 (og + 1) <= c_out`.
#[target_feature(enable = "avx512f")]
unsafe fn dot_products(
    u: &[f32],
    points: usize,
    (c_in, c_out, og): (usize, usize, usize),
    n: usize,
    v: &[f32],
    m: &mut [f32],
) {
    debug_assert!(u.len() >= points * c_in * c_out && SIMD_C_OUT * (og + 1) <= c_out);
    for xi in 0..points {
        // SAFETY: the point's slices are inside the caller contract's ranges.
        unsafe {
            let up = u.as_ptr().add(xi * c_in * c_out + og * SIMD_C_OUT);
            let vp = v.as_ptr().add(xi * n * c_in);
            let mp = m.as_mut_ptr().add(xi * n * SIMD_C_OUT);
            match (c_in, c_out) {
                (32, 32) => any_block::<32, 32>(n, up, vp, (c_in, c_out), mp),
                (32, 128) => any_block::<32, 128>(n, up, vp, (c_in, c_out), mp),
                (_, 32) => any_block::<0, 32>(n, up, vp, (c_in, c_out), mp),
                _ => any_block::<0, 0>(n, up, vp, (c_in, c_out), mp),
            }
        }
    }
}

/// [`block`] for a group of `n` tiles, `CI`, `CO` as in [`block`].
///
/// # Safety
/// As [`block`] with `P = n`.
#[target_feature(enable = "avx512f")]
unsafe fn any_block<const CI: usize, const CO: usize>(
    n: usize,
    u: *const f32,
    v: *const f32,
    c: (usize, usize),
    m: *mut f32,
) {
    // SAFETY: forwarded caller contract.
    unsafe {
        match n {
            14 => block::<14, CI, CO>(u, v, c, m),
            13 => block::<13, CI, CO>(u, v, c, m),
            12 => block::<12, CI, CO>(u, v, c, m),
            11 => block::<11, CI, CO>(u, v, c, m),
            10 => block::<10, CI, CO>(u, v, c, m),
            9 => block::<9, CI, CO>(u, v, c, m),
            8 => block::<8, CI, CO>(u, v, c, m),
            7 => block::<7, CI, CO>(u, v, c, m),
            6 => block::<6, CI, CO>(u, v, c, m),
            5 => block::<5, CI, CO>(u, v, c, m),
            4 => block::<4, CI, CO>(u, v, c, m),
            3 => block::<3, CI, CO>(u, v, c, m),
            2 => block::<2, CI, CO>(u, v, c, m),
            1 => block::<1, CI, CO>(u, v, c, m),
            _ => unreachable!("a group of {n} tiles"),
        }
    }
}

/// `P` tiles x 32 output channels of one Winograd point: `P · 2` accumulators. `CI` and `CO` are
/// `c_in` and `c_out` (the stride of `u`'s rows) as constants (so each load is a fixed offset from
/// one pointer), or 0 to use `c = (c_in, c_out)`.
///
/// # Safety
/// AVX-512F; `u + c_out c .. + 32` for `c < c_in`, `v .. v + P c_in` readable, `m .. m + 32 P`
/// writable.
#[target_feature(enable = "avx512f")]
unsafe fn block<const P: usize, const CI: usize, const CO: usize>(
    u: *const f32,
    v: *const f32,
    (c_in, c_out): (usize, usize),
    m: *mut f32,
) {
    let ci = if CI == 0 { c_in } else { CI };
    let co = if CO == 0 { c_out } else { CO };
    let mut acc = [[_mm512_setzero_ps(); 2]; P];
    for c in 0..ci {
        // SAFETY: c < c_in keeps every read inside the caller contract's ranges.
        unsafe {
            let w = u.add(c * co);
            let (w0, w1) = (_mm512_loadu_ps(w), _mm512_loadu_ps(w.add(LANES)));
            let x0 = v.add(c);
            for (t, a) in acc.iter_mut().enumerate() {
                let x = _mm512_set1_ps(*x0.add(t * ci));
                a[0] = _mm512_fmadd_ps(x, w0, a[0]);
                a[1] = _mm512_fmadd_ps(x, w1, a[1]);
            }
        }
    }
    for (t, a) in acc.iter().enumerate() {
        // SAFETY: tile t's 32 floats are inside `m .. m + 32 P`.
        unsafe {
            _mm512_storeu_ps(m.add(t * SIMD_C_OUT), a[0]);
            _mm512_storeu_ps(m.add(t * SIMD_C_OUT + LANES), a[1]);
        }
    }
}
