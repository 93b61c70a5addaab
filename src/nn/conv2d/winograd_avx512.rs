//! The AVX-512F kernel of [`WinogradKernel::Avx512F`](super::winograd::WinogradKernel::Avx512F):
//! one group of up to [`TILES`] tiles of a tile row, `c_out = 32`. The transforms run across
//! channels (16 per zmm, the last chunk masked); the 16 dot products over `c_in` run as the direct
//! kernel's register block (tiles x 32 channels in `2 n` accumulators, one broadcast per tile and
//! channel, two FMAs). The same operations in the same order as the portable kernel (module docs
//! of [`super::winograd`]), so the same bits. x86-64 only; callers check AVX-512F at run time.

use std::arch::x86_64::{
    __m512, __mmask16, _mm512_add_ps, _mm512_fmadd_ps, _mm512_loadu_ps, _mm512_mask_storeu_ps,
    _mm512_maskz_loadu_ps, _mm512_max_ps, _mm512_set1_ps, _mm512_setzero_ps, _mm512_storeu_ps, _mm512_sub_ps,
};

use super::winograd::{Group, PackedWinograd, Scratch, AVX512_C_OUT, POINTS, TILES};
use crate::nn::Activation;

/// f32 lanes of a zmm register.
const LANES: usize = 16;

/// One group: input transform into `scratch.v`, dot products into `scratch.m`, output transform
/// into `rows` (output rows `2 ty` and, if it exists, `2 ty + 1`, each `w · 32` floats).
///
/// # Safety
/// The CPU has AVX-512F; `packed` is a stride-1 geometry with `c_out = 32`; `input` holds the
/// whole `[h, w, c_in]` map; `rows` holds `min(2, h - 2 ty) · w · 32` floats; the group's tiles
/// exist (`tx0 + n <= ceil(w / 2)`, `1 <= n <= TILES`); `scratch` was made for this geometry.
#[target_feature(enable = "avx512f")]
pub(super) unsafe fn group(
    packed: &PackedWinograd,
    input: &[f32],
    g: Group,
    activation: Activation,
    scratch: &mut Scratch,
    rows: &mut [f32],
) {
    let c_in = packed.geometry().c_in();
    let (v, m, zeros) = scratch.parts();
    debug_assert!(v.len() >= POINTS * TILES * c_in && m.len() >= POINTS * TILES * AVX512_C_OUT);
    debug_assert!(g.n >= 1 && g.n <= TILES);
    // SAFETY: forwarded caller contract.
    unsafe {
        input_transform(packed, input, g, v, zeros);
        dot_products(packed.transformed(), c_in, g.n, v, m);
        output_transform(packed, g, activation, m, rows);
    }
}

