//! The f64 oracle of the loss: plain loops, every sample and cost in f64.

use ndarray::{Array3, ArrayView2, ArrayView3};

use super::{
    bilinear_taps, check_inputs, hypothesis_position, pixel_sampled, pixel_target, pixel_terms, ray_point,
};
use super::{LossConfig, LossSums, ScaleLoss};
use crate::error::Result;
use crate::geometry::Warp;

/// The loss of one scale and its gradients, in f64 (SPEC.md §13.1). `warp` maps the reference
/// camera (its size must match `f_ref` and `depth`) to the live camera (`f_live`'s size).
///
/// # Errors
/// [`crate::Error::InvalidArgument`] for a bad configuration or shapes that disagree.
pub fn scale_loss_reference(
    cfg: &LossConfig,
    f_ref: ArrayView3<f64>,
    f_live: ArrayView3<f64>,
    depth: ArrayView2<f32>,
    warp: &Warp,
) -> Result<ScaleLoss<f64>> {
    cfg.validate()?;
    check_inputs(warp, f_ref.shape(), f_live.shape(), &depth)?;
    let (h, w, c) = f_ref.dim();
    let (hl, wl, _) = f_live.dim();
    let k = cfg.bins.count;
    let mut sums = LossSums::default();
    let mut d_ref = Array3::<f64>::zeros((h, w, c));
    let mut d_live = Array3::<f64>::zeros((hl, wl, c));
    let mut energies = vec![0.0; k];
    let mut grad = vec![0.0; k];
    let mut taps: Vec<Option<([usize; 4], [f64; 4])>> = vec![None; k];
    // Gradients are summed first (weighted s² under sampling) and divided by the unmasked pixel
    // count at the end.
    let m = cfg.sample_stride * cfg.sample_stride;
    let mut unmasked = 0;
    for y in 0..h {
        for x in 0..w {
            let Some((rho_star, target)) = pixel_target(cfg, warp, x, y, depth[[y, x]]) else { continue };
            unmasked += 1;
            if !pixel_sampled(cfg, x, y) {
                continue;
            }
            let p0 = ray_point(warp, x, y);
            for l in 0..k {
                taps[l] = hypothesis_position(warp, &p0, cfg.bins.rho(l))
                    .and_then(|(u, v)| bilinear_taps(u, v, wl, hl));
                energies[l] = match &taps[l] {
                    None => cfg.outside_cost,
                    Some((idx, wt)) => (0..c)
                        .map(|ch| {
                            let s: f64 = (0..4).map(|t| wt[t] * f_live[[idx[t] / wl, idx[t] % wl, ch]]).sum();
                            (f_ref[[y, x, ch]] - s) * (f_ref[[y, x, ch]] - s)
                        })
                        .sum(),
                };
            }
            let terms = pixel_terms(cfg, &energies, target, rho_star, &mut grad);
            sums.add_pixel(cfg, &terms, rho_star, m);
            for l in 0..k {
                let Some((idx, wt)) = &taps[l] else { continue };
                for ch in 0..c {
                    let s: f64 = (0..4).map(|t| wt[t] * f_live[[idx[t] / wl, idx[t] % wl, ch]]).sum();
                    let r = 2.0 * m as f64 * grad[l] * (f_ref[[y, x, ch]] - s);
                    d_ref[[y, x, ch]] += r;
                    for t in 0..4 {
                        d_live[[idx[t] / wl, idx[t] % wl, ch]] -= r * wt[t];
                    }
                }
            }
        }
    }
    sums.pixels = unmasked;
    if sums.pixels > 0 {
        let n = sums.pixels as f64;
        d_ref.mapv_inplace(|v| v / n);
        d_live.mapv_inplace(|v| v / n);
    }
    Ok(ScaleLoss { sums, d_ref, d_live })
}
