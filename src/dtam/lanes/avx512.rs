//! AVX-512 builds of the lane-wise kernels of the a-search and of the energy terms: the same IEEE
//! operations as the portable code (`portable.rs`), lane for lane and in the same order, on whole `__m512d` registers (8 pixels), with the costs gathered from the
//! pixels' curves. No fused multiply-adds, and every comparison keeps Rust's NaN semantics, hence
//! the same bits (tested against the portable build and the scalar definition in tests/dtam.rs).
//!
//! Every function here is `unsafe`: it must be inlined into a function built with AVX-512F that
//! runs only where the CPU reported it, and its offsets must lie in the cost slice.

use std::arch::x86_64::*;

use super::{
    applies, bounded_search_portable, Lanes, Scan, SearchParams, BLOCK_BINS, LANES, MAX_PARABOLA_OFFSET,
    UNSEEN,
};

/// `v` in every lane.
#[inline(always)]
unsafe fn splat(v: f64) -> __m512d {
    _mm512_set1_pd(v)
}

/// Eight `usize` as `i64` lanes.
#[inline(always)]
unsafe fn load_idx(v: &[usize; LANES]) -> __m512i {
    _mm512_loadu_si512(v.as_ptr().cast())
}

/// Eight `bool` as a mask.
#[inline(always)]
fn mask(v: &[bool; LANES]) -> __mmask8 {
    v.iter().enumerate().fold(0, |m, (j, &b)| m | (u8::from(b) << j))
}

/// `costs[i]` per lane, as `f64`. Eight scalar loads: on the Skylake-SP machine of SPEC.md §12.2
/// they beat `vgatherqps` (the DTAM solve at 320x240, K = 128 took 20% less time).
#[inline(always)]
unsafe fn gather(costs: &[f32], i: __m512i) -> __m512d {
    let mut idx = [0usize; LANES];
    _mm512_storeu_si512(idx.as_mut_ptr().cast(), i);
    let c = costs.as_ptr();
    let at = |j: usize| *c.add(idx[j]);
    _mm512_cvtps_pd(_mm256_setr_ps(at(0), at(1), at(2), at(3), at(4), at(5), at(6), at(7)))
}

/// `i` (small, non-negative) as `f64`.
#[inline(always)]
unsafe fn to_f64(i: __m512i) -> __m512d {
    _mm512_cvtepi32_pd(_mm512_cvtepi64_epi32(i))
}

/// `ρ_k` by [`crate::geometry::InverseDepthBins::rho`]'s formula.
#[inline(always)]
unsafe fn rho(k: __m512i, p: &SearchParams) -> __m512d {
    let v = _mm512_add_pd(splat(p.rho_min), _mm512_mul_pd(to_f64(k), splat(p.step)));
    let last = _mm512_cmpeq_epi64_mask(k, _mm512_set1_epi64(p.k as i64 - 1));
    _mm512_mask_blend_pd(last, v, splat(p.rho_max))
}

/// `search::energy`: `(d - ρ)² · 1/(2θ) + c · 1/λ`.
#[inline(always)]
unsafe fn energy(d: __m512d, rho: __m512d, c: __m512d, p: &SearchParams) -> __m512d {
    let diff = _mm512_sub_pd(d, rho);
    _mm512_add_pd(
        _mm512_mul_pd(_mm512_mul_pd(diff, diff), splat(p.inv_two_theta)),
        _mm512_mul_pd(c, splat(p.inv_lambda)),
    )
}

/// `f64::clamp(x, lo, hi)`: `if x < lo { lo }`, then `if x > hi { hi }` (NaN stays NaN).
#[inline(always)]
unsafe fn clamp(x: __m512d, lo: f64, hi: f64) -> __m512d {
    let x = _mm512_mask_blend_pd(_mm512_cmp_pd_mask::<_CMP_LT_OQ>(x, splat(lo)), x, splat(lo));
    _mm512_mask_blend_pd(_mm512_cmp_pd_mask::<_CMP_GT_OQ>(x, splat(hi)), x, splat(hi))
}

/// The registers of a group's scan: curve offsets, ranges, `d`, the live lanes.
struct Group {
    off: __m512i,
    lo: __m512i,
    hi: __m512i,
    d: __m512d,
    live: __mmask8,
    span: usize,
}

/// Step `t` of a scan: the hypotheses `lo + t` (clamped to `lo` past `hi`), the lanes where that is
/// in range, their costs and `ρ`.
#[inline(always)]
unsafe fn step(
    costs: &[f32],
    p: &SearchParams,
    g: &Group,
    t: usize,
) -> (__m512i, __mmask8, __m512d, __m512d) {
    let k = _mm512_add_epi64(g.lo, _mm512_set1_epi64(t as i64));
    let active = g.live & _mm512_cmple_epi64_mask(k, g.hi);
    let k = _mm512_mask_blend_epi64(active, g.lo, k);
    let c = gather(costs, _mm512_add_epi64(g.off, k));
    (k, active, c, rho(k, p))
}

