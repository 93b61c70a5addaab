//! The second half of a DTAM iteration in one pass over the cost volume: the a-search
//! ([`super::search`]) of each group of 8 pixels, immediately followed by their coupling and data
//! terms of `E_θ(d, a)` while their cost curves are still in cache (computed lane-wise, in the
//! AVX-512 build with the cells gathered), then per row the rms-gap and regulariser terms (rows of
//! `d`, `a` and `g` still in cache).
//!
//! Every term is the reference's per-pixel expression ([`super::total_energy`],
//! [`super::rms_gap`], [`HuberTv::regulariser_energy`]) and is summed in the reference's order:
//! per row in `f64`, `x` ascending, then over rows in order. Hence the energy and the gap are the
//! references' bits, for any thread count and either build (`fused_pass_equals_the_reference_functions`
//! in tests/dtam.rs). This replaces three passes of the unfused iteration, the second of which
//! re-read one cost-curve cache line per pixel from memory.

use ndarray::{Array2, ArrayView3};
use rayon::prelude::*;

use super::huber_tv::{regulariser_row, slope_regulariser_row};
use super::lanes::{self, LANES};
use super::search::{for_each_group, GroupSink, SearchParams, SearchRow};
use super::HuberTv;
use crate::dtam::search::{exhaustive_search_reference, CostRange};
use crate::geometry::InverseDepthBins;
use crate::runtime::CpuFeatureLevel;

/// What [`search_with_energy`] measures after writing `a`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct IterationMeasures {
    /// `E_θ(d, a)`: the bits of [`super::total_energy`].
    pub energy: f64,
    /// Root mean square of `d - a`: the bits of [`super::rms_gap`].
    pub gap: f64,
}

/// Per-row sums.
struct RowSums {
    regulariser: f64,
    coupling: f64,
    data: f64,
    gap: f64,
}

/// One row's inputs.
struct Row<'a> {
    costs: &'a [f32],
    range: &'a [(f32, f32)],
    minima: &'a [f32],
    d: &'a [f32],
    below: Option<&'a [f32]>,
    g: &'a [f32],
    /// The normal prior's slope rows (`q_x`, `q_y`), if it is on.
    slope: Option<(&'a [f32], &'a [f32])>,
    /// TGV²'s rows and `β`, if it is on.
    tgv: Option<(super::tgv::Rows<'a>, f64)>,
    eps: f64,
}

/// For the current `d = tv.primal()`: write the a-search's result into `a` (the bits of
/// [`super::exhaustive_search`]) and return `E_θ(d, a)` and the rms gap, with the AVX-512 build of
/// the row loop where `level` allows it.
///
/// # Panics
/// If `a`, `d` or `range` do not match the volume's `[H, W]`, or `costs` has fewer hypotheses than
/// `bins` (callers validate shapes).
#[allow(clippy::too_many_arguments)]
pub fn search_with_energy(
    costs: ArrayView3<f32>,
    range: &CostRange,
    bins: &InverseDepthBins,
    tv: &HuberTv,
    theta: f64,
    lambda: f64,
    a: &mut Array2<f32>,
    level: CpuFeatureLevel,
) -> IterationMeasures {
    let (h, w, k) = costs.dim();
    assert_eq!(tv.primal().dim(), (h, w), "d must match the cost volume");
    assert_eq!(a.dim(), (h, w), "a must match the cost volume");
    assert_eq!(k, bins.count, "one cost per hypothesis");
    if h * w == 0 {
        *a = exhaustive_search_reference(costs, range, bins, tv.primal(), theta, lambda);
        return IterationMeasures {
            energy: super::total_energy(tv, costs, bins, a.view(), theta, lambda),
            gap: super::rms_gap(tv.primal(), a.view()),
        };
    }
    let costs = costs.as_standard_layout();
    let costs = costs.as_slice().expect("standard layout is contiguous");
    let d = tv.primal().to_slice().expect("owned arrays are contiguous");
    let g = tv.weights().to_slice().expect("owned arrays are contiguous");
    let ranges = range.as_slice();
    assert_eq!(ranges.len(), h * w, "the cost range must match the cost volume");
    let p = SearchParams::new(bins, theta, lambda);
    let minima = range.minima();
    let eps = tv.epsilon();
    let out = a.as_slice_mut().expect("owned arrays are contiguous");
    let rows: Vec<RowSums> = out
        .par_chunks_mut(w)
        .enumerate()
        .map(|(y, a_row)| {
            let row = Row {
                costs: &costs[y * w * k..][..w * k],
                range: &ranges[y * w..][..w],
                minima: &minima[y * w * p.blocks..][..w * p.blocks],
                d: &d[y * w..][..w],
                below: (y + 1 < h).then(|| &d[(y + 1) * w..][..w]),
                g: &g[y * w..][..w],
                slope: tv.slope_rows(y),
                tgv: tv.tgv_rows(y),
                eps,
            };
            fused_row(&row, &p, a_row, level)
        })
        .collect();
    // The reference's sums over rows: `Iterator::sum` for the regulariser and the gap, `+=` from
    // 0.0 for the coupling and data terms, then `regulariser + coupling + data`.
    let regulariser: f64 = rows.iter().map(|r| r.regulariser).collect::<Vec<f64>>().iter().sum();
    let (mut coupling, mut data) = (0.0, 0.0);
    for r in &rows {
        coupling += r.coupling;
        data += r.data;
    }
    let gaps: Vec<f64> = rows.iter().map(|r| r.gap).collect();
    IterationMeasures {
        energy: regulariser + coupling + data,
        gap: (gaps.iter().sum::<f64>() / (h * w).max(1) as f64).sqrt(),
    }
}

