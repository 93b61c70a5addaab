//! The point-wise exhaustive search for the auxiliary variable of DTAM:
//!
//! ```text
//! a(u) = argmin_k  1/(2θ) (d(u) - ρ_k)² + 1/λ · C(u, ρ_k)      over hypotheses seen by a frame
//! ```
//!
//! then refined inside the bin by the vertex of the parabola through the energies at `k*-1, k*,
//! k*+1` (clamped to ±½ bin, none at the ends or next to an unseen cell: SPEC.md §9.5's formula).
//!
//! **Pruning (exact).** Let `C_min, C_max` be the pixel's extreme seen costs and `k_n` the seen
//! hypothesis nearest to `d`. Then `E(k_n) <= (d - ρ_{k_n})²/(2θ) + C_max/λ`, while any `k` with
//! `(d - ρ_k)² > r² = 2θ (C_max - C_min)/λ + (d - ρ_{k_n})²` has `E(k) > E(k_n)`. So only
//! `|ρ_k - d| <= r` is searched — the same hypotheses in the same order as a full search, hence the
//! same argmin bit for bit (`pruned_search_equals_full_search`). As `θ` falls, `r` shrinks.
//!
//! **Implementation.** [`exhaustive_search`] (and the fused pass, `dtam::search_with_energy`)
//! search a row in groups of 8 consecutive pixels (`LANES`), one per SIMD lane. The pruned ranges
//! of the next 16 pixels are computed ahead (a loop across pixels that vectorises) and the cache
//! lines of the cost curves they will read are prefetched: the curves lie `K` floats apart and which
//! of their lines a search reads depends on `d`, so the hardware prefetcher cannot follow. Each lane
//! then runs the scalar definition's scan over its own range (the first seen hypothesis, then any
//! with a strictly lower energy), the lanes stepping together for the longest range (a lane past
//! its end idles, masked) with the costs gathered from the 8 curves; then the parabola refinement,
//! lane-wise. Every value is the scalar definition's sequence of IEEE operations (no fused
//! multiply-adds, no reordered reductions; `ρ_k` by [`InverseDepthBins::rho`]'s own formula or a
//! table of its values), so the result is the definition's bit for bit, ties, infinities and NaNs
//! included. Two builds: portable and AVX-512 (`dtam::lanes`,
//! intrinsics, run-time dispatch by the [`CpuFeatureLevel`] passed in); tests/dtam.rs checks both against the scalar
//! definition ([`exhaustive_search_full`]) and the original one-pixel-at-a-time implementation
//! ([`exhaustive_search_reference`]).

use ndarray::{Array1, Array2, ArrayView2, ArrayView3};
use rayon::prelude::*;

use super::bounds;
use super::lanes::{self, Lanes, Scan, LANES};
use crate::costvolume::{parabola_offset, UNSEEN_COST};
use crate::geometry::InverseDepthBins;
use crate::runtime::CpuFeatureLevel;
use crate::util::alloc::zeroed_aligned;

/// Cells at or above this are unseen (`crate::costvolume::UNSEEN_COST`).
pub const UNSEEN: f32 = UNSEEN_COST;

/// Per-pixel extreme seen costs and per-block least costs (SPEC.md §10.1, "Block bounds"), computed once
/// per cost volume.
#[derive(Clone, Debug)]
pub struct CostRange {
    /// `(C_min, C_max)` per pixel; `(∞, -∞)` where nothing was seen.
    range: Array2<(f32, f32)>,
    /// `[H, W, ⌈K/8⌉]`: each block's least seen cost (SPEC.md §10.1), starting a cache line (one
    /// line per pixel at K = 128).
    minima: Array1<f32>,
}

