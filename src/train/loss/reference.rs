//! The f64 oracle of the loss: plain loops, every sample and cost in f64.

use ndarray::{Array3, ArrayView2, ArrayView3};

use super::{
    any_target, bilinear_taps, check_inputs, check_lives, hypothesis_position, multi_target, pixel_sampled,
};
use super::{
    pixel_terms, ray_point, seen_energies, LiveView, LossConfig, LossSums, MultiCost, MultiScaleLoss,
    ScaleLoss,
};
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
    let m = scale_loss_multi_reference(cfg, f_ref, &[LiveView { features: f_live, warp }], depth)?;
    let Some(d_live) = m.d_lives.into_iter().next() else {
        unreachable!("one live frame in, one gradient out")
    };
    Ok(ScaleLoss { sums: m.sums, d_ref: m.d_ref, d_live })
}

/// The multi-frame loss of one scale and its gradients, in f64 (SPEC.md §13.1b): per hypothesis
/// the mean over the live frames of each frame's cost (`m` outside that frame).
///
/// # Errors
/// [`crate::Error::InvalidArgument`] for a bad configuration, no live frame, or shapes that
/// disagree.
pub fn scale_loss_multi_reference(
    cfg: &LossConfig,
    f_ref: ArrayView3<f64>,
    lives: &[LiveView<'_, f64>],
    depth: ArrayView2<f32>,
) -> Result<MultiScaleLoss<f64>> {
    cfg.validate()?;
    check_lives(lives.len())?;
    for l in lives {
        check_inputs(l.warp, f_ref.shape(), l.features.shape(), &depth)?;
    }
    let (h, w, c) = f_ref.dim();
    let k = cfg.bins.count;
    let n_live = lives.len() as f64;
    let mut sums = LossSums::default();
    let mut d_ref = Array3::<f64>::zeros((h, w, c));
    let mut d_lives: Vec<Array3<f64>> = lives.iter().map(|l| Array3::zeros(l.features.raw_dim())).collect();
    let mut energies = vec![0.0; k];
    let mut grad = vec![0.0; k];
    type Taps = Option<([usize; 4], [f64; 4])>;
    let mut taps: Vec<Vec<Taps>> = vec![vec![None; k]; lives.len()];
    // Gradients are summed first (weighted s² under sampling) and divided by the unmasked pixel
    // count at the end.
    let m = cfg.sample_stride * cfg.sample_stride;
    let mut unmasked = 0;
    let sample = |live: &LiveView<'_, f64>, idx: &[usize; 4], wt: &[f64; 4], ch: usize| -> f64 {
        let wl = live.features.dim().1;
        (0..4).map(|t| wt[t] * live.features[[idx[t] / wl, idx[t] % wl, ch]]).sum()
    };
    let seen = cfg.multi_cost == MultiCost::Seen;
    let mut counts = vec![0u32; k];
    for y in 0..h {
        for x in 0..w {
            let z = depth[[y, x]];
            let target =
                if seen { any_target(cfg, lives, x, y, z) } else { multi_target(cfg, lives, x, y, z) };
            let Some((rho_star, target)) = target else { continue };
            // Every frame's taps (under `Seen` the pixel's use depends on them, SPEC.md §13.1d).
            energies.fill(0.0);
            counts.fill(0);
            for (live, live_taps) in lives.iter().zip(&mut taps) {
                let (hl, wl, _) = live.features.dim();
                let p0 = ray_point(live.warp, x, y);
                for l in 0..k {
                    live_taps[l] = hypothesis_position(live.warp, &p0, cfg.bins.rho(l))
                        .and_then(|(u, v)| bilinear_taps(u, v, wl, hl));
                    energies[l] += match &live_taps[l] {
                        None if seen => 0.0,
                        None => cfg.outside_cost,
                        Some((idx, wt)) => {
                            counts[l] += 1;
                            (0..c)
                                .map(|ch| {
                                    let s = sample(live, idx, wt, ch);
                                    (f_ref[[y, x, ch]] - s) * (f_ref[[y, x, ch]] - s)
                                })
                                .sum()
                        }
                    };
                }
            }
            let need = if seen {
                let need = seen_energies(cfg, &mut energies, &counts);
                if counts[target] < need {
                    continue;
                }
                need
            } else {
                for e in energies.iter_mut() {
                    *e /= n_live;
                }
                0
            };
            unmasked += 1;
            if !pixel_sampled(cfg, x, y) {
                continue;
            }
            let terms = pixel_terms(cfg, &energies, target, rho_star, &mut grad);
            sums.add_pixel(cfg, &terms, rho_star, m);
            for ((live, live_taps), d_live) in lives.iter().zip(&taps).zip(&mut d_lives) {
                let wl = live.features.dim().1;
                for l in 0..k {
                    let Some((idx, wt)) = &live_taps[l] else { continue };
                    // ∂E_l/∂(frame n's cost): 1/N, or under `Seen` 1/c_l where bin l competes.
                    let per_frame = if !seen {
                        n_live
                    } else if counts[l] >= need {
                        f64::from(counts[l])
                    } else {
                        continue;
                    };
                    for ch in 0..c {
                        let s = sample(live, idx, wt, ch);
                        let r = 2.0 * m as f64 * grad[l] * (f_ref[[y, x, ch]] - s) / per_frame;
                        d_ref[[y, x, ch]] += r;
                        for t in 0..4 {
                            d_live[[idx[t] / wl, idx[t] % wl, ch]] -= r * wt[t];
                        }
                    }
                }
            }
        }
    }
    sums.pixels = unmasked;
    if sums.pixels > 0 {
        let n = sums.pixels as f64;
        d_ref.mapv_inplace(|v| v / n);
        for d in &mut d_lives {
            d.mapv_inplace(|v| v / n);
        }
    }
    Ok(MultiScaleLoss { sums, d_ref, d_lives })
}