fn fused_row(row: &Row, p: &SearchParams, a: &mut [f32], level: CpuFeatureLevel) -> RowSums {
    #[cfg(target_arch = "x86_64")]
    if level.avx512f() {
        // SAFETY: `avx512f()` reported AVX-512F on this CPU.
        return unsafe { fused_row_avx512(row, p, a) };
    }
    #[cfg(target_arch = "x86_64")]
    if level.avx2_fma() {
        // SAFETY: `avx2_fma()` reported AVX2 and FMA on this CPU.
        return unsafe { fused_row_avx2(row, p, a) };
    }
    fused_row_any::<{ lanes::PORTABLE }>(row, p, a)
}

/// The fused row compiled for AVX2 and FMA: the AVX2 lane scan, the rest portable (no fused
/// multiply-add is formed: the same bits).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn fused_row_avx2(row: &Row, p: &SearchParams, a: &mut [f32]) -> RowSums {
    fused_row_any::<{ lanes::AVX2 }>(row, p, a)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
unsafe fn fused_row_avx512(row: &Row, p: &SearchParams, a: &mut [f32]) -> RowSums {
    fused_row_any::<{ lanes::AVX512 }>(row, p, a)
}

#[inline(always)]
fn fused_row_any<const ISA: u8>(row: &Row, p: &SearchParams, a: &mut [f32]) -> RowSums {
    let w = a.len();
    let d = &row.d[..w];
    let search = SearchRow { costs: row.costs, range: row.range, minima: row.minima, d };
    let mut sink = Terms::<ISA> { a, d, costs: &row.costs[..w * p.k], p, coupling: 0.0, data: 0.0 };
    for_each_group::<ISA>(&search, p, &mut sink);
    let Terms { a, coupling, data, .. } = sink;
    // `rms_gap`'s row sum.
    let gap = d.iter().zip(a.iter()).map(|(&d, &a)| (f64::from(d) - f64::from(a)).powi(2)).sum();
    let regulariser = match (row.slope, row.tgv) {
        (_, Some((rows, beta))) => super::tgv::regulariser_row(rows, beta, row.eps),
        (Some((sx, sy)), None) => slope_regulariser_row(d, row.below, row.g, sx, sy, row.eps),
        (None, None) => regulariser_row(d, row.below, row.g, row.eps),
    };
    RowSums { regulariser, coupling, data, gap }
}

/// Writes `a` and adds `total_energy`'s per-pixel coupling and data terms while the group's curves
/// are in cache: the terms are computed lane-wise ([`lanes::terms`]), then
/// added one pixel at a time, `x` ascending.
struct Terms<'a, const ISA: u8> {
    a: &'a mut [f32],
    d: &'a [f32],
    costs: &'a [f32],
    p: &'a SearchParams<'a>,
    coupling: f64,
    data: f64,
}

impl<const ISA: u8> GroupSink for Terms<'_, ISA> {
    #[inline(always)]
    fn group(&mut self, x0: usize, n: usize, a: &[f64; LANES]) {
        let (k, w) = (self.p.k, self.d.len());
        // Lanes past the row's end repeat its last pixel (computed, never added).
        let x = |j: usize| (x0 + j).min(w - 1);
        let off: [usize; LANES] = std::array::from_fn(|j| x(j) * k);
        let d: [f64; LANES] = std::array::from_fn(|j| self.d[x(j)] as f64);
        let (a32, coupling, data, seen) = lanes::terms::<ISA>(self.costs, self.p, &off, &d, a);
        for j in 0..n {
            self.a[x0 + j] = a32[j];
            self.coupling += coupling[j];
            if seen[j] {
                self.data += data[j];
            }
        }
    }
}
