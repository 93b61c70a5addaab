//! Per-pixel cost-curve analysis on a `[H, W, K]` cost array (SPEC.md §9.5, §9.10-§9.12):
//! the evidence filter (a cell competes only when enough frames saw it), winner-take-all on an
//! array, the per-volume cost scale that makes one `λ` serve every feature kind, and the confidence
//! map. Every function is a per-pixel computation, row-parallel, so its bits do not depend on the
//! thread count; the one reduction over pixels (the median of the scale) sorts first.

use ndarray::{Array2, Array3, ArrayView3};
use rayon::prelude::*;

use super::wta::refined_minimum;
use super::{WtaDepth, UNSEEN_COST};
use crate::geometry::InverseDepthBins;

/// Per-pixel evidence threshold: with `N_u = max_k N_{u,k}` (the most frames that saw any
/// hypothesis of the pixel), a cell competes iff `N_{u,k} >= max(1, ceil(fraction · N_u))`.
#[inline]
pub fn evidence_threshold(max_count: u16, fraction: f64) -> u16 {
    ((fraction * f64::from(max_count)).ceil() as u16).max(1)
}

/// The evidence fraction's rule (SPEC.md §9.10): a fraction in `[0, 1]`.
///
/// # Errors
/// [`crate::error::Error::InvalidArgument`] (`min-evidence`) otherwise.
pub fn check_evidence_fraction(fraction: f64) -> crate::error::Result<()> {
    if (0.0..=1.0).contains(&fraction) {
        Ok(())
    } else {
        Err(crate::error::Error::invalid_argument(
            "min-evidence",
            format!("{fraction}: must be a fraction in [0, 1]"),
        ))
    }
}

/// Mean costs `[H, W, K]` from `costs` and `counts` with every cell below the evidence threshold
/// (see [`evidence_threshold`]) replaced by [`UNSEEN_COST`]. `fraction = 0` keeps every seen cell.
///
/// # Panics
/// If the shapes differ.
pub fn filter_evidence(costs: &mut Array3<f32>, counts: ArrayView3<u16>, fraction: f64) {
    assert_eq!(costs.dim(), counts.dim(), "costs and counts must agree");
    let k = costs.dim().2;
    let counts = counts.as_standard_layout();
    let counts = counts.as_slice().expect("standard layout");
    let costs = costs.as_slice_mut().expect("owned cost arrays are contiguous");
    costs.par_chunks_mut(k.max(1)).zip(counts.par_chunks(k.max(1))).for_each(|(c, n)| {
        let t = evidence_threshold(n.iter().copied().max().unwrap_or(0), fraction);
        for (c, &n) in c.iter_mut().zip(n) {
            if n < t {
                *c = UNSEEN_COST;
            }
        }
    });
}

/// Winner-take-all on a cost array (cells `>= UNSEEN_COST` are unseen): SPEC.md §9.5, the same
/// rule as [`super::CostVolume::winner_take_all`] (bit-identical on the unfiltered costs).
pub fn winner_take_all_costs(costs: ArrayView3<f32>, bins: &InverseDepthBins) -> WtaDepth {
    let (h, w, k_count) = costs.dim();
    let mut rows: Vec<Vec<Option<(f64, f64)>>> = vec![Vec::new(); h];
    rows.par_iter_mut().enumerate().for_each(|(y, row)| {
        *row = (0..w)
            .map(|x| {
                let curve = costs.slice(ndarray::s![y, x, ..]);
                refined_minimum(k_count, |k| (curve[k] < UNSEEN_COST).then_some(curve[k]), bins)
            })
            .collect();
    });
    let mut out = WtaDepth {
        inverse_depth: Array2::zeros((h, w)),
        depth: Array2::zeros((h, w)),
        valid: Array2::from_elem((h, w), false),
        bin: Array2::zeros((h, w)),
    };
    for (y, row) in rows.iter().enumerate() {
        for (x, r) in row.iter().enumerate() {
            if let Some((bin, rho)) = *r {
                out.set(y, x, bin, rho);
            }
        }
    }
    out
}

/// Minimum and median of a pixel's seen costs; `None` with fewer than 2 seen cells.
fn min_median(curve: ndarray::ArrayView1<f32>, scratch: &mut Vec<f32>) -> Option<(f32, f32)> {
    scratch.clear();
    scratch.extend(curve.iter().copied().filter(|&c| c < UNSEEN_COST));
    if scratch.len() < 2 {
        return None;
    }
    // The minimum and the order statistic `(n-1)/2` under `total_cmp` (values that compare equal
    // under it have equal bits, so this is the value a full sort would put there), in O(n).
    let lo = scratch.iter().copied().min_by(f32::total_cmp).expect("at least two cells");
    let mid = (scratch.len() - 1) / 2;
    let (_, &mut med, _) = scratch.select_nth_unstable_by(mid, f32::total_cmp);
    Some((lo, med))
}

/// The volume's cost scale `s`: the median over pixels (with at least two seen cells) of the
/// pixel's spread `median_k C - min_k C` over seen cells (lower median for even counts). It has the
/// units of the cost, so `C / s` is dimensionless and multiplying every feature by a constant leaves
/// `C / s` unchanged. 1 when no pixel has a positive spread.
pub fn cost_scale(costs: ArrayView3<f32>) -> f64 {
    let (h, w, _) = costs.dim();
    let spreads: Vec<f32> = (0..h)
        .into_par_iter()
        .flat_map_iter(|y| {
            let mut scratch = Vec::new();
            (0..w)
                .filter_map(|x| {
                    min_median(costs.slice(ndarray::s![y, x, ..]), &mut scratch).map(|(lo, med)| med - lo)
                })
                .collect::<Vec<_>>()
        })
        .collect();
    scale_of_spreads(spreads)
}

