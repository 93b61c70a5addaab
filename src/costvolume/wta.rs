//! Winner-take-all over a cost volume with sub-bin parabola refinement (SPEC.md §9.5).

use ndarray::Array2;

use super::CostVolume;

/// Per-pixel winner-take-all result.
#[derive(Clone, Debug)]
pub struct WtaDepth {
    /// Refined inverse depth, 1/m; 0 where invalid (check `valid`: 0 is also a legal hypothesis).
    pub inverse_depth: Array2<f32>,
    /// `1 / inverse_depth`, metres; 0 (no measurement, SPEC.md §2.2) where invalid or where the
    /// refined inverse depth is not positive (a point at infinity).
    pub depth: Array2<f32>,
    /// Whether some hypothesis of the pixel was seen by at least one frame.
    pub valid: Array2<bool>,
    /// The refined continuous bin coordinate `k* + δ`; 0 where invalid.
    pub bin: Array2<f32>,
}

/// Largest sub-bin offset of the parabola refinement.
pub(crate) const MAX_OFFSET: f64 = 0.5;

pub(super) fn winner_take_all(cv: &CostVolume) -> WtaDepth {
    let (h, w, k_count) = cv.dim();
    let bins = cv.bins();
    let mut out = WtaDepth {
        inverse_depth: Array2::zeros((h, w)),
        depth: Array2::zeros((h, w)),
        valid: Array2::from_elem((h, w), false),
        bin: Array2::zeros((h, w)),
    };
    let mut curve: Vec<Option<f32>> = vec![None; k_count];
    for y in 0..h {
        for x in 0..w {
            for (k, c) in curve.iter_mut().enumerate() {
                *c = cv.cost(y, x, k);
            }
            let Some((bin, rho)) = refined_minimum(k_count, |k| curve[k], bins) else { continue };
            out.valid[[y, x]] = true;
            out.set(y, x, bin, rho);
        }
    }
    out
}

impl WtaDepth {
    /// Stores pixel `(y, x)`'s refined bin and inverse depth (and the depth `1/ρ`, 0 for `ρ <= 0`).
    pub(super) fn set(&mut self, y: usize, x: usize, bin: f64, rho: f64) {
        self.valid[[y, x]] = true;
        self.bin[[y, x]] = bin as f32;
        self.inverse_depth[[y, x]] = rho as f32;
        self.depth[[y, x]] = if rho > 0.0 { (1.0 / rho) as f32 } else { 0.0 };
    }
}

/// The first (lowest-k) minimum among the seen cells of one cost curve (`cost(k)` is `None` for
/// an unseen cell), refined by [`parabola_offset`] when both neighbours are seen: the refined
/// bin `k* + δ` and its inverse depth. `None` when no cell is seen.
pub(super) fn refined_minimum(
    k_count: usize,
    cost: impl Fn(usize) -> Option<f32>,
    bins: &crate::geometry::InverseDepthBins,
) -> Option<(f64, f64)> {
    let mut best: Option<(usize, f32)> = None;
    for k in 0..k_count {
        if let Some(c) = cost(k) {
            if best.is_none_or(|(_, b)| c < b) {
                best = Some((k, c));
            }
        }
    }
    let (k, c0) = best?;
    let offset = if k > 0 && k + 1 < k_count {
        match (cost(k - 1), cost(k + 1)) {
            (Some(cm), Some(cp)) => parabola_offset(cm.into(), c0.into(), cp.into()),
            _ => 0.0,
        }
    } else {
        0.0
    };
    let bin = k as f64 + offset;
    let rho = if offset == 0.0 { bins.rho(k) } else { bins.rho_min + bin * bins.step() };
    Some((bin, rho))
}

/// Vertex of the parabola through `(-1, cm), (0, c0), (1, cp)`:
/// `δ = (cm - cp) / (2 (cm - 2 c0 + cp))`, clamped to `±0.5`; 0 when the curvature is not positive.
#[inline(always)]
pub fn parabola_offset(cm: f64, c0: f64, cp: f64) -> f64 {
    let curvature = cm - 2.0 * c0 + cp;
    if curvature > 0.0 {
        ((cm - cp) / (2.0 * curvature)).clamp(-MAX_OFFSET, MAX_OFFSET)
    } else {
        0.0
    }
}