/// `!(c >= UNSEEN)`: the cells the scan considers (NaN included).
#[inline(always)]
unsafe fn scanned(c: __m512d) -> __mmask8 {
    _mm512_cmp_pd_mask::<_CMP_NGE_UQ>(c, splat(UNSEEN as f64))
}

/// The scalar definition's scan, lane-wise: the first scanned cell is taken, then any with a
/// strictly lower energy (`e < best` is false for NaN). Returns the best energy, its hypothesis and
/// the lanes that found one.
#[inline(always)]
unsafe fn scan_exact(costs: &[f32], p: &SearchParams, g: &Group) -> (__m512d, __m512i, __mmask8) {
    let (mut best, mut arg, mut found) = (splat(f64::INFINITY), _mm512_setzero_si512(), 0u8);
    for t in 0..g.span {
        let (k, active, c, rho) = step(costs, p, g, t);
        let e = energy(g.d, rho, c, p);
        let lower = _mm512_cmp_pd_mask::<_CMP_LT_OQ>(e, best);
        let take = active & scanned(c) & (!found | lower);
        best = _mm512_mask_blend_pd(take, best, e);
        arg = _mm512_mask_blend_epi64(take, arg, k);
        found |= take;
    }
    (best, arg, found)
}

/// `portable::scan_lanes` on registers: [`scan_exact`] over every lane's `lo..=hi`.
///
/// # Safety
/// See the module documentation; `l.off[j] + k < costs.len()` for every `k < K`.
#[inline(always)]
pub(super) unsafe fn scan_lanes(costs: &[f32], p: &SearchParams, l: &Lanes) -> Scan {
    let g = Group {
        off: load_idx(&l.off),
        lo: load_idx(&l.lo),
        hi: load_idx(&l.hi),
        d: _mm512_loadu_pd(l.d.as_ptr()),
        live: !mask(&l.flat),
        span: l.span,
    };
    let (best, arg, found) = scan_exact(costs, p, &g);
    let mut s = Scan { best: [0.0; LANES], arg: [0; LANES], found: [false; LANES] };
    _mm512_storeu_pd(s.best.as_mut_ptr(), best);
    _mm512_storeu_si512(s.arg.as_mut_ptr().cast(), arg);
    s.found = std::array::from_fn(|j| found >> j & 1 == 1);
    s
}

/// `portable::refine_lanes` on registers: the parabola refinement of the lanes' scan results.
///
/// # Safety
/// See the module documentation; `l.off[j] + k < costs.len()` for every `k < K`.
#[inline(always)]
pub(super) unsafe fn refine_lanes(costs: &[f32], p: &SearchParams, l: &Lanes, s: &Scan) -> [f64; LANES] {
    let unseen = splat(UNSEEN as f64);
    let off = load_idx(&l.off);
    let d = _mm512_loadu_pd(l.d.as_ptr());
    let live = !mask(&l.flat);
    let best = _mm512_loadu_pd(s.best.as_ptr());
    let arg = load_idx(&s.arg);
    let found = mask(&s.found);
    // The parabola through k - 1, k, k + 1 (`costvolume::parabola_offset`).
    let one = _mm512_set1_epi64(1);
    let inner = _mm512_cmpgt_epi64_mask(arg, _mm512_setzero_si512())
        & _mm512_cmplt_epi64_mask(_mm512_add_epi64(arg, one), _mm512_set1_epi64(p.k as i64));
    let km = _mm512_mask_blend_epi64(inner, arg, _mm512_sub_epi64(arg, one));
    let kp = _mm512_mask_blend_epi64(inner, arg, _mm512_add_epi64(arg, one));
    let (cm, cp) = (gather(costs, _mm512_add_epi64(off, km)), gather(costs, _mm512_add_epi64(off, kp)));
    let em = energy(d, rho(km, p), cm, p);
    let ep = energy(d, rho(kp, p), cp, p);
    let refine =
        inner & _mm512_cmp_pd_mask::<_CMP_LT_OQ>(cm, unseen) & _mm512_cmp_pd_mask::<_CMP_LT_OQ>(cp, unseen);
    let curvature = _mm512_add_pd(_mm512_sub_pd(em, _mm512_mul_pd(splat(2.0), best)), ep);
    let convex = _mm512_cmp_pd_mask::<_CMP_GT_OQ>(curvature, splat(0.0));
    let vertex = _mm512_div_pd(_mm512_sub_pd(em, ep), _mm512_mul_pd(splat(2.0), curvature));
    let vertex = clamp(vertex, -MAX_PARABOLA_OFFSET, MAX_PARABOLA_OFFSET);
    let delta = _mm512_mask_blend_pd(refine & convex, splat(0.0), vertex);
    let on_bin = _mm512_cmp_pd_mask::<_CMP_EQ_OQ>(delta, splat(0.0));
    let between =
        _mm512_add_pd(splat(p.rho_min), _mm512_mul_pd(_mm512_add_pd(to_f64(arg), delta), splat(p.step)));
    let refined = _mm512_mask_blend_pd(on_bin, between, rho(arg, p));
    let a = _mm512_mask_blend_pd(live & found, d, refined);
    let mut out = [0.0; LANES];
    _mm512_storeu_pd(out.as_mut_ptr(), a);
    out
}

