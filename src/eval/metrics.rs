//! Depth metrics exactly as in Eigen et al. (NIPS 2014) and the paper's Table 1, plus the
//! supplement's `δ < 1.1`. Over the set `V` of pixels where both ground truth and prediction are
//! valid depths (finite, `> 0`), with `n = |V|`, accumulated in `f64`:
//!
//! - `rms = sqrt(1/n Σ (d - d*)²)`, metres
//! - `log rms = sqrt(1/n Σ (ln d - ln d*)²)`
//! - `abs rel = 1/n Σ |d - d*| / d*`
//! - `sq rel = 1/n Σ (d - d*)² / d*`
//! - `δ < t`: fraction of `V` with `max(d/d*, d*/d) < t`, for `t ∈ {1.1, 1.25, 1.25², 1.25³}`

use ndarray::ArrayView2;
use serde::Serialize;

use crate::error::{Error, Result};
use crate::image::is_valid_depth;

/// The paper's depth metrics over the pixels where both maps hold a valid depth.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct DepthMetrics {
    /// Root mean squared error, metres.
    pub rms: f64,
    /// Root mean squared error of natural logs.
    pub log_rms: f64,
    /// Mean absolute relative error.
    pub abs_rel: f64,
    /// Mean squared relative error (metres).
    pub sq_rel: f64,
    /// Fraction with ratio below 1.1.
    pub delta_1_1: f64,
    /// Fraction with ratio below 1.25.
    pub delta_1_25: f64,
    /// Fraction with ratio below 1.25².
    pub delta_1_25_2: f64,
    /// Fraction with ratio below 1.25³.
    pub delta_1_25_3: f64,
    /// Number of pixels evaluated.
    pub count: usize,
    /// Fraction of valid ground-truth pixels that had a prediction (coverage).
    pub coverage: f64,
}

/// Compute [`DepthMetrics`] of `pred` against `gt` (both `[H, W]`, metres, invalid = `0`/non-finite).
///
/// # Errors
/// [`Error::InvalidArgument`] if the shapes differ or no pixel has both a valid prediction and
/// valid ground truth.
pub fn depth_metrics(pred: ArrayView2<f32>, gt: ArrayView2<f32>) -> Result<DepthMetrics> {
    if pred.dim() != gt.dim() {
        return Err(Error::invalid_argument(
            "depth maps",
            format!("prediction is {:?} but ground truth is {:?}", pred.dim(), gt.dim()),
        ));
    }
    let (mut n, mut n_gt) = (0usize, 0usize);
    let (mut se, mut sle, mut ar, mut sr) = (0.0f64, 0.0f64, 0.0f64, 0.0f64);
    let mut hits = [0usize; 4];
    const THRESHOLDS: [f64; 4] = [1.1, 1.25, 1.25 * 1.25, 1.25 * 1.25 * 1.25];
    for (&p, &g) in pred.iter().zip(gt.iter()) {
        if !is_valid_depth(g) {
            continue;
        }
        n_gt += 1;
        if !is_valid_depth(p) {
            continue;
        }
        let (p, g) = (p as f64, g as f64);
        let d = p - g;
        n += 1;
        se += d * d;
        let dl = p.ln() - g.ln();
        sle += dl * dl;
        ar += d.abs() / g;
        sr += d * d / g;
        let ratio = (p / g).max(g / p);
        for (h, t) in hits.iter_mut().zip(THRESHOLDS) {
            *h += usize::from(ratio < t);
        }
    }
    if n == 0 {
        return Err(Error::invalid_argument(
            "depth maps",
            format!("no pixel has both a valid prediction and valid ground truth ({n_gt} valid ground-truth pixels)"),
        ));
    }
    let nf = n as f64;
    Ok(DepthMetrics {
        rms: (se / nf).sqrt(),
        log_rms: (sle / nf).sqrt(),
        abs_rel: ar / nf,
        sq_rel: sr / nf,
        delta_1_1: hits[0] as f64 / nf,
        delta_1_25: hits[1] as f64 / nf,
        delta_1_25_2: hits[2] as f64 / nf,
        delta_1_25_3: hits[3] as f64 / nf,
        count: n,
        coverage: nf / n_gt as f64,
    })
}
