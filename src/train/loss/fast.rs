//! The fast f32 loss: samples, residuals and costs in f32, the per-pixel softmax and regression in
//! f64 ([`pixel_terms`]). Per reference pixel the in-image hypotheses' bilinear taps are computed
//! once (f64, as the reference), their costs and residuals in one pass over the live features
//! ([`kernel::costs`]), and after [`pixel_terms`] the backward in one more ([`kernel::backward`]).
//! Reference rows are split into a fixed number of chunks (independent of the thread count); each
//! chunk scatters its live-feature gradient into its own lazily allocated tiles of live rows, and
//! the tiles are summed in chunk order, so the result is bit-identical for any thread count.

use ndarray::{Array3, ArrayView2, ArrayView3};
use rayon::prelude::*;

use super::kernel::{self, LiveRows, Tap, TILE_PX};
use super::taps::{self, PixelRay};
use super::{
    any_target, check_inputs, check_lives, multi_target, pixel_sampled, pixel_terms_with, PixelScratch,
};
use super::{seen_energies, seen_need, LiveView, LossConfig, LossSums, MultiCost, MultiScaleLoss, ScaleLoss};
use crate::error::Result;
use crate::geometry::Warp;
use crate::runtime::CpuFeatureLevel;

/// Most chunks the reference rows are split into (fixed, so results do not depend on threads).
const CHUNKS: usize = 16;

/// What one chunk of reference rows produces.
struct ChunkOut {
    sums: LossSums,
    /// Per live frame.
    d_live: Vec<LiveRows>,
}

/// Per-chunk scratch of one live frame, reused for every pixel.
struct PerLive {
    taps: Vec<Tap>,
    resid: Vec<f32>,
    e32: Vec<f32>,
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
    scale_loss_with(CpuFeatureLevel::get(), cfg, f_ref, f_live, depth, warp)
}

/// [`scale_loss`] at a chosen CPU-feature level (every level gives the same bits; for tests and
/// benches).
///
/// # Errors
/// As [`scale_loss`].
pub fn scale_loss_with(
    level: CpuFeatureLevel,
    cfg: &LossConfig,
    f_ref: ArrayView3<f32>,
    f_live: ArrayView3<f32>,
    depth: ArrayView2<f32>,
    warp: &Warp,
) -> Result<ScaleLoss<f32>> {
    let m = scale_loss_multi_with(level, cfg, f_ref, &[LiveView { features: f_live, warp }], depth)?;
    let Some(d_live) = m.d_lives.into_iter().next() else {
        unreachable!("one live frame in, one gradient out")
    };
    Ok(ScaleLoss { sums: m.sums, d_ref: m.d_ref, d_live })
}

