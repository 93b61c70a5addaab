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

use ndarray::{Array2, ArrayView2, ArrayView3};
use rayon::prelude::*;

use crate::costvolume::{parabola_offset, UNSEEN_COST};
use crate::geometry::InverseDepthBins;

/// Cells at or above this are unseen (`crate::costvolume::UNSEEN_COST`).
pub const UNSEEN: f32 = UNSEEN_COST;

/// Per-pixel extreme seen costs, computed once per cost volume.
#[derive(Clone, Debug)]
pub struct CostRange {
    /// `(C_min, C_max)` per pixel; `(∞, -∞)` where nothing was seen.
    range: Array2<(f32, f32)>,
}

impl CostRange {
    /// Scan the volume once.
    pub fn new(costs: ArrayView3<f32>) -> Self {
        let (h, w, _) = costs.dim();
        let range = Array2::from_shape_fn((h, w), |(y, x)| {
            costs
                .slice(ndarray::s![y, x, ..])
                .iter()
                .filter(|&&c| c < UNSEEN)
                .fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), &c| (lo.min(c), hi.max(c)))
        });
        Self { range }
    }
}

/// Energy of hypothesis `k` for a pixel.
#[inline]
fn energy(d: f64, rho: f64, cost: f32, theta: f64, lambda: f64) -> f64 {
    let diff = d - rho;
    diff * diff / (2.0 * theta) + cost as f64 / lambda
}

/// Search one pixel over hypotheses `lo..=hi`; `None` if none of them was seen.
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

/// The auxiliary map `a` for the current `d` (`[H, W]`), row-parallel.
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
    let (h, w, _) = costs.dim();
    assert_eq!(d.dim(), (h, w), "d must match the cost volume");
    let mut a = Array2::<f32>::zeros((h, w));
    let slice = a.as_slice_mut().expect("owned arrays are contiguous");
    slice.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
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