/// `V[ξ][t][c] = (Bᵀ d B)[ξ]` for every tile `t` of the group and channel `c`, 16 channels at a
/// time. Interior tiles (whole window inside the image's columns) with `c_in` a multiple of 16 read
/// their four rows through row pointers, a row outside the image pointing at `zeros`; the others
/// use masked loads (zero, no access, outside the image).
///
/// # Safety
/// As [`group`]; `v` holds `POINTS · n · c_in` floats, `zeros` `w · c_in` zeros.
#[target_feature(enable = "avx512f")]
unsafe fn input_transform(packed: &PackedWinograd, input: &[f32], g: Group, v: &mut [f32], zeros: &[f32]) {
    let geom = packed.geometry();
    let (h, w, c_in) = (geom.h(), geom.w(), geom.c_in());
    debug_assert!(zeros.len() >= w * c_in);
    let base = input.as_ptr();
    let vp = v.as_mut_ptr();
    let rows: [*const f32; 4] = std::array::from_fn(|r| {
        let iy = (2 * g.ty + r).wrapping_sub(1);
        // SAFETY (of the offset): iy < h is a row of the image.
        if iy < h {
            unsafe { base.add(iy * w * c_in) }
        } else {
            zeros.as_ptr()
        }
    });
    for t in 0..g.n {
        let tx = g.tx0 + t;
        let interior = tx >= 1 && 2 * tx + 2 < w && c_in.is_multiple_of(LANES);
        for c0 in (0..c_in).step_by(LANES) {
            let lanes = LANES.min(c_in - c0);
            let chan: __mmask16 = if lanes == LANES { !0 } else { (1u16 << lanes) - 1 };
            let mut d = [_mm512_setzero_ps(); POINTS];
            if interior {
                let col = (2 * tx - 1) * c_in + c0;
                for (k, dk) in d.iter_mut().enumerate() {
                    // SAFETY: columns 2 tx - 1 ..= 2 tx + 2 are inside the image and 16 channels
                    // from c0 exist; each row pointer is an image row or `zeros` (w c_in floats).
                    *dk = unsafe { _mm512_loadu_ps(rows[k / 4].add(col + (k % 4) * c_in)) };
                }
            } else {
                for (k, dk) in d.iter_mut().enumerate() {
                    let (iy, ix) = ((2 * g.ty + k / 4).wrapping_sub(1), (2 * tx + k % 4).wrapping_sub(1));
                    if iy < h && ix < w {
                        // SAFETY: (iy, ix) is inside the image, and channels c0 .. c0 + lanes exist.
                        *dk = unsafe { _mm512_maskz_loadu_ps(chan, base.add((iy * w + ix) * c_in + c0)) };
                    }
                }
            }
            let mut e = [_mm512_setzero_ps(); POINTS];
            for r in 0..4 {
                let x = &d[4 * r..4 * r + 4];
                e[4 * r] = _mm512_sub_ps(x[0], x[2]);
                e[4 * r + 1] = _mm512_add_ps(x[1], x[2]);
                e[4 * r + 2] = _mm512_sub_ps(x[2], x[1]);
                e[4 * r + 3] = _mm512_sub_ps(x[1], x[3]);
            }
            for j in 0..4 {
                let vals = [
                    _mm512_sub_ps(e[j], e[8 + j]),
                    _mm512_add_ps(e[4 + j], e[8 + j]),
                    _mm512_sub_ps(e[8 + j], e[4 + j]),
                    _mm512_sub_ps(e[4 + j], e[12 + j]),
                ];
                for (i, val) in vals.into_iter().enumerate() {
                    let at = ((4 * i + j) * g.n + t) * c_in + c0;
                    // SAFETY: at + lanes <= POINTS n c_in (caller contract).
                    unsafe {
                        if lanes == LANES {
                            _mm512_storeu_ps(vp.add(at), val);
                        } else {
                            _mm512_mask_storeu_ps(vp.add(at), chan, val);
                        }
                    }
                }
            }
        }
    }
}

/// `M[ξ][t][o] = Σ_c V[ξ][t][c] U[ξ][c][o]` (FMA chain from zero, `c` ascending) for the group's
/// `n` tiles.
///
/// # Safety
/// AVX-512F; `u` holds `POINTS · c_in · 32` floats, `v` `POINTS · n · c_in`, `m` `POINTS · n · 32`.
#[target_feature(enable = "avx512f")]
unsafe fn dot_products(u: &[f32], c_in: usize, n: usize, v: &[f32], m: &mut [f32]) {
    debug_assert!(u.len() >= POINTS * c_in * AVX512_C_OUT);
    for xi in 0..POINTS {
        // SAFETY: the point's slices are inside the caller contract's ranges.
        unsafe {
            let up = u.as_ptr().add(xi * c_in * AVX512_C_OUT);
            let vp = v.as_ptr().add(xi * n * c_in);
            let mp = m.as_mut_ptr().add(xi * n * AVX512_C_OUT);
            if c_in == 32 {
                any_block::<32>(n, up, vp, c_in, mp);
            } else {
                any_block::<0>(n, up, vp, c_in, mp);
            }
        }
    }
}