/// The multi-frame loss of one scale (SPEC.md §13.1b) and its gradients, f32: the costs of every
/// live frame averaged per hypothesis, then §13.1's softmax, cross-entropy and regression. With
/// one live frame it is [`scale_loss`], bit for bit. Same contract as
/// [`super::scale_loss_multi_reference`].
///
/// # Errors
/// [`crate::Error::InvalidArgument`] for a bad configuration, no live frame, or shapes that
/// disagree.
pub fn scale_loss_multi(
    cfg: &LossConfig,
    f_ref: ArrayView3<f32>,
    lives: &[LiveView<'_, f32>],
    depth: ArrayView2<f32>,
) -> Result<MultiScaleLoss<f32>> {
    scale_loss_multi_with(CpuFeatureLevel::get(), cfg, f_ref, lives, depth)
}

/// [`scale_loss_multi`] at a chosen CPU-feature level.
///
/// # Errors
/// As [`scale_loss_multi`].
pub fn scale_loss_multi_with(
    level: CpuFeatureLevel,
    cfg: &LossConfig,
    f_ref: ArrayView3<f32>,
    lives: &[LiveView<'_, f32>],
    depth: ArrayView2<f32>,
) -> Result<MultiScaleLoss<f32>> {
    cfg.validate()?;
    check_lives(lives.len())?;
    for l in lives {
        check_inputs(l.warp, f_ref.shape(), l.features.shape(), &depth)?;
    }
    let (h, w, c) = f_ref.dim();
    let n_live = lives.len();
    let kernels = kernel::loss_kernels(level, c);
    let f_ref = f_ref.as_standard_layout();
    let Some(fr) = f_ref.as_slice() else { unreachable!("standard-layout arrays are contiguous") };
    let live_maps: Vec<_> = lives.iter().map(|l| l.features.as_standard_layout()).collect();
    let fls: Vec<&[f32]> = live_maps
        .iter()
        .map(|a| a.as_slice().unwrap_or_else(|| unreachable!("standard-layout arrays are contiguous")))
        .collect();
    let dims: Vec<(usize, usize)> = lives.iter().map(|l| (l.features.dim().0, l.features.dim().1)).collect();
    let k = cfg.bins.count;
    let rhos: Vec<f64> = (0..k).map(|l| cfg.bins.rho(l)).collect();
    let seen = cfg.multi_cost == MultiCost::Seen;
    // The pixel count first, so every gradient is scaled once, as it is made. Under `Seen` a
    // pixel counts when its true bin competes (SPEC.md §13.1d), from the same taps as below.
    let targets: Vec<Option<(f64, usize)>> = (0..h * w)
        .into_par_iter()
        .map_init(
            || (Vec::with_capacity(k), vec![0u32; k]),
            |(tap_buf, counts), i| {
                let (x, y, z) = (i % w, i / w, depth[[i / w, i % w]]);
                if !seen {
                    return multi_target(cfg, lives, x, y, z);
                }
                let (rho_star, target) = any_target(cfg, lives, x, y, z)?;
                counts.fill(0);
                for (live, &(hl, wl)) in lives.iter().zip(&dims) {
                    taps::hypothesis_taps(
                        kernels,
                        &PixelRay::new(live.warp, x, y, wl, hl, c),
                        &rhos,
                        tap_buf,
                    );
                    for tap in tap_buf.iter() {
                        counts[tap.bin as usize] += 1;
                    }
                }
                (counts[target] >= seen_need(counts)).then_some((rho_star, target))
            },
        )
        .collect();
    let n = targets.iter().filter(|t| t.is_some()).count();
    // Under sampling (SPEC.md §13.1a) each evaluated pixel stands for m = s² pixels; each live
    // frame's cost counts 1/N of the averaged cost.
    let m = cfg.sample_stride * cfg.sample_stride;
    let scale = if n > 0 { m as f64 / n as f64 } else { 0.0 };
    let inv_live = 1.0 / n_live as f64;
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
    let outs: Vec<ChunkOut> = pieces
        .into_par_iter()
        .map(|(i, d_ref_rows)| {
            let mut sums = LossSums::default();
            let mut d_live: Vec<LiveRows> =
                dims.iter().map(|&(hl, wl)| LiveRows::new(hl, wl * c, c)).collect();
            let mut per_live: Vec<PerLive> = (0..n_live)
                .map(|_| PerLive { taps: Vec::with_capacity(k), resid: vec![0.0; k * c], e32: vec![0.0; k] })
                .collect();
            let mut coefs = vec![0.0f32; k];
            let mut energies = vec![0.0f64; k];
            let mut counts = vec![0u32; k];
            let mut grad = vec![0.0f64; k];
            let mut scratch = PixelScratch::default();
            let rows = rows_of(i);
            for y in rows.clone() {
                for x in 0..w {
                    let Some((rho_star, target)) = targets[y * w + x] else { continue };
                    if !pixel_sampled(cfg, x, y) {
                        continue;
                    }
                    let f_u = &fr[(y * w + x) * c..][..c];
                    for (((live, pl), fl), &(hl, wl)) in lives.iter().zip(&mut per_live).zip(&fls).zip(&dims)
                    {
                        let ray = PixelRay::new(live.warp, x, y, wl, hl, c);
                        taps::hypothesis_taps(kernels, &ray, &rhos, &mut pl.taps);
                        kernel::costs(kernels, f_u, fl, wl * c, &pl.taps, &mut pl.resid, &mut pl.e32);
                    }
                    // E_l = (Σ_n E_l^(n)) / N, in f64, live frames in order (m outside a frame);
                    // under `Seen` the sum over the frames that see bin l, over their count.
                    let mut need = 0;
                    if seen {
                        energies.fill(0.0);
                        counts.fill(0);
                        for pl in &per_live {
                            for (tap, &e) in pl.taps.iter().zip(&pl.e32) {
                                energies[tap.bin as usize] += f64::from(e);
                                counts[tap.bin as usize] += 1;
                            }
                        }
                        need = seen_energies(cfg, &mut energies, &counts);
                    } else if n_live == 1 {
                        energies.fill(cfg.outside_cost);
                        for (tap, &e) in per_live[0].taps.iter().zip(&per_live[0].e32) {
                            energies[tap.bin as usize] = f64::from(e);
                        }
                    } else {
                        energies.fill(0.0);
                        for pl in &per_live {
                            let mut next = 0;
                            for (l, e) in energies.iter_mut().enumerate() {
                                if next < pl.taps.len() && pl.taps[next].bin as usize == l {
                                    *e += f64::from(pl.e32[next]);
                                    next += 1;
                                } else {
                                    *e += cfg.outside_cost;
                                }
                            }
                        }
                        for e in energies.iter_mut() {
                            *e *= inv_live;
                        }
                    }
                    let terms =
                        pixel_terms_with(cfg, &energies, target, rho_star, &mut grad, &mut scratch, level);
                    sums.add_pixel(cfg, &terms, rho_star, m);
                    let d_u = &mut d_ref_rows[((y - rows.start) * w + x) * c..][..c];
                    for (pl, dl) in per_live.iter().zip(&mut d_live) {
                        for (coef, tap) in coefs.iter_mut().zip(&pl.taps) {
                            let b = tap.bin as usize;
                            *coef = if !seen {
                                (2.0 * grad[b] * scale * inv_live) as f32
                            } else if counts[b] >= need {
                                (2.0 * grad[b] * scale / f64::from(counts[b])) as f32
                            } else {
                                0.0
                            };
                        }
                        kernel::backward(kernels, &pl.taps, &coefs, &pl.resid, d_u, dl);
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
    sums.pixels = n;
    let d_lives = (0..n_live)
        .map(|li| {
            let (hl, wl) = dims[li];
            let row = wl * c;
            let mut d_live = Array3::<f32>::zeros((hl, wl, c));
            let Some(dl) = d_live.as_slice_mut() else { unreachable!("new arrays are contiguous") };
            // Each live row, tile by tile: the chunks that touched the tile, summed in chunk order.
            dl.par_chunks_mut(row).enumerate().for_each(|(yl, out)| {
                for (t, out) in out.chunks_mut(TILE_PX * c).enumerate() {
                    let mut first = true;
                    for o in &outs {
                        let rows = &o.d_live[li];
                        let src = &rows.tiles[yl * rows.per_row + t];
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
                }
            });
            d_live
        })
        .collect();
    Ok(MultiScaleLoss { sums, d_ref, d_lives })
}