impl CostRange {
    /// Scan the volume once (row-parallel; each pixel's folds are the sequential ones over `k`).
    pub fn new(costs: ArrayView3<f32>) -> Self {
        let (h, w, k) = costs.dim();
        let fold = |curve: &[f32]| {
            curve
                .iter()
                .filter(|&&c| c < UNSEEN)
                .fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), &c| (lo.min(c), hi.max(c)))
        };
        if h * w * k == 0 {
            let empty = (f32::INFINITY, f32::NEG_INFINITY);
            return Self { range: Array2::from_elem((h, w), empty), minima: Array1::zeros(0) };
        }
        let costs = costs.as_standard_layout();
        let flat = costs.as_slice().expect("standard layout is contiguous");
        let g = bounds::block_count(k);
        let mut range = vec![(0.0f32, 0.0f32); h * w];
        let mut minima = zeroed_aligned::<f32>(h * w * g);
        let slice = minima.as_slice_mut().expect("owned one-dimensional arrays are contiguous");
        // One pass: each curve's extremes and block minima while it is in cache.
        range.par_chunks_mut(w).zip(slice.par_chunks_mut(w * g)).zip(flat.par_chunks(w * k)).for_each(
            |((range, minima), row)| {
                for ((range, minima), curve) in range.iter_mut().zip(minima.chunks_mut(g)).zip(row.chunks(k))
                {
                    *range = fold(curve);
                    bounds::block_minima(curve, minima);
                }
            },
        );
        Self { range: Array2::from_shape_vec((h, w), range).expect("one range per pixel"), minima }
    }

    /// `(C_min, C_max)` per pixel, row-major.
    pub(crate) fn as_slice(&self) -> &[(f32, f32)] {
        self.range.as_slice().expect("owned arrays are contiguous")
    }

    /// The block minima `[H, W, ⌈K/8⌉]`, row-major.
    pub(crate) fn minima(&self) -> &[f32] {
        self.minima.as_slice().expect("owned one-dimensional arrays are contiguous")
    }
}

/// Energy of hypothesis `k` for a pixel: `(d - ρ)² · 1/(2θ) + c · 1/λ`, each reciprocal one
/// rounded `f64` division (the compiler hoists them out of the loops over hypotheses).
#[inline(always)]
pub(crate) fn energy(d: f64, rho: f64, cost: f32, theta: f64, lambda: f64) -> f64 {
    energy_scaled(d, rho, cost, 1.0 / (2.0 * theta), 1.0 / lambda)
}

/// [`energy`] with its two reciprocals given.
#[inline(always)]
pub(crate) fn energy_scaled(d: f64, rho: f64, cost: f32, inv_two_theta: f64, inv_lambda: f64) -> f64 {
    let diff = d - rho;
    diff * diff * inv_two_theta + cost as f64 * inv_lambda
}

/// Search one pixel over hypotheses `lo..=hi`; `None` if none of them was seen. The scalar
/// definition: the first strict minimum of [`energy`] over the seen hypotheses.
fn search_range(
    curve: &[f32],
    bins: &InverseDepthBins,
    d: f64,
    theta: f64,
    lambda: f64,
    lo: usize,
    hi: usize,
) -> Option<f64> {
    let mut best: Option<(usize, f64)> = None;
    for (k, &c) in curve.iter().enumerate().take(hi + 1).skip(lo) {
        if c >= UNSEEN {
            continue;
        }
        let e = energy(d, bins.rho(k), c, theta, lambda);
        if best.is_none_or(|(_, be)| e < be) {
            best = Some((k, e));
        }
    }
    let (k, e0) = best?;
    let n = curve.len();
    let delta = if k > 0 && k + 1 < n && curve[k - 1] < UNSEEN && curve[k + 1] < UNSEEN {
        let em = energy(d, bins.rho(k - 1), curve[k - 1], theta, lambda);
        let ep = energy(d, bins.rho(k + 1), curve[k + 1], theta, lambda);
        parabola_offset(em, e0, ep)
    } else {
        0.0
    };
    Some(if delta == 0.0 { bins.rho(k) } else { bins.rho_min + (k as f64 + delta) * bins.step() })
}

