//! The patch volume, fast (SPEC.md §9a.5): rows of `[W, K]` cells in parallel (each cell updated by
//! one task, frames in call order: bit-identical for any thread count); per pixel the reference patch
//! is read and mean-removed once; per hypothesis the same f64 patch warp, positions and corners as
//! the reference, then the 49 bilinear samples, the mean and the L1 in f32, each summed in patch
//! order.

use rayon::prelude::*;

use super::reference::offsets;
use super::{clamped_axis, patch_warp, Problem, PATCH_SAMPLES};

/// Add one live frame into `sums` / `counts` (`[H, W, K]`, hypothesis fastest).
pub(super) fn add_frame(p: &Problem, sums: &mut [f32], counts: &mut [u16]) {
    let w = p.key.dim().1;
    let row_len = w * p.rhos.len();
    if row_len == 0 {
        return;
    }
    sums.par_chunks_mut(row_len)
        .zip(counts.par_chunks_mut(row_len))
        .enumerate()
        .for_each(|(y, (s, c))| add_row(p, y, s, c));
}

/// The mean-removed reference patch of pixel `(x, y)`, f32, the mean summed in patch order.
fn reference_patch(p: &Problem, x: usize, y: usize) -> [f32; PATCH_SAMPLES] {
    let (h, w) = p.key.dim();
    let mut r = [0.0f32; PATCH_SAMPLES];
    for (ri, (dx, dy)) in r.iter_mut().zip(offsets()) {
        let yy = (y as i64 + dy).clamp(0, h as i64 - 1) as usize;
        let xx = (x as i64 + dx).clamp(0, w as i64 - 1) as usize;
        *ri = p.key[[yy, xx]];
    }
    let mean = r.iter().fold(0.0f32, |a, v| a + v) / PATCH_SAMPLES as f32;
    r.map(|v| v - mean)
}

fn add_row(p: &Problem, y: usize, sums: &mut [f32], counts: &mut [u16]) {
    let (lh, lw) = p.live.dim();
    let Some(live) = p.live.as_slice() else { unreachable!("the live image is standard layout") };
    let k_count = p.rhos.len();
    let tau = p.truncation;
    for (x, (s, c)) in sums.chunks_exact_mut(k_count).zip(counts.chunks_exact_mut(k_count)).enumerate() {
        let r = reference_patch(p, x, y);
        'hypotheses: for (k, &rho) in p.rhos.iter().enumerate() {
            let Some(pw) = patch_warp(p.warp, x as f64, y as f64, rho) else {
                continue;
            };
            let mut l = [0.0f32; PATCH_SAMPLES];
            for (li, (dx, dy)) in l.iter_mut().zip(offsets()) {
                let (sx, sy) = pw.position(dx, dy);
                let (Some((x0, x1, a)), Some((y0, y1, b))) = (clamped_axis(sx, lw), clamped_axis(sy, lh))
                else {
                    continue 'hypotheses;
                };
                let (a, b) = (a as f32, b as f32);
                // Invariant: corners from `clamped_axis` lie inside the `lh x lw` image.
                let (r0, r1) = (&live[y0 * lw..][..lw], &live[y1 * lw..][..lw]);
                *li = (1.0 - a) * (1.0 - b) * r0[x0]
                    + a * (1.0 - b) * r0[x1]
                    + (1.0 - a) * b * r1[x0]
                    + a * b * r1[x1];
            }
            let mean = l.iter().fold(0.0f32, |a, v| a + v) / PATCH_SAMPLES as f32;
            let e = r.iter().zip(&l).fold(0.0f32, |acc, (ri, li)| acc + (ri - (li - mean)).abs());
            s[k] += e.min(tau);
            c[k] += 1;
        }
    }
}
