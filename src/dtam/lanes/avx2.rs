//! AVX2 build of the lane scan of the a-search: the same IEEE operations as the portable code
//! (`portable.rs`), lane for lane and in the same order, on two `__m256d` registers (lanes 0-3 and
//! 4-7), with the costs gathered from the pixels' curves. No fused multiply-adds, and every
//! comparison keeps Rust's NaN semantics, hence the same bits (tested against the portable build
//! and the scalar definition in tests/dtam.rs). The refinement, the energy terms and the bounded
//! search keep the portable code, compiled for AVX2 by the caller.
//!
//! Every function here is `unsafe`: it must be inlined into a function built with AVX2 that runs
//! only where the CPU reported it, and its offsets must lie in the cost slice.

use std::arch::x86_64::*;

use super::{Lanes, Scan, SearchParams, LANES, UNSEEN};

/// Lanes per register.
const HALF: usize = LANES / 2;

/// `v` in every lane.
#[inline(always)]
unsafe fn splat(v: f64) -> __m256d {
    _mm256_set1_pd(v)
}

/// Four `usize` (lanes `h*4..h*4 + 4`) as `i64` lanes.
#[inline(always)]
unsafe fn load_idx(v: &[usize; LANES], h: usize) -> __m256i {
    _mm256_loadu_si256(v.as_ptr().add(h * HALF).cast())
}

/// The lanes that are not flat, as an all-ones / all-zeros lane mask.
#[inline(always)]
unsafe fn live(flat: &[bool; LANES], h: usize) -> __m256i {
    let m = |j: usize| -i64::from(!flat[h * HALF + j]);
    _mm256_setr_epi64x(m(0), m(1), m(2), m(3))
}

/// `costs[i]` per lane, as `f64` (four scalar loads, as the AVX-512 build).
#[inline(always)]
unsafe fn gather(costs: &[f32], i: __m256i) -> __m256d {
    let mut idx = [0usize; HALF];
    _mm256_storeu_si256(idx.as_mut_ptr().cast(), i);
    let c = costs.as_ptr();
    let at = |j: usize| *c.add(idx[j]);
    _mm256_cvtps_pd(_mm_setr_ps(at(0), at(1), at(2), at(3)))
}

/// `i` (non-negative, below 2^52) as `f64`, exactly: its bits under the exponent of 2^52, minus
/// 2^52.
#[inline(always)]
unsafe fn to_f64(i: __m256i) -> __m256d {
    let magic = _mm256_set1_epi64x(0x4330_0000_0000_0000);
    _mm256_sub_pd(_mm256_castsi256_pd(_mm256_or_si256(i, magic)), splat(4_503_599_627_370_496.0))
}

/// `ρ_k` by [`crate::geometry::InverseDepthBins::rho`]'s formula.
#[inline(always)]
unsafe fn rho(k: __m256i, p: &SearchParams) -> __m256d {
    let v = _mm256_add_pd(splat(p.rho_min), _mm256_mul_pd(to_f64(k), splat(p.step)));
    let last = _mm256_cmpeq_epi64(k, _mm256_set1_epi64x(p.k as i64 - 1));
    _mm256_blendv_pd(v, splat(p.rho_max), _mm256_castsi256_pd(last))
}

/// `search::energy`: `(d - ρ)² · 1/(2θ) + c · 1/λ`.
#[inline(always)]
unsafe fn energy(d: __m256d, rho: __m256d, c: __m256d, p: &SearchParams) -> __m256d {
    let diff = _mm256_sub_pd(d, rho);
    _mm256_add_pd(
        _mm256_mul_pd(_mm256_mul_pd(diff, diff), splat(p.inv_two_theta)),
        _mm256_mul_pd(c, splat(p.inv_lambda)),
    )
}

/// The registers of one half of a group's scan and its running result.
struct Half {
    off: __m256i,
    lo: __m256i,
    hi: __m256i,
    d: __m256d,
    live: __m256i,
    best: __m256d,
    arg: __m256i,
    found: __m256i,
}

impl Half {
    #[inline(always)]
    unsafe fn new(l: &Lanes, h: usize) -> Self {
        Half {
            off: load_idx(&l.off, h),
            lo: load_idx(&l.lo, h),
            hi: load_idx(&l.hi, h),
            d: _mm256_loadu_pd(l.d.as_ptr().add(h * HALF)),
            live: live(&l.flat, h),
            best: splat(f64::INFINITY),
            arg: _mm256_setzero_si256(),
            found: _mm256_setzero_si256(),
        }
    }

    /// Step `t`: the hypotheses `lo + t` (clamped to `lo` past `hi`) where in range; the first
    /// scanned cell is taken, then any with a strictly lower energy (`e < best` is false for NaN).
    #[inline(always)]
    unsafe fn step(&mut self, costs: &[f32], p: &SearchParams, t: usize) {
        let k = _mm256_add_epi64(self.lo, _mm256_set1_epi64x(t as i64));
        let active = _mm256_andnot_si256(_mm256_cmpgt_epi64(k, self.hi), self.live);
        let k = _mm256_blendv_epi8(self.lo, k, active);
        let c = gather(costs, _mm256_add_epi64(self.off, k));
        let e = energy(self.d, rho(k, p), c, p);
        let lower = _mm256_castpd_si256(_mm256_cmp_pd::<_CMP_LT_OQ>(e, self.best));
        // `!(c >= UNSEEN)`: the cells the scan considers (NaN included).
        let scanned = _mm256_castpd_si256(_mm256_cmp_pd::<_CMP_NGE_UQ>(c, splat(UNSEEN as f64)));
        let first_or_lower = _mm256_or_si256(_mm256_xor_si256(self.found, _mm256_set1_epi64x(-1)), lower);
        let take = _mm256_and_si256(_mm256_and_si256(active, scanned), first_or_lower);
        self.best = _mm256_blendv_pd(self.best, e, _mm256_castsi256_pd(take));
        self.arg = _mm256_blendv_epi8(self.arg, k, take);
        self.found = _mm256_or_si256(self.found, take);
    }

    #[inline(always)]
    unsafe fn store(&self, s: &mut Scan, h: usize) {
        _mm256_storeu_pd(s.best.as_mut_ptr().add(h * HALF), self.best);
        _mm256_storeu_si256(s.arg.as_mut_ptr().add(h * HALF).cast(), self.arg);
        let mut found = [0i64; HALF];
        _mm256_storeu_si256(found.as_mut_ptr().cast(), self.found);
        for (out, f) in s.found[h * HALF..][..HALF].iter_mut().zip(found) {
            *out = f != 0;
        }
    }
}

/// `portable::scan_lanes` on registers: each live lane's scan over its `lo..=hi`, both halves
/// stepping together for the group's `span` steps.
///
/// # Safety
/// See the module documentation; `l.off[j] + k < costs.len()` for every `k < K`.
#[inline(always)]
pub(super) unsafe fn scan_lanes(costs: &[f32], p: &SearchParams, l: &Lanes) -> Scan {
    let (mut a, mut b) = (Half::new(l, 0), Half::new(l, 1));
    for t in 0..l.span {
        a.step(costs, p, t);
        b.step(costs, p, t);
    }
    let mut s = Scan { best: [0.0; LANES], arg: [0; LANES], found: [false; LANES] };
    a.store(&mut s, 0);
    b.store(&mut s, 1);
    s
}