/// One pixel: pruned search, falling back to the full search when the pruning bound does not apply.
/// The scalar definition of [`search_pixel_fast`].
fn search_pixel(
    curve: &[f32],
    range: (f32, f32),
    bins: &InverseDepthBins,
    d: f64,
    theta: f64,
    lambda: f64,
) -> f64 {
    let n = curve.len();
    let (c_min, c_max) = range;
    if c_min > c_max {
        return d; // nothing seen: the data term is flat, the coupling pulls a onto d
    }
    let nearest = bins.bin_of(d).round().clamp(0.0, (n - 1) as f64) as usize;
    if curve[nearest] < UNSEEN {
        let dn = d - bins.rho(nearest);
        let r = (2.0 * theta * (c_max - c_min) as f64 / lambda + dn * dn).sqrt();
        let lo = bins.bin_of(d - r).floor().clamp(0.0, (n - 1) as f64) as usize;
        let hi = bins.bin_of(d + r).ceil().clamp(0.0, (n - 1) as f64) as usize;
        if let Some(a) = search_range(curve, bins, d, theta, lambda, lo.min(nearest), hi.max(nearest)) {
            return a;
        }
    }
    search_range(curve, bins, d, theta, lambda, 0, n - 1).unwrap_or(d)
}

/// The auxiliary map `a` for the current `d` (`[H, W]`), row-parallel, with the AVX-512 build of the
/// row loop where the CPU has it.
///
/// # Panics
/// If `d` does not match the volume's `[H, W]` (callers validate shapes).
pub fn exhaustive_search(
    costs: ArrayView3<f32>,
    range: &CostRange,
    bins: &InverseDepthBins,
    d: ArrayView2<f32>,
    theta: f64,
    lambda: f64,
) -> Array2<f32> {
    exhaustive_search_with(costs, range, bins, d, theta, lambda, CpuFeatureLevel::get())
}

/// [`exhaustive_search`] with an explicit choice of kernel build (the same bits for every build).
///
/// # Panics
/// If `d` does not match the volume's `[H, W]`.
pub fn exhaustive_search_with(
    costs: ArrayView3<f32>,
    range: &CostRange,
    bins: &InverseDepthBins,
    d: ArrayView2<f32>,
    theta: f64,
    lambda: f64,
    level: CpuFeatureLevel,
) -> Array2<f32> {
    let (h, w, k) = costs.dim();
    assert_eq!(d.dim(), (h, w), "d must match the cost volume");
    assert_eq!(range.range.dim(), (h, w), "the cost range must match the cost volume");
    let mut a = Array2::<f32>::zeros((h, w));
    if h * w == 0 {
        return a;
    }
    let costs = costs.as_standard_layout();
    let costs = costs.as_slice().expect("standard layout is contiguous");
    let d = d.as_standard_layout();
    let d = d.as_slice().expect("standard layout is contiguous");
    let p = SearchParams::new(bins, theta, lambda);
    let ranges = range.as_slice();
    let (minima, g) = (range.minima(), p.blocks);
    let out = a.as_slice_mut().expect("owned arrays are contiguous");
    out.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        let rows = SearchRow {
            costs: &costs[y * w * k..][..w * k],
            range: &ranges[y * w..][..w],
            minima: &minima[y * w * g..][..w * g],
            d: &d[y * w..][..w],
        };
        search_row(&rows, &p, row, level);
    });
    a
}

/// Constants of one search (`θ`, `λ` fixed), each the scalar definition's subexpression evaluated
/// once, and the hypotheses as a table.
pub(crate) struct SearchParams<'a> {
    /// The bins, for the scalar fallback.
    pub bins: &'a InverseDepthBins,
    /// `ρ_k = bins.rho(k)` for every `k`.
    pub rho: Vec<f64>,
    /// Per block of [`bounds::BLOCK_BINS`] hypotheses, its least `ρ_k`.
    pub rho_block_lo: Vec<f64>,
    /// Per block, its greatest `ρ_k`.
    pub rho_block_hi: Vec<f64>,
    /// `⌈K/8⌉`, the blocks of a curve.
    pub blocks: usize,
    /// `K`.
    pub k: usize,
    /// `ρ_min`.
    pub rho_min: f64,
    /// `ρ_max`.
    pub rho_max: f64,
    /// `Δρ = bins.step()`.
    pub step: f64,
    /// `θ`.
    pub theta: f64,
    /// `2θ`.
    pub two_theta: f64,
    /// `λ`.
    pub lambda: f64,
    /// `1/(2θ)`.
    pub inv_two_theta: f64,
    /// `1/λ`.
    pub inv_lambda: f64,
}

