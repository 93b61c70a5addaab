//! The fast f32 loss: samples, residuals and costs in f32, the per-pixel softmax and regression in
//! f64 ([`pixel_terms`]). Per reference pixel the in-image hypotheses' bilinear taps are computed
//! once (f64, as the reference), their costs and residuals in one pass over the live features
//! ([`kernel::costs`]), and after [`pixel_terms`] the backward in one more ([`kernel::backward`]).
//! Reference rows are split into a fixed number of chunks (independent of the thread count); each
//! chunk scatters its live-feature gradient into its own lazily allocated live rows, and the rows
//! are summed in chunk order, so the result is bit-identical for any thread count.

use ndarray::{Array3, ArrayView2, ArrayView3};
use rayon::prelude::*;

use super::kernel::{self, LiveRows, LossKernel, Tap};
use super::{check_inputs, hypothesis_position, pixel_sampled, pixel_target, pixel_terms, ray_point};
use super::{LossConfig, LossSums, ScaleLoss};
use crate::error::Result;
use crate::geometry::Warp;
use crate::image::sample::axis;

/// Most chunks the reference rows are split into (fixed, so results do not depend on threads).
const CHUNKS: usize = 16;

/// What one chunk of reference rows produces.
struct ChunkOut {
    sums: LossSums,
    d_live: LiveRows,
}

/// Per-chunk scratch, reused for every pixel.
struct Scratch {
    taps: Vec<Tap>,
    resid: Vec<f32>,
    e32: Vec<f32>,
    coefs: Vec<f32>,
    energies: Vec<f64>,
    grad: Vec<f64>,
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
    scale_loss_with(LossKernel::Auto, cfg, f_ref, f_live, depth, warp)
}

/// [`scale_loss`] with a chosen kernel implementation (both give the same bits; for tests and
/// benches).
///
/// # Errors
/// As [`scale_loss`].
pub fn scale_loss_with(
    kernel: LossKernel,
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
    let avx512 = kernel::uses_avx512(kernel, c);
    let f_ref = f_ref.as_standard_layout();
    let f_live = f_live.as_standard_layout();
    let (Some(fr), Some(fl)) = (f_ref.as_slice(), f_live.as_slice()) else {
        unreachable!("standard-layout arrays are contiguous")
    };
    // The pixel count first, so every gradient is scaled once, as it is made.
    let targets: Vec<Option<(f64, usize)>> = (0..h * w)
        .into_par_iter()
        .map(|i| pixel_target(cfg, warp, i % w, i / w, depth[[i / w, i % w]]))
        .collect();
    let n = targets.iter().filter(|t| t.is_some()).count();
    // Under sampling (SPEC.md §13.1a) each evaluated pixel stands for m = s² pixels.
    let m = cfg.sample_stride * cfg.sample_stride;
    let scale = if n > 0 { m as f64 / n as f64 } else { 0.0 };
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
    let rhos: Vec<f64> = (0..k).map(|l| cfg.bins.rho(l)).collect();
    let row = wl * c;
    let outs: Vec<ChunkOut> = pieces
        .into_par_iter()
        .map(|(i, d_ref_rows)| {
            let mut sums = LossSums::default();
            let mut d_live = LiveRows::new(hl, row);
            let mut s = Scratch {
                taps: Vec::with_capacity(k),
                resid: vec![0.0; k * c],
                e32: vec![0.0; k],
                coefs: vec![0.0; k],
                energies: vec![0.0; k],
                grad: vec![0.0; k],
            };
            let rows = rows_of(i);
            for y in rows.clone() {
                for x in 0..w {
                    let Some((rho_star, target)) = targets[y * w + x] else { continue };
                    if !pixel_sampled(cfg, x, y) {
                        continue;
                    }
                    let p0 = ray_point(warp, x, y);
                    s.taps.clear();
                    for (l, &rho) in rhos.iter().enumerate() {
                        // bilinear_taps, without its flat indices (no integer divisions).
                        let Some((u, v)) = hypothesis_position(warp, &p0, rho) else { continue };
                        let (Some((x0, x1, a)), Some((y0, y1, b))) = (axis(u, wl), axis(v, hl)) else {
                            continue;
                        };
                        let wt = [(1.0 - a) * (1.0 - b), a * (1.0 - b), (1.0 - a) * b, a * b];
                        s.taps.push(Tap {
                            bin: l as u32,
                            y: [y0 as u32, y1 as u32],
                            xc: [x0 * c, x1 * c],
                            w: wt.map(|v| v as f32),
                        });
                    }
                    let f_u = &fr[(y * w + x) * c..][..c];
                    kernel::costs(avx512, f_u, fl, row, &s.taps, &mut s.resid, &mut s.e32);
                    s.energies.fill(cfg.outside_cost);
                    for (tap, &e) in s.taps.iter().zip(&s.e32) {
                        s.energies[tap.bin as usize] = f64::from(e);
                    }
                    let terms = pixel_terms(cfg, &s.energies, target, rho_star, &mut s.grad);
                    sums.add_pixel(cfg, &terms, rho_star, m);
                    for (coef, tap) in s.coefs.iter_mut().zip(&s.taps) {
                        *coef = (2.0 * s.grad[tap.bin as usize] * scale) as f32;
                    }
                    let d_u = &mut d_ref_rows[((y - rows.start) * w + x) * c..][..c];
                    kernel::backward(avx512, &s.taps, &s.coefs, &s.resid, d_u, &mut d_live);
                }
            }
            ChunkOut { sums, d_live }
        })
        .collect();
    let mut sums = LossSums::default();
    for o in &outs {
        sums.accumulate(&o.sums);
    }
    sums.pixels = n;
    let mut d_live = Array3::<f32>::zeros((hl, wl, c));
    let Some(dl) = d_live.as_slice_mut() else { unreachable!("new arrays are contiguous") };
    // Each live row: the chunks that touched it, summed in chunk order.
    dl.par_chunks_mut(row).enumerate().for_each(|(yl, out)| {
        let mut first = true;
        for o in &outs {
            let src = &o.d_live.rows[yl];
            if src.is_empty() {
                continue;
            }
            if first {
                out.copy_from_slice(src);
                first = false;
            } else {
                for (v, &g) in out.iter_mut().zip(src) {
                    *v += g;
                }
            }
        }
    });
    Ok(ScaleLoss { sums, d_ref, d_live })
}
