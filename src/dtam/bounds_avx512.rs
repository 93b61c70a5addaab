//! The AVX-512 build of [`super::bounds::bounded_search`]: the same bounds, energies and choices
//! (SPEC.md §10.1), eight blocks' bounds or one block's eight energies per register. Every value is
//! the scalar code's sequence of IEEE operations (no fused multiply-adds), and the least `(E, k)` is
//! found by a minimum and the first lane equal to it, so the result is the same bits; where the
//! scalar code would fall back to the plain scan (a NaN, `d` not finite), this calls it.
//!
//! Every function here is `unsafe`: it must be inlined into a function built with AVX-512F that
//! runs only where the CPU reported it.

use std::arch::x86_64::*;

use super::avx512::{energy, splat};
use super::bounds::{self, BLOCK_BINS};
use super::search::{SearchParams, UNSEEN};

/// Most blocks one search covers in this build (ranges of up to 512 hypotheses); wider ones run
/// the portable search.
const MAX_BLOCKS: usize = 64;

/// The lanes below `n` (all eight for `n >= 8`).
#[inline(always)]
fn below(n: usize) -> __mmask8 {
    if n >= 8 {
        0xff
    } else {
        (1u8 << n) - 1
    }
}

/// `s[at..at + 8]` in the lanes of `m`, 0 elsewhere (the lanes of `m` lie inside `s`). Where all
/// eight lie inside `s`, one plain 256-bit load: the masked load that AVX-512F offers without VL is
/// 512 bits wide, and it waits for both cache lines it spans even where the second is masked off
/// (a block at the upper half of a line stalled the bounded search on the next line, never read;
/// SPEC.md §10.1).
#[inline(always)]
unsafe fn load8(m: __mmask8, s: &[f32], at: usize) -> __m256 {
    let p = s.as_ptr().add(at);
    let wide = if at + 8 <= s.len() {
        _mm512_maskz_mov_ps(u16::from(m), _mm512_castps256_ps512(_mm256_loadu_ps(p)))
    } else {
        _mm512_maskz_loadu_ps(u16::from(m), p)
    };
    _mm512_castps512_ps256(wide)
}