impl<'a> SearchParams<'a> {
    pub fn new(bins: &'a InverseDepthBins, theta: f64, lambda: f64) -> Self {
        let rho = bins.values();
        let (rho_block_lo, rho_block_hi) = bounds::block_rho_extremes(&rho);
        Self {
            bins,
            rho_block_lo,
            rho_block_hi,
            blocks: bounds::block_count(bins.count),
            rho,
            k: bins.count,
            rho_min: bins.rho_min,
            rho_max: bins.rho_max,
            step: bins.step(),
            theta,
            two_theta: 2.0 * theta,
            lambda,
            inv_two_theta: 1.0 / (2.0 * theta),
            inv_lambda: 1.0 / lambda,
        }
    }
}

/// One row's inputs: its `W·K` costs, `W` cost ranges, `W·⌈K/8⌉` block minima and `W` values of
/// `d`.
pub(crate) struct SearchRow<'a> {
    pub costs: &'a [f32],
    pub range: &'a [(f32, f32)],
    pub minima: &'a [f32],
    pub d: &'a [f32],
}

fn search_row(rows: &SearchRow, p: &SearchParams, out: &mut [f32], level: CpuFeatureLevel) {
    #[cfg(target_arch = "x86_64")]
    if level.avx512f() {
        // SAFETY: `avx512f()` reported AVX-512F on this CPU.
        unsafe { search_row_avx512(rows, p, out) };
        return;
    }
    #[cfg(target_arch = "x86_64")]
    if level.avx2_fma() {
        // SAFETY: `avx2_fma()` reported AVX2 and FMA on this CPU.
        unsafe { search_row_avx2(rows, p, out) };
        return;
    }
    for_each_group::<{ lanes::PORTABLE }>(rows, p, &mut Output(out));
}

/// The search compiled for AVX2 and FMA: the AVX2 lane scan, the rest portable (no fused
/// multiply-add is formed: the same bits).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn search_row_avx2(rows: &SearchRow, p: &SearchParams, out: &mut [f32]) {
    for_each_group::<{ lanes::AVX2 }>(rows, p, &mut Output(out));
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
unsafe fn search_row_avx512(rows: &SearchRow, p: &SearchParams, out: &mut [f32]) {
    for_each_group::<{ lanes::AVX512 }>(rows, p, &mut Output(out));
}

/// Pixels per block of the row pipeline: a block's pixels are planned (and their cost-curve cache
/// lines prefetched) while the previous block is searched.
const BLOCK: usize = 2 * LANES;

/// What [`for_each_group`] does with each group's results. A trait rather than a closure: a
/// closure is a function of its own, compiled for the baseline target unless inlined, while an
/// `#[inline(always)]` trait method is inlined into the AVX-512 build of the row loop.
pub(crate) trait GroupSink {
    /// Pixels `x0..x0 + n` (`n <= LANES`) of the row have `a[..n]` (in `f64`, before rounding to
    /// `f32`); the other lanes hold junk.
    fn group(&mut self, x0: usize, n: usize, a: &[f64; LANES]);
}

/// Writes `a` as `f32`.
struct Output<'a>(&'a mut [f32]);

impl GroupSink for Output<'_> {
    #[inline(always)]
    fn group(&mut self, x0: usize, n: usize, a: &[f64; LANES]) {
        for (out, &a) in self.0[x0..x0 + n].iter_mut().zip(a) {
            *out = a as f32;
        }
    }
}