/// [`block`] for a group of `n` tiles, `CI` as in [`block`].
///
/// # Safety
/// As [`block`] with `P = n`.
#[target_feature(enable = "avx512f")]
unsafe fn any_block<const CI: usize>(n: usize, u: *const f32, v: *const f32, c_in: usize, m: *mut f32) {
    // SAFETY: forwarded caller contract.
    unsafe {
        match n {
            14 => block::<14, CI>(u, v, c_in, m),
            13 => block::<13, CI>(u, v, c_in, m),
            12 => block::<12, CI>(u, v, c_in, m),
            11 => block::<11, CI>(u, v, c_in, m),
            10 => block::<10, CI>(u, v, c_in, m),
            9 => block::<9, CI>(u, v, c_in, m),
            8 => block::<8, CI>(u, v, c_in, m),
            7 => block::<7, CI>(u, v, c_in, m),
            6 => block::<6, CI>(u, v, c_in, m),
            5 => block::<5, CI>(u, v, c_in, m),
            4 => block::<4, CI>(u, v, c_in, m),
            3 => block::<3, CI>(u, v, c_in, m),
            2 => block::<2, CI>(u, v, c_in, m),
            1 => block::<1, CI>(u, v, c_in, m),
            _ => unreachable!("a group of {n} tiles"),
        }
    }
}

/// `P` tiles x 32 output channels of one Winograd point: `P · 2` accumulators. `CI` is `c_in` as
/// a constant (so each tile's broadcast is a fixed offset from one pointer), or 0 to use `c_in`.
///
/// # Safety
/// AVX-512F; `u .. u + 32 c_in`, `v .. v + P c_in` readable, `m .. m + 32 P` writable.
#[target_feature(enable = "avx512f")]
unsafe fn block<const P: usize, const CI: usize>(u: *const f32, v: *const f32, c_in: usize, m: *mut f32) {
    let ci = if CI == 0 { c_in } else { CI };
    let mut acc = [[_mm512_setzero_ps(); 2]; P];
    for c in 0..ci {
        // SAFETY: c < c_in keeps every read inside the caller contract's ranges.
        unsafe {
            let w = u.add(c * AVX512_C_OUT);
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
            _mm512_storeu_ps(m.add(t * AVX512_C_OUT), a[0]);
            _mm512_storeu_ps(m.add(t * AVX512_C_OUT + LANES), a[1]);
        }
    }
}

/// `act((Aᵀ M A) + b)` for every tile of the group into its (up to) 2x2 output pixels.
///
/// # Safety
/// As [`group`].
#[target_feature(enable = "avx512f")]
unsafe fn output_transform(
    packed: &PackedWinograd,
    g: Group,
    activation: Activation,
    m: &[f32],
    rows: &mut [f32],
) {
    let geom = packed.geometry();
    let (h, w) = (geom.h(), geom.w());
    let relu = activation == Activation::Relu;
    let zero = _mm512_setzero_ps();
    let out = rows.as_mut_ptr();
    let n_rows = 2.min(h - 2 * g.ty);
    for half in 0..2 {
        // SAFETY: the bias holds 32 floats.
        let b = unsafe { _mm512_loadu_ps(packed.bias().as_ptr().add(half * LANES)) };
        for t in 0..g.n {
            let tx = g.tx0 + t;
            // SAFETY: point ξ's tile t lives at (ξ n + t) 32 + half 16 .. + 16 inside `m`.
            let x: [__m512; POINTS] = std::array::from_fn(|xi| unsafe {
                _mm512_loadu_ps(m.as_ptr().add((xi * g.n + t) * AVX512_C_OUT + half * LANES))
            });
            let mut s = [[zero; 2]; 4];
            for (i, row) in s.iter_mut().enumerate() {
                let r = &x[4 * i..4 * i + 4];
                *row = [
                    _mm512_add_ps(_mm512_add_ps(r[0], r[1]), r[2]),
                    _mm512_sub_ps(_mm512_sub_ps(r[1], r[2]), r[3]),
                ];
            }
            for (j, ox) in (2 * tx..w.min(2 * tx + 2)).enumerate() {
                let y = [
                    _mm512_add_ps(_mm512_add_ps(s[0][j], s[1][j]), s[2][j]),
                    _mm512_sub_ps(_mm512_sub_ps(s[1][j], s[2][j]), s[3][j]),
                ];
                for (r, yr) in y.iter().enumerate().take(n_rows) {
                    let mut val = _mm512_add_ps(*yr, b);
                    if relu {
                        val = _mm512_max_ps(val, zero);
                    }
                    // SAFETY: output row r < n_rows of the tile row, column ox < w: inside `rows`.
                    unsafe { _mm512_storeu_ps(out.add((r * w + ox) * AVX512_C_OUT + half * LANES), val) };
                }
            }
        }
    }
}
