//! The AVX2+FMA kernel of [`WinogradKernel::Avx2Fma`](super::WinogradKernel::Avx2Fma), both
//! variants, for x86-64 CPUs without AVX-512: one group of up to [`TILES`] tiles of a tile row,
//! `c_out` a multiple of 32, `c_in` a multiple of 8. The transforms run across channels (8 per
//! ymm); per 32 output channels, the dot products run as the AVX2 direct kernel's register block
//! (up to [`STRIP`] tiles x 16 output channels in 12 ymm accumulators, once per channel half), then
//! the output transform. The same operations in the same order as the other
//! Winograd kernels (module docs of [`super`]), so the same bits. x86-64 only; callers
//! check AVX2 and FMA at run time.

use std::arch::x86_64::{
    __m256, _mm256_add_ps, _mm256_fmadd_ps, _mm256_loadu_ps, _mm256_max_ps, _mm256_mul_ps, _mm256_set1_ps,
    _mm256_setzero_ps, _mm256_storeu_ps, _mm256_sub_ps,
};

use super::tiles::{Tile, MAX_M, MAX_POINTS, MAX_R};
use super::{window_rows, Group, PackedWinograd, Rows, Scratch, SIMD_C_OUT};
use crate::ops::Activation;

/// f32 lanes of a ymm register.
const LANES: usize = 8;

super::simd::simd_common!(
    "avx2,fma",
    __m256,
    LANES,
    _mm256_loadu_ps,
    _mm256_storeu_ps,
    _mm256_add_ps,
    _mm256_sub_ps,
    _mm256_mul_ps,
    _mm256_fmadd_ps,
    _mm256_set1_ps,
    _mm256_max_ps,
    _mm256_setzero_ps
);

/// Output channels per dot-product pass (two ymm registers).
const HALF: usize = 16;

/// Tiles per dot-product block: `2 · 6 = 12` accumulators, two weight registers, one broadcast.
const STRIP: usize = 6;

/// One group of variant `T`: input transform into V, then per 32 output channels the dot
/// products into M and the output transform into `out` (the tile row's output rows, `min(M, h - M
/// ty) · w · c_out` floats in its layout).
///
/// # Safety
/// The CPU has AVX2 and FMA; `packed` is a stride-1 geometry packed for `T` that
/// [`WinogradKernel::Avx2Fma`](super::WinogradKernel::Avx2Fma) supports; `input` holds the whole
/// `[h, w, c_in]` map; `out.rows` (and `out.skip`) hold `min(M, h - M ty) · w · c_out` floats;
/// the group's tiles exist (`tx0 + n <= ceil(w / M)`, `1 <= n <= TILES`); `scratch` was made for
/// this geometry and variant.
#[target_feature(enable = "avx2,fma")]
pub(super) unsafe fn group<T: Tile>(
    packed: &PackedWinograd,
    input: &[f32],
    g: Group,
    activation: Activation,
    scratch: &mut Scratch,
    mut out: Rows<'_>,
) {
    let (c_in, c_out) = (packed.geometry().c_in(), packed.geometry().c_out());
    debug_assert!(c_in % LANES == 0 && c_out.is_multiple_of(SIMD_C_OUT));
    let (v, m, zeros) = scratch.parts();
    // SAFETY: forwarded caller contract.
    unsafe {
        input_transform::<T>(packed, input, g, v, zeros);
        for og in 0..c_out / SIMD_C_OUT {
            for t0 in (0..g.n).step_by(STRIP) {
                for h in 0..2 {
                    let tiles = (t0, STRIP.min(g.n - t0));
                    dot_products(packed.transformed(), T::P, (c_in, c_out, og), g.n, tiles, h, v, m);
                }
            }
            output_transform::<T>(packed, g, activation, m, &mut out, og);
        }
    }
}

/// The 8 floats at `p` (`c_in` is a multiple of 8, so every chunk is whole).
///
/// # Safety
/// AVX2; `p .. p + 8` readable.
#[inline]
#[target_feature(enable = "avx2,fma")]
unsafe fn load_chunk(p: *const f32, lanes: usize) -> __m256 {
    debug_assert_eq!(lanes, LANES);
    // SAFETY: caller contract.
    unsafe { _mm256_loadu_ps(p) }
}