/// Run the a-search on every pixel of a row, in groups of [`LANES`] consecutive pixels, `x`
/// ascending, handing each group's results to `sink`. `ISA`: which lane kernels
/// (`lanes::PORTABLE`, `lanes::AVX2`, `lanes::AVX512`; the latter two only inside a function built
/// with that instruction set).
///
/// Software-pipelined: the search bounds of the next [`BLOCK`] pixels are computed (a loop across
/// pixels that vectorises), and the cache lines their searches will read requested, before the
/// current block is searched. The curves are `K` floats apart and each search reads a few lines at
/// a position that depends on `d`, which the hardware prefetcher cannot follow.
#[inline(always)]
pub(crate) fn for_each_group<const ISA: u8>(rows: &SearchRow, p: &SearchParams, sink: &mut impl GroupSink) {
    let w = rows.d.len();
    let mut plans = [Plans::default(); 2];
    plan_block::<ISA>(&mut plans[0], rows, p, 0);
    for (b, start) in (0..w).step_by(BLOCK).enumerate() {
        if start + BLOCK < w {
            plan_block::<ISA>(&mut plans[(b + 1) % 2], rows, p, start + BLOCK);
        }
        for g in (0..BLOCK).step_by(LANES) {
            let x0 = start + g;
            if x0 >= w {
                break;
            }
            let a = search_group::<ISA>(rows, p, &plans[b % 2], g, x0);
            sink.group(x0, LANES.min(w - x0), &a);
        }
    }
}

/// The parts of [`BLOCK`] pixels' searches that do not read their cost curves (exactly
/// [`search_pixel`]'s values): whether anything was seen, the hypothesis nearest `d` and the pruned
/// range `lo..=hi` (already widened to include `nearest`).
#[derive(Clone, Copy, Debug, Default)]
struct Plans {
    flat: [bool; BLOCK],
    nearest: [u32; BLOCK],
    lo: [u32; BLOCK],
    hi: [u32; BLOCK],
}

/// Plan pixels `start..start + BLOCK` (clipped to the row) and prefetch their curves' lines.
#[inline(always)]
fn plan_block<const ISA: u8>(plans: &mut Plans, rows: &SearchRow, p: &SearchParams, start: usize) {
    let end = (start + BLOCK).min(rows.d.len());
    let (range, d) = (&rows.range[start..end], &rows.d[start..end]);
    if end - start == BLOCK {
        // A fixed trip count: vectorised across pixels.
        for i in 0..BLOCK {
            (plans.flat[i], plans.nearest[i], plans.lo[i], plans.hi[i]) = plan(range[i], p, d[i] as f64);
        }
    } else {
        for i in 0..end - start {
            (plans.flat[i], plans.nearest[i], plans.lo[i], plans.hi[i]) = plan(range[i], p, d[i] as f64);
        }
    }
    #[cfg(target_arch = "x86_64")]
    for (i, x) in (start..end).enumerate() {
        use std::arch::x86_64::{_mm_prefetch, _MM_HINT_T0};
        // The cache lines the search will most likely read: for a narrow range the lines of `lo..=hi`
        // (at most four: the lane scan reads all of them), for a wide one the line of the block with
        // the least seen cost (where the bounded search starts, unless the coupling term moves it).
        // And the block minima of the pixel a block ahead, which this plan reads next time: read
        // pixel after pixel between the curves' scattered lines, the hardware prefetcher did not
        // keep up with them (SPEC.md §10.1).
        let curve = &rows.costs[x * p.k..][..p.k];
        let (lo, hi) = (plans.lo[i] as usize, plans.hi[i] as usize);
        if hi - lo >= NARROW {
            let at = lanes::least_block::<ISA>(&rows.minima[x * p.blocks..][..p.blocks]) * bounds::BLOCK_BINS;
            // SAFETY: a prefetch is a hint; it never faults, and `at < K` is inside the curve.
            unsafe { _mm_prefetch::<_MM_HINT_T0>(curve[at..].as_ptr().cast()) };
        } else {
            for at in (lo..=hi).step_by(LINE_FLOATS).chain(std::iter::once(hi)).take(4) {
                // SAFETY: as above; `lo <= at <= hi < K`.
                unsafe { _mm_prefetch::<_MM_HINT_T0>(curve[at..].as_ptr().cast()) };
            }
        }
        if x + BLOCK < rows.d.len() {
            let ahead = &rows.minima[(x + BLOCK) * p.blocks..][..p.blocks];
            for at in (0..p.blocks).step_by(LINE_FLOATS) {
                // SAFETY: as above; `at` is inside the pixel's minima.
                unsafe { _mm_prefetch::<_MM_HINT_T0>(ahead[at..].as_ptr().cast()) };
            }
        }
    }
}