/// [`confidence`] and [`cost_scale`] of the same costs from one pass: each pixel's minimum and
/// median are computed once and feed both. Bit-identical to calling the two functions.
///
/// # Panics
/// If the shapes differ.
pub fn confidence_and_scale(
    costs: ArrayView3<f32>,
    counts: ArrayView3<u16>,
    frames: usize,
) -> (Array2<f32>, f64) {
    assert_eq!(costs.dim(), counts.dim(), "costs and counts must agree");
    let (h, w, _) = costs.dim();
    let mut out = Array2::<f32>::zeros((h, w));
    let slice = out.as_slice_mut().expect("owned arrays are contiguous");
    let rows: Vec<Vec<f32>> = slice
        .par_chunks_mut(w.max(1))
        .enumerate()
        .map(|(y, row)| {
            let mut scratch = Vec::new();
            let mut spreads = Vec::new();
            for (x, out) in row.iter_mut().enumerate() {
                let curve = costs.slice(ndarray::s![y, x, ..]);
                let Some((lo, med)) = min_median(curve, &mut scratch) else { continue };
                spreads.push(med - lo);
                *out = pixel_confidence(curve, counts, (y, x), (lo, med), frames);
            }
            spreads
        })
        .collect();
    (out, scale_of_spreads(rows.into_iter().flatten().collect()))
}

/// One pixel's confidence from its minimum and median (see [`confidence`]).
#[inline]
fn pixel_confidence(
    curve: ndarray::ArrayView1<f32>,
    counts: ArrayView3<u16>,
    (y, x): (usize, usize),
    (lo, med): (f32, f32),
    frames: usize,
) -> f32 {
    let sharp = if med > 0.0 { 1.0 - f64::from(lo) / f64::from(med) } else { 0.0 };
    let k = curve.iter().position(|&c| c == lo).expect("the minimum is a seen cell");
    let evidence = f64::from(counts[[y, x, k]]) / frames.max(1) as f64;
    (sharp.clamp(0.0, 1.0) * evidence.min(1.0)) as f32
}

/// [`cost_scale`] from the per-pixel spreads (of the pixels with at least two seen cells, in any
/// order: they are sorted first). A device backend computes the spreads per pixel and this median
/// on the host (SPEC.md §15.6).
pub fn scale_of_spreads(mut spreads: Vec<f32>) -> f64 {
    if spreads.is_empty() {
        return 1.0;
    }
    spreads.sort_by(f32::total_cmp);
    let s = f64::from(spreads[(spreads.len() - 1) / 2]);
    if s > 0.0 && s.is_finite() {
        s
    } else {
        1.0
    }
}

/// Per-pixel confidence in `[0, 1]`: `(1 - C_min / C_med) · N_{u,k*} / N`, the cost curve's
/// sharpness (0 for a flat curve, 1 when the best cost is 0 and the median is not) times the
/// fraction of the `frames` live frames that saw the winning cell `k*` (the first argmin). 0 where
/// fewer than two cells are seen.
///
/// # Panics
/// If the shapes differ.
pub fn confidence(costs: ArrayView3<f32>, counts: ArrayView3<u16>, frames: usize) -> Array2<f32> {
    assert_eq!(costs.dim(), counts.dim(), "costs and counts must agree");
    let (h, w, _) = costs.dim();
    let mut out = Array2::<f32>::zeros((h, w));
    let slice = out.as_slice_mut().expect("owned arrays are contiguous");
    slice.par_chunks_mut(w.max(1)).enumerate().for_each(|(y, row)| {
        let mut scratch = Vec::new();
        for (x, out) in row.iter_mut().enumerate() {
            let curve = costs.slice(ndarray::s![y, x, ..]);
            let Some((lo, med)) = min_median(curve, &mut scratch) else { continue };
            *out = pixel_confidence(curve, counts, (y, x), (lo, med), frames);
        }
    });
    out
}

/// Smallest weight of [`border_weight`] (a pixel on the border keeps 5 % of its data term).
pub const BORDER_WEIGHT_FLOOR: f32 = 0.05;

/// The border taper's weight of pixel `(y, x)` of an `h x w` grid for a taper of `r` pixels of that
/// grid (SPEC.md §10.1c; applied after winner-take-all, to the regulariser's data term only): `clamp((d + 0.5) / r, 0.05, 1)`, `d` the pixel's distance in pixels to the
/// nearest image edge (0 on the outermost row or column); 1 for `r <= 0`.
pub fn border_weight(y: usize, x: usize, h: usize, w: usize, r: f64) -> f32 {
    if r <= 0.0 {
        return 1.0;
    }
    let d = x.min(y).min(w - 1 - x).min(h - 1 - y) as f64 + 0.5;
    ((d / r) as f32).clamp(BORDER_WEIGHT_FLOOR, 1.0)
}

/// Applies the border taper of `r` pixels of the volume's grid to `costs` (`[H, W, K]`): every
/// seen cost (`< UNSEEN_COST`) of pixel `(y, x)` is multiplied by [`border_weight`]; unseen cells
/// stay unseen. Per pixel, so the same bits for any thread count.
pub fn taper_border(costs: &mut Array3<f32>, r: f64) {
    if r <= 0.0 {
        return;
    }
    let (h, w, _) = costs.dim();
    for y in 0..h {
        for x in 0..w {
            let wt = border_weight(y, x, h, w, r);
            if wt < 1.0 {
                costs
                    .slice_mut(ndarray::s![y, x, ..])
                    .iter_mut()
                    .filter(|c| **c < UNSEEN_COST)
                    .for_each(|c| *c *= wt);
            }
        }
    }
}
