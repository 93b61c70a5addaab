//! The fast f32 loss: samples, residuals and costs in f32, the per-pixel softmax and regression in
//! f64 ([`pixel_terms`]). Reference rows are split into a fixed number of chunks (independent of
//! the thread count); each chunk scatters its live-feature gradient into its own buffer and the
//! buffers are summed in chunk order, so the result is bit-identical for any thread count.

use ndarray::{Array3, ArrayView2, ArrayView3};
use rayon::prelude::*;

use super::{bilinear_taps, check_inputs, hypothesis_position, pixel_target, pixel_terms, ray_point};
use super::{LossConfig, LossSums, ScaleLoss};
use crate::error::Result;
use crate::geometry::Warp;

/// Most chunks the reference rows are split into (fixed, so results do not depend on threads).
const CHUNKS: usize = 16;

/// What one chunk of reference rows produces.
struct ChunkOut {
    sums: LossSums,
    d_live: Vec<f32>,
}

/// The loss of one scale and its gradients, f32 (SPEC.md §13.1, budget §13.3). Same contract as
/// [`super::scale_loss_reference`].
///
/// # Errors
/// [`crate::Error::InvalidArgument`] for a bad configuration or shapes that disagree.
pub fn scale_loss(
    cfg: &LossConfig,
    f_ref: ArrayView3<f32>,
    f_live: ArrayView3<f32>,
    depth: ArrayView2<f32>,
    warp: &Warp,
) -> Result<ScaleLoss<f32>> {
    cfg.validate()?;
    check_inputs(warp, f_ref.shape(), f_live.shape(), &depth)?;
    let (h, w, c) = f_ref.dim();
    let (hl, wl, _) = f_live.dim();
    let f_ref = f_ref.as_standard_layout();
    let f_live = f_live.as_standard_layout();
    let (Some(fr), Some(fl)) = (f_ref.as_slice(), f_live.as_slice()) else {
        unreachable!("standard-layout arrays are contiguous")
    };
    // The pixel count first, so every gradient is scaled once, as it is made.
    let targets: Vec<Option<(f64, usize)>> =
        (0..h * w).map(|i| pixel_target(cfg, warp, i % w, i / w, depth[[i / w, i % w]])).collect();
    let n = targets.iter().filter(|t| t.is_some()).count();
    let scale = if n > 0 { 1.0 / n as f64 } else { 0.0 };
    let mut d_ref = Array3::<f32>::zeros((h, w, c));
    let Some(d_ref_slice) = d_ref.as_slice_mut() else { unreachable!("new arrays are contiguous") };
    let chunks = CHUNKS.min(h);
    let rows_of = |i: usize| (i * h / chunks)..((i + 1) * h / chunks);
    // Split d_ref into the chunks' rows.
    let mut pieces: Vec<(usize, &mut [f32])> = Vec::with_capacity(chunks);
    let mut rest = d_ref_slice;
    for i in 0..chunks {
        let (piece, tail) = std::mem::take(&mut rest).split_at_mut(rows_of(i).len() * w * c);
        pieces.push((i, piece));
        rest = tail;
    }
    let k = cfg.bins.count;
    let outs: Vec<ChunkOut> = pieces
        .into_par_iter()
        .map(|(i, d_ref_rows)| {
            let mut sums = LossSums::default();
            let mut d_live = vec![0.0f32; hl * wl * c];
            let mut taps: Vec<Option<([usize; 4], [f32; 4])>> = vec![None; k];
            let mut resid = vec![0.0f32; k * c];
            let mut energies = vec![0.0f64; k];
            let mut grad = vec![0.0f64; k];
            let rows = rows_of(i);
            for y in rows.clone() {
                for x in 0..w {
                    let Some((rho_star, target)) = targets[y * w + x] else { continue };
                    let f_u = &fr[(y * w + x) * c..][..c];
                    let p0 = ray_point(warp, x, y);
                    for l in 0..k {
                        let t = hypothesis_position(warp, &p0, cfg.bins.rho(l))
                            .and_then(|(u, v)| bilinear_taps(u, v, wl, hl))
                            .map(|(idx, wt)| (idx, wt.map(|v| v as f32)));
                        energies[l] = match &t {
                            None => cfg.outside_cost,
                            Some((idx, wt)) => {
                                let r = &mut resid[l * c..][..c];
                                let (a, b, cc, d) = (
                                    &fl[idx[0] * c..][..c],
                                    &fl[idx[1] * c..][..c],
                                    &fl[idx[2] * c..][..c],
                                    &fl[idx[3] * c..][..c],
                                );
                                let mut e = 0.0f32;
                                for ch in 0..c {
                                    let s = wt[0] * a[ch] + wt[1] * b[ch] + wt[2] * cc[ch] + wt[3] * d[ch];
                                    let v = f_u[ch] - s;
                                    r[ch] = v;
                                    e += v * v;
                                }
                                f64::from(e)
                            }
                        };
                        taps[l] = t;
                    }
                    let terms = pixel_terms(cfg, &energies, target, rho_star, &mut grad);
                    sums.add_pixel(cfg, &terms, rho_star);
                    let d_u = &mut d_ref_rows[((y - rows.start) * w + x) * c..][..c];
                    for l in 0..k {
                        let Some((idx, wt)) = &taps[l] else { continue };
                        let coef = (2.0 * grad[l] * scale) as f32;
                        if coef == 0.0 {
                            continue;
                        }
                        let r = &resid[l * c..][..c];
                        for (dv, &rv) in d_u.iter_mut().zip(r) {
                            *dv += coef * rv;
                        }
                        for t in 0..4 {
                            let cw = -coef * wt[t];
                            let dl = &mut d_live[idx[t] * c..][..c];
                            for (dv, &rv) in dl.iter_mut().zip(r) {
                                *dv += cw * rv;
                            }
                        }
                    }
                }
            }
            ChunkOut { sums, d_live }
        })
        .collect();
    let mut sums = LossSums::default();
    for o in &outs {
        sums.accumulate(&o.sums);
    }
    let mut d_live = Array3::<f32>::zeros((hl, wl, c));
    let Some(dl) = d_live.as_slice_mut() else { unreachable!("new arrays are contiguous") };
    dl.par_chunks_mut(wl * c).enumerate().for_each(|(row, out)| {
        let base = row * wl * c;
        for o in &outs {
            for (v, &g) in out.iter_mut().zip(&o.d_live[base..base + wl * c]) {
                *v += g;
            }
        }
    });
    Ok(ScaleLoss { sums, d_ref, d_live })
}
