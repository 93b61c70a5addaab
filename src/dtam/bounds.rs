//! Exact block bounds for the a-search (SPEC.md §10.1, "Block bounds").
//!
//! Each cost curve is cut into blocks of [`BLOCK_BINS`] consecutive hypotheses, and the least seen
//! cost of every block is stored once per cost volume ([`block_minima`], kept by
//! [`super::CostRange`]). Within block `j`, every hypothesis `k` has `C_k >= m_j` and `ρ_k` in
//! `[ρ_lo(j), ρ_hi(j)]` (the block's extreme `ρ` values), so
//!
//! ```text
//! E(k) = (d - ρ_k)² · 1/(2θ) + C_k · 1/λ  >=  B_j = (d - ρ*)² · 1/(2θ) + m_j · 1/λ
//! ```
//!
//! with `ρ* = ρ_lo(j)` if `d < ρ_lo(j)`, `ρ_hi(j)` if `d > ρ_hi(j)`, else `d` (difference 0). The
//! bound holds for the rounded values too: `d - ρ` rounds monotonically in `ρ`, and the square, the
//! products by the non-negative reciprocals and the sum round monotonically in their arguments.
//!
//! The search ([`bounded_search`]) scans the block with the least bound first, then every other
//! block in ascending order unless its bound shows that none of its cells can beat the best so far
//! in the order `(energy, k)`: `B_j > E_best`, or `B_j = E_best` and the block's first hypothesis
//! comes after `k_best`. The least `(E, k)` over the seen cells is the definition's first strict
//! minimum of the ascending scan, so the result is the definition's bit for bit. Where that
//! argument needs finite numbers (a NaN cost or energy, `d` not finite, a reciprocal not positive
//! and finite) the pixel falls back to the definition's plain scan ([`plain_scan`]).

use super::search::{energy_scaled, SearchParams, UNSEEN};

/// Hypotheses per block of the bound table.
pub(crate) const BLOCK_BINS: usize = 8;

/// Blocks per curve of `k` hypotheses (the last one may be partial).
pub(crate) fn block_count(k: usize) -> usize {
    k.div_ceil(BLOCK_BINS)
}

/// Per block of `curve`, into `out` (length [`block_count`]): the least seen (`< UNSEEN`) cost;
/// `UNSEEN` where the block has no seen cell; NaN where it holds a NaN.
pub(crate) fn block_minima(curve: &[f32], out: &mut [f32]) {
    for (m, block) in out.iter_mut().zip(curve.chunks(BLOCK_BINS)) {
        *m = block.iter().fold(UNSEEN, |m, &c| {
            if c.is_nan() || m.is_nan() {
                f32::NAN
            } else if c < m {
                c
            } else {
                m
            }
        });
    }
}

/// Per block, the least and the greatest of its `ρ_k` (`rho` is the table of every `ρ_k`).
pub(crate) fn block_rho_extremes(rho: &[f64]) -> (Vec<f64>, Vec<f64>) {
    let lo = rho.chunks(BLOCK_BINS).map(|b| b.iter().copied().fold(f64::INFINITY, f64::min)).collect();
    let hi = rho.chunks(BLOCK_BINS).map(|b| b.iter().copied().fold(f64::NEG_INFINITY, f64::max)).collect();
    (lo, hi)
}

/// `B_j` for a block with least seen cost `m` and `ρ` extremes `(lo, hi)`.
#[inline(always)]
fn bound(d: f64, (lo, hi): (f64, f64), m: f32, p: &SearchParams) -> f64 {
    let nearest = if d < lo {
        lo
    } else if d > hi {
        hi
    } else {
        d
    };
    energy_scaled(d, nearest, m, p.inv_two_theta, p.inv_lambda)
}

/// Whether the bounds apply for this `d` and these parameters.
#[inline(always)]
pub(crate) fn applies(d: f64, p: &SearchParams) -> bool {
    let positive = |v: f64| v > 0.0 && v.is_finite();
    d.is_finite() && positive(p.inv_two_theta) && positive(p.inv_lambda)
}

/// The least `(E(k), k)` over the seen cells of `lo..=hi` (`None`: none seen), with `E` the
/// definition's energy: the definition's first strict minimum. `curve` holds the `K` costs of the
/// pixel, `minima` its [`block_minima`].
#[inline(always)]
pub(crate) fn bounded_search(
    curve: &[f32],
    minima: &[f32],
    p: &SearchParams,
    d: f64,
    lo: usize,
    hi: usize,
) -> Option<(usize, f64)> {
    exact_or_none(curve, minima, p, d, lo, hi).unwrap_or_else(|| plain_scan(curve, p, d, lo, hi))
}