/// `f32` values per 64-byte cache line.
const LINE_FLOATS: usize = 16;

/// One pixel's plan: [`search_pixel`]'s `c_min > c_max`, `nearest`, `lo.min(nearest)` and
/// `hi.max(nearest)`, with `ρ_nearest` evaluated by [`InverseDepthBins::rho`]'s formula (no table
/// lookup, so the loop over pixels vectorises). The indices are at most `K - 1`, so `u32` holds them
/// exactly (and `NaN` still maps to 0).
#[inline(always)]
fn plan(range: (f32, f32), p: &SearchParams, d: f64) -> (bool, u32, u32, u32) {
    let (c_min, c_max) = range;
    let last = (p.k - 1) as f64;
    let nearest = ((d - p.rho_min) / p.step).round().clamp(0.0, last) as u32;
    let rho_nearest =
        if nearest as usize + 1 == p.k { p.rho_max } else { p.rho_min + f64::from(nearest) * p.step };
    let dn = d - rho_nearest;
    let r = (p.two_theta * (c_max - c_min) as f64 / p.lambda + dn * dn).sqrt();
    let lo = ((d - r - p.rho_min) / p.step).floor().clamp(0.0, last) as u32;
    let hi = ((d + r - p.rho_min) / p.step).ceil().clamp(0.0, last) as u32;
    (c_min > c_max, nearest, lo.min(nearest), hi.max(nearest))
}

impl Lanes {
    #[inline(always)]
    fn new(rows: &SearchRow, p: &SearchParams, plans: &Plans, i0: usize, x0: usize) -> Self {
        let (k, w) = (p.k, rows.d.len());
        let costs = &rows.costs[..w * k];
        let mut l = Lanes {
            off: [0; LANES],
            d: [0.0; LANES],
            flat: [true; LANES],
            full: [false; LANES],
            lo: [0; LANES],
            hi: [0; LANES],
            span: 0,
        };
        for j in 0..LANES.min(w - x0) {
            let (x, i) = (x0 + j, i0 + j);
            l.off[j] = x * k;
            l.d[j] = rows.d[x] as f64;
            l.flat[j] = plans.flat[i];
            // The pruning applies only where the hypothesis nearest `d` was seen.
            // (`!(c < UNSEEN)`: NaN counts as unseen here, as in `search_pixel`.)
            let c = costs[x * k + plans.nearest[i] as usize];
            l.full[j] = c >= UNSEEN || c.is_nan();
            l.lo[j] = if l.full[j] { 0 } else { plans.lo[i] as usize };
            l.hi[j] = if l.full[j] { k - 1 } else { plans.hi[i] as usize };
            if !l.flat[j] {
                l.span = l.span.max(l.hi[j] - l.lo[j] + 1);
            }
        }
        l
    }
}

/// [`search_pixel`] for the [`LANES`] pixels `x0..` of a row (planned in `plans` from index `i0`):
/// the definition's argmin over each live lane's `lo..=hi`, by the lane scan ([`lanes::scan`]) when
/// the longest range is at most [`NARROW`], else by each lane's bounded search ([`bounded_group`]);
/// then the parabola refinement of all lanes at once ([`lanes::refine`]); lanes past the row's end hold junk.
#[inline(always)]
fn search_group<const ISA: u8>(
    rows: &SearchRow,
    p: &SearchParams,
    plans: &Plans,
    i0: usize,
    x0: usize,
) -> [f64; LANES] {
    let (k, w) = (p.k, rows.d.len());
    let costs = &rows.costs[..w * k];
    let lanes = Lanes::new(rows, p, plans, i0, x0);
    let scan = if lanes.span <= NARROW {
        lanes::scan::<ISA>(costs, p, &lanes)
    } else {
        bounded_group::<ISA>(rows, p, &lanes, x0)
    };
    let mut a = lanes::refine::<ISA>(costs, p, &lanes, &scan);
    for (j, a) in a.iter_mut().enumerate().take(LANES.min(w - x0)) {
        if !lanes.flat[j] && !lanes.full[j] && !scan.found[j] {
            // A pruned range with nothing seen in it cannot happen (it holds the seen nearest
            // hypothesis); should it, the scalar definition falls back to the full search.
            let x = x0 + j;
            *a = search_pixel(&costs[x * k..][..k], rows.range[x], p.bins, lanes.d[j], p.theta, p.lambda);
        }
    }
    a
}