/// Stores the 8 floats of `v` at `p`.
///
/// # Safety
/// AVX2; `p .. p + 8` writable.
#[inline]
#[target_feature(enable = "avx2,fma")]
unsafe fn store_chunk(p: *mut f32, lanes: usize, v: __m256) {
    debug_assert_eq!(lanes, LANES);
    // SAFETY: caller contract.
    unsafe { _mm256_storeu_ps(p, v) }
}

/// `M[ξ][t][o - 32 og]` for tiles `t0 .. t0 + p` and output channels `o` in `32 og + 16 h .. + 16`,
/// every point.
///
/// # Safety
/// AVX2 and FMA; `u` holds `points · c_in · c_out` floats, `v` `points · n · c_in`, `m` `points ·
/// n · 32`; `t0 + p <= n`, `1 <= p <= STRIP`, `h < 2`, `32 (og + 1) <= c_out`.
#[allow(clippy::too_many_arguments)]
#[target_feature(enable = "avx2,fma")]
unsafe fn dot_products(
    u: &[f32],
    points: usize,
    (c_in, c_out, og): (usize, usize, usize),
    n: usize,
    (t0, p): (usize, usize),
    h: usize,
    v: &[f32],
    m: &mut [f32],
) {
    debug_assert!(u.len() >= points * c_in * c_out && t0 + p <= n && h < 2);
    debug_assert!(SIMD_C_OUT * (og + 1) <= c_out);
    for xi in 0..points {
        // SAFETY: the point's slices are inside the caller contract's ranges.
        unsafe {
            let up = u.as_ptr().add(xi * c_in * c_out + og * SIMD_C_OUT + h * HALF);
            let vp = v.as_ptr().add((xi * n + t0) * c_in);
            let mp = m.as_mut_ptr().add((xi * n + t0) * SIMD_C_OUT + h * HALF);
            let c = (c_in, c_out);
            match (p, c_in) {
                (6, 32) => block::<6, 32>(up, vp, c, mp),
                (6, _) => block::<6, 0>(up, vp, c, mp),
                (5, _) => block::<5, 0>(up, vp, c, mp),
                (4, _) => block::<4, 0>(up, vp, c, mp),
                (3, _) => block::<3, 0>(up, vp, c, mp),
                (2, _) => block::<2, 0>(up, vp, c, mp),
                (1, _) => block::<1, 0>(up, vp, c, mp),
                _ => unreachable!("a block of {p} tiles"),
            }
        }
    }
}

/// `P` tiles x 16 output channels of one point (FMA chain from zero over `c`). `CI` is `c_in` as a
/// constant, or 0 to use `c = (c_in, c_out)` (`c_out` is the stride of `u`'s rows).
///
/// # Safety
/// AVX2 and FMA; `u + c_out c .. + 16` for `c < c_in`, `v .. v + P c_in` readable; `m + 32 t .. + 16`
/// writable for `t < P`.
#[target_feature(enable = "avx2,fma")]
unsafe fn block<const P: usize, const CI: usize>(
    u: *const f32,
    v: *const f32,
    (c_in, c_out): (usize, usize),
    m: *mut f32,
) {
    let ci = if CI == 0 { c_in } else { CI };
    let mut acc = [[_mm256_setzero_ps(); 2]; P];
    for c in 0..ci {
        // SAFETY: c < c_in keeps every read inside the caller contract's ranges.
        unsafe {
            let w = u.add(c * c_out);
            let (w0, w1) = (_mm256_loadu_ps(w), _mm256_loadu_ps(w.add(LANES)));
            let x0 = v.add(c);
            for (t, a) in acc.iter_mut().enumerate() {
                let x = _mm256_set1_ps(*x0.add(t * ci));
                a[0] = _mm256_fmadd_ps(x, w0, a[0]);
                a[1] = _mm256_fmadd_ps(x, w1, a[1]);
            }
        }
    }
    for (t, a) in acc.iter().enumerate() {
        // SAFETY: tile t's 16 floats are inside the caller contract.
        unsafe {
            _mm256_storeu_ps(m.add(t * SIMD_C_OUT), a[0]);
            _mm256_storeu_ps(m.add(t * SIMD_C_OUT + LANES), a[1]);
        }
    }
}