/// [`bounded_search`]'s bounded path; `None` where it does not apply (then the plain scan runs).
#[inline(always)]
fn exact_or_none(
    curve: &[f32],
    minima: &[f32],
    p: &SearchParams,
    d: f64,
    lo: usize,
    hi: usize,
) -> Option<Option<(usize, f64)>> {
    if !applies(d, p) {
        return None;
    }
    let (first, last) = (lo / BLOCK_BINS, hi / BLOCK_BINS);
    // The block with the least bound (the first of equal ones).
    let mut start: Option<(usize, f64)> = None;
    for (j, &m) in minima.iter().enumerate().take(last + 1).skip(first) {
        if m.is_nan() {
            return None;
        }
        if m < UNSEEN {
            let b = bound(d, (p.rho_block_lo[j], p.rho_block_hi[j]), m, p);
            if b.is_nan() {
                return None;
            }
            if start.is_none_or(|(_, least)| b < least) {
                start = Some((j, b));
            }
        }
    }
    let Some((start, _)) = start else {
        return Some(None);
    };
    let mut best = None;
    scan_block(curve, p, d, start, lo, hi, &mut best)?;
    for (j, &m) in minima.iter().enumerate().take(last + 1).skip(first) {
        let seen = m < UNSEEN;
        if j == start || !seen {
            continue;
        }
        if let Some((k_best, e_best)) = best {
            let b = bound(d, (p.rho_block_lo[j], p.rho_block_hi[j]), m, p);
            if b > e_best || (b == e_best && (j * BLOCK_BINS).max(lo) > k_best) {
                continue;
            }
        }
        scan_block(curve, p, d, j, lo, hi, &mut best)?;
    }
    Some(best)
}

/// Fold block `j`'s seen cells within `lo..=hi` into `best` (least `(E, k)`); `None` on a NaN
/// energy.
#[inline(always)]
fn scan_block(
    curve: &[f32],
    p: &SearchParams,
    d: f64,
    j: usize,
    lo: usize,
    hi: usize,
    best: &mut Option<(usize, f64)>,
) -> Option<()> {
    let from = (j * BLOCK_BINS).max(lo);
    let to = (j * BLOCK_BINS + BLOCK_BINS - 1).min(hi);
    for (k, &c) in curve.iter().enumerate().take(to + 1).skip(from) {
        let seen = c < UNSEEN;
        if !seen {
            continue;
        }
        let e = energy_scaled(d, p.rho[k], c, p.inv_two_theta, p.inv_lambda);
        if e.is_nan() {
            return None;
        }
        if best.is_none_or(|(k_best, e_best)| e < e_best || (e == e_best && k < k_best)) {
            *best = Some((k, e));
        }
    }
    Some(())
}

/// The definition's scan of `lo..=hi`: the first scanned cell (`!(c >= UNSEEN)`, NaN included),
/// then any with a strictly lower energy.
#[inline(always)]
pub(crate) fn plain_scan(
    curve: &[f32],
    p: &SearchParams,
    d: f64,
    lo: usize,
    hi: usize,
) -> Option<(usize, f64)> {
    let mut best: Option<(usize, f64)> = None;
    for (k, &c) in curve.iter().enumerate().take(hi + 1).skip(lo) {
        if c >= UNSEEN {
            continue;
        }
        let e = energy_scaled(d, p.rho[k], c, p.inv_two_theta, p.inv_lambda);
        if best.is_none_or(|(_, e_best)| e < e_best) {
            best = Some((k, e));
        }
    }
    best
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::InverseDepthBins;

    #[test]
    fn minima_skip_unseen_cells_and_keep_nans() {
        let curve = [3.0, UNSEEN, 1.0, 2.0, 5.0, 6.0, 7.0, 8.0, UNSEEN, f32::INFINITY, f32::NAN, 0.5];
        let mut out = [0.0; 2];
        block_minima(&curve, &mut out);
        assert_eq!(out[0], 1.0);
        assert!(out[1].is_nan());
        block_minima(&[UNSEEN, f32::INFINITY], &mut out[..1]);
        assert_eq!(out[0], UNSEEN);
    }

    #[test]
    fn block_bounds_are_below_every_energy_in_the_block() {
        let bins = InverseDepthBins::new(0.1, 2.0, 37).unwrap();
        let (theta, lambda) = (0.013, 3.7);
        let p = SearchParams::new(&bins, theta, lambda);
        let curve: Vec<f32> = (0..37).map(|k| ((k * 7919) % 31) as f32 * 0.37).collect();
        let mut minima = vec![0.0; block_count(37)];
        block_minima(&curve, &mut minima);
        for d in [-0.5, 0.1, 0.37, 1.0, 1.3333, 2.0, 2.8] {
            for (j, &m) in minima.iter().enumerate() {
                let b = bound(d, (p.rho_block_lo[j], p.rho_block_hi[j]), m, &p);
                for (k, &c) in curve.iter().enumerate().skip(j * BLOCK_BINS).take(BLOCK_BINS) {
                    let e = energy_scaled(d, p.rho[k], c, p.inv_two_theta, p.inv_lambda);
                    assert!(b <= e, "d {d}, block {j}, k {k}: bound {b} > energy {e}");
                }
            }
            for (lo, hi) in [(0, 36), (3, 20), (9, 9), (17, 36)] {
                assert_eq!(bounded_search(&curve, &minima, &p, d, lo, hi), plain_scan(&curve, &p, d, lo, hi));
            }
        }
    }
}