/// The bounded search of each live lane of a group ([`lanes::bounded`]).
#[inline(always)]
fn bounded_group<const ISA: u8>(rows: &SearchRow, p: &SearchParams, lanes: &Lanes, x0: usize) -> Scan {
    let (k, w) = (p.k, rows.d.len());
    let mut scan = Scan { best: [f64::INFINITY; LANES], arg: [0; LANES], found: [false; LANES] };
    for j in 0..LANES.min(w - x0) {
        if lanes.flat[j] {
            continue;
        }
        let x = x0 + j;
        let (curve, minima) = (&rows.costs[x * k..][..k], &rows.minima[x * p.blocks..][..p.blocks]);
        let (d, lo, hi) = (lanes.d[j], lanes.lo[j], lanes.hi[j]);
        let found = lanes::bounded::<ISA>(curve, minima, p, d, lo, hi);
        if let Some((kk, e)) = found {
            (scan.best[j], scan.arg[j], scan.found[j]) = (e, kk, true);
        }
    }
    scan
}

/// Groups whose longest range is at most this many hypotheses run the lane scan ([`lanes::scan`]);
/// wider ones the bounded search of each lane ([`bounds`]). Both give the definition's argmin, so
/// this affects the speed only.
const NARROW: usize = 6 * bounds::BLOCK_BINS;

/// The original scalar implementation of [`exhaustive_search`] (ndarray indexing, one pixel at a
/// time through `search_pixel`): the reference the vectorised search is tested against
/// (`pruned_search_equals_full_search`, and through `dtam::solve_reference`).
///
/// # Panics
/// If `d` does not match the volume's `[H, W]`.
pub fn exhaustive_search_reference(
    costs: ArrayView3<f32>,
    range: &CostRange,
    bins: &InverseDepthBins,
    d: ArrayView2<f32>,
    theta: f64,
    lambda: f64,
) -> Array2<f32> {
    let (h, w, _) = costs.dim();
    assert_eq!(d.dim(), (h, w), "d must match the cost volume");
    let mut a = Array2::<f32>::zeros((h, w));
    let slice = a.as_slice_mut().expect("owned arrays are contiguous");
    slice.par_chunks_mut(w.max(1)).enumerate().for_each(|(y, row)| {
        for (x, out) in row.iter_mut().enumerate() {
            let curve = costs.slice(ndarray::s![y, x, ..]);
            let curve =
                curve.as_slice().map(std::borrow::Cow::Borrowed).unwrap_or_else(|| curve.to_vec().into());
            *out = search_pixel(&curve, range.range[[y, x]], bins, d[[y, x]] as f64, theta, lambda) as f32;
        }
    });
    a
}

/// The same search without pruning, for tests and as the definition.
///
/// # Panics
/// If `d` does not match the volume's `[H, W]`.
pub fn exhaustive_search_full(
    costs: ArrayView3<f32>,
    bins: &InverseDepthBins,
    d: ArrayView2<f32>,
    theta: f64,
    lambda: f64,
) -> Array2<f32> {
    let (h, w, k) = costs.dim();
    assert_eq!(d.dim(), (h, w), "d must match the cost volume");
    Array2::from_shape_fn((h, w), |(y, x)| {
        let curve = costs.slice(ndarray::s![y, x, ..]).to_vec();
        let dv = d[[y, x]] as f64;
        search_range(&curve, bins, dv, theta, lambda, 0, k - 1).unwrap_or(dv) as f32
    })
}