/// `portable::terms_lanes` on registers: per lane `a as f32`, the coupling term, the data term and
/// whether it counts (both interpolated cells seen).
///
/// # Safety
/// See the module documentation; `off[j] + k < costs.len()` for every `k < K`.
#[inline(always)]
pub(super) unsafe fn terms_lanes(
    costs: &[f32],
    p: &SearchParams,
    off: &[usize; LANES],
    d: &[f64; LANES],
    a: &[f64; LANES],
) -> ([f32; LANES], [f64; LANES], [f64; LANES], [bool; LANES]) {
    let unseen = splat(UNSEEN as f64);
    let off = load_idx(off);
    let a32 = _mm512_cvtpd_ps(_mm512_loadu_pd(a.as_ptr()));
    let af = _mm512_cvtps_pd(a32);
    let diff = _mm512_sub_pd(_mm512_loadu_pd(d.as_ptr()), af);
    let coupling = _mm512_div_pd(_mm512_mul_pd(diff, diff), splat(2.0 * p.theta));
    let b = clamp(_mm512_div_pd(_mm512_sub_pd(af, splat(p.rho_min)), splat(p.step)), 0.0, (p.k - 1) as f64);
    // `floor(b) as usize` (NaN → 0), then `.min(K - 2)`.
    let floor = _mm512_roundscale_pd::<{ _MM_FROUND_TO_NEG_INF | _MM_FROUND_NO_EXC }>(b);
    let k0 = _mm512_cvtepi32_epi64(_mm512_cvttpd_epi32(floor));
    let k0 = _mm512_mask_blend_epi64(_mm512_cmp_pd_mask::<_CMP_UNORD_Q>(b, b), k0, _mm512_setzero_si512());
    let k0 = _mm512_min_epi64(k0, _mm512_set1_epi64(p.k.saturating_sub(2) as i64));
    let t = _mm512_sub_pd(b, to_f64(k0));
    let k1 = _mm512_min_epi64(_mm512_add_epi64(k0, _mm512_set1_epi64(1)), _mm512_set1_epi64(p.k as i64 - 1));
    let c0 = gather(costs, _mm512_add_epi64(off, k0));
    let c1 = gather(costs, _mm512_add_epi64(off, k1));
    let seen = _mm512_cmp_pd_mask::<_CMP_LT_OQ>(c0, unseen) & _mm512_cmp_pd_mask::<_CMP_LT_OQ>(c1, unseen);
    let data = _mm512_div_pd(
        _mm512_add_pd(_mm512_mul_pd(_mm512_sub_pd(splat(1.0), t), c0), _mm512_mul_pd(t, c1)),
        splat(p.lambda),
    );
    let (mut a_out, mut c_out, mut d_out) = ([0.0f32; LANES], [0.0; LANES], [0.0; LANES]);
    _mm256_storeu_ps(a_out.as_mut_ptr(), a32);
    _mm512_storeu_pd(c_out.as_mut_ptr(), coupling);
    _mm512_storeu_pd(d_out.as_mut_ptr(), data);
    (a_out, c_out, d_out, std::array::from_fn(|j| seen >> j & 1 == 1))
}

// The bounded search (`bounds::bounded_search` on registers).

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

/// `bounds::bounded_search` on registers: the same bounds, energies and choices (SPEC.md §10.1),
/// eight blocks' bounds or one block's eight energies per register; the least `(E, k)` is found by a
/// minimum and the first lane equal to it, so the result is the same bits; where the scalar code
/// would fall back to the plain scan (a NaN, `d` not finite), this calls it.
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
    if n > MAX_BLOCKS || !applies(d, p) {
        return bounded_search_portable(curve, minima, p, d, lo, hi);
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
            return bounded_search_portable(curve, minima, p, d, lo, hi);
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
        return bounded_search_portable(curve, minima, p, d, lo, hi);
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
                return bounded_search_portable(curve, minima, p, d, lo, hi);
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

/// `portable::least_block` on one register: the first lane equal to the least
/// minimum.
///
/// # Safety
/// Inlined into AVX-512F code only; `minima.len() <= 16`.
#[inline(always)]
pub(super) unsafe fn least_block(minima: &[f32]) -> usize {
    let m = ((1u32 << minima.len()) - 1) as u16;
    let v = _mm512_mask_loadu_ps(_mm512_set1_ps(f32::INFINITY), m, minima.as_ptr());
    let least = _mm512_reduce_min_ps(v);
    let at = _mm512_cmp_ps_mask::<_CMP_EQ_OQ>(v, _mm512_set1_ps(least));
    (at.trailing_zeros() as usize).min(minima.len() - 1)
}