/// [`bounds::bounded_search`] on registers.
///
/// # Safety
/// Inlined into AVX-512F code only (see the module documentation); `curve` holds `K` costs and
/// `minima` the pixel's `⌈K/8⌉` block minima, with `lo <= hi < K`.
#[inline(always)]
pub(super) unsafe fn bounded_search(
    curve: &[f32],
    minima: &[f32],
    p: &SearchParams,
    d: f64,
    lo: usize,
    hi: usize,
) -> Option<(usize, f64)> {
    let (first, last) = (lo / BLOCK_BINS, hi / BLOCK_BINS);
    let n = last - first + 1;
    if n > MAX_BLOCKS || !bounds::applies(d, p) {
        return bounds::bounded_search(curve, minima, p, d, lo, hi);
    }
    let dv = splat(d);
    // The bounds of blocks `first..=last` (+∞ where a block has no seen cell), which are seen, and
    // their least value.
    let mut lb = [0.0f64; MAX_BLOCKS];
    let (mut seen, mut least) = (0u64, splat(f64::INFINITY));
    for c in (0..n).step_by(8) {
        let (m, j) = (below(n - c), first + c);
        let mins = _mm512_cvtps_pd(load8(m, minima, j));
        let rlo = _mm512_maskz_loadu_pd(m, p.rho_block_lo.as_ptr().add(j));
        let rhi = _mm512_maskz_loadu_pd(m, p.rho_block_hi.as_ptr().add(j));
        let s = _mm512_mask_cmp_pd_mask::<_CMP_LT_OQ>(m, mins, splat(f64::from(UNSEEN)));
        // `d < lo ? lo : d > hi ? hi : d`
        let under = _mm512_cmp_pd_mask::<_CMP_LT_OQ>(dv, rlo);
        let over = _mm512_cmp_pd_mask::<_CMP_GT_OQ>(dv, rhi);
        let nearest = _mm512_mask_blend_pd(over, _mm512_mask_blend_pd(under, dv, rlo), rhi);
        let b = energy(dv, nearest, mins, p);
        if _mm512_mask_cmp_pd_mask::<_CMP_UNORD_Q>(m, mins, mins) != 0
            || _mm512_mask_cmp_pd_mask::<_CMP_UNORD_Q>(s, b, b) != 0
        {
            return bounds::bounded_search(curve, minima, p, d, lo, hi);
        }
        let b = _mm512_mask_blend_pd(s, splat(f64::INFINITY), b);
        _mm512_storeu_pd(lb.as_mut_ptr().add(c), b);
        least = _mm512_min_pd(least, b);
        seen |= u64::from(s) << c;
    }
    if seen == 0 {
        return None;
    }
    // The first seen block with the least bound.
    let least = splat(_mm512_reduce_min_pd(least));
    let mut start = n;
    for c in (0..n).step_by(8) {
        let s = (seen >> c) as u8;
        let eq = _mm512_mask_cmp_pd_mask::<_CMP_EQ_OQ>(s, _mm512_loadu_pd(lb.as_ptr().add(c)), least);
        if eq != 0 {
            start = c + eq.trailing_zeros() as usize;
            break;
        }
    }
    let Some(mut best) = block(curve, p, dv, first + start, lo, hi) else {
        return bounds::bounded_search(curve, minima, p, d, lo, hi);
    };
    // Every other block its bound does not rule out against the start block's best (scanning more
    // than needed changes nothing: the least `(E, k)` is merged exactly).
    for c in (0..n).step_by(8) {
        let s = (seen >> c) as u8 & !(if start / 8 == c / 8 { 1u8 << (start % 8) } else { 0 });
        let candidates = match best {
            None => s,
            Some((k_best, e_best)) => {
                let (b, e) = (_mm512_loadu_pd(lb.as_ptr().add(c)), splat(e_best));
                // On a tie, only blocks before the best's own block can hold a lower `k`.
                let earlier = below((k_best / BLOCK_BINS - first).saturating_sub(c));
                _mm512_mask_cmp_pd_mask::<_CMP_LT_OQ>(s, b, e)
                    | (_mm512_mask_cmp_pd_mask::<_CMP_EQ_OQ>(s, b, e) & earlier)
            }
        };
        let mut rest = candidates;
        while rest != 0 {
            let j = first + c + rest.trailing_zeros() as usize;
            rest &= rest - 1;
            let Some(found) = block(curve, p, dv, j, lo, hi) else {
                return bounds::bounded_search(curve, minima, p, d, lo, hi);
            };
            if let Some((k, e)) = found {
                if best.is_none_or(|(k_best, e_best)| e < e_best || (e == e_best && k < k_best)) {
                    best = Some((k, e));
                }
            }
        }
    }
    best
}

/// The least `(E, k)` over block `j`'s seen cells within `lo..=hi` (`Some(None)`: none seen;
/// `None`: a NaN energy).
#[inline(always)]
unsafe fn block(
    curve: &[f32],
    p: &SearchParams,
    dv: __m512d,
    j: usize,
    lo: usize,
    hi: usize,
) -> Option<Option<(usize, f64)>> {
    let base = j * BLOCK_BINS;
    let (from, to) = (base.max(lo), (base + BLOCK_BINS - 1).min(hi));
    let m = below(to - base + 1) & !below(from - base);
    let c = _mm512_cvtps_pd(load8(m, curve, base));
    let rho = _mm512_maskz_loadu_pd(m, p.rho.as_ptr().add(base));
    let seen = _mm512_mask_cmp_pd_mask::<_CMP_LT_OQ>(m, c, splat(f64::from(UNSEEN)));
    let e = energy(dv, rho, c, p);
    if _mm512_mask_cmp_pd_mask::<_CMP_UNORD_Q>(seen, e, e) != 0 {
        return None;
    }
    if seen == 0 {
        return Some(None);
    }
    let least = _mm512_mask_reduce_min_pd(seen, e);
    let at = _mm512_mask_cmp_pd_mask::<_CMP_EQ_OQ>(seen, e, splat(least)).trailing_zeros() as usize;
    Some(Some((base + at, least)))
}
