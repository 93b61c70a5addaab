//! Dense SIFT, fast (SPEC.md §9a.2): the window weight of cell `(i, j)` is separable,
//! `k_j(d_x) k_i(d_y)`, so the histograms are two 1-D correlations of per-pixel orientation planes:
//!
//! 1. `S = (R + G) + B` per pixel (exact for byte images), f32;
//! 2. orientation planes `P[y, x, o] = m · w_o(θ)` (`[H, W, 8]`) from
//!    `g = ((S(x+1) - S(x-1)) / 6, (S(y+1) - S(y-1)) / 6)` (the grey image's central differences);
//! 3. horizontal pass `Q[y, x, j, o] = Σ_d k_j(d) P[y, x + d, o]` (`[H, W, 4, 8]`);
//! 4. vertical pass `h[y, x, i, j, o] = Σ_d k_i(d) Q[y + d, x, j, o]` and the per-pixel
//!    normalisation, written into the `[H, W, 128]` output.
//!
//! Samples outside the image are skipped (zero gradient). Every stage splits over output rows with
//! rayon, and each value is summed in a fixed order (taps by increasing offset; the normalisation's
//! norms over 16 lanes folded pairwise), so the output is bit-identical for any thread count.

use ndarray::{Array3, ArrayView3};
use rayon::prelude::*;

use super::{DsiftParams, CELLS, CHANNELS, CLIP, ORIENTATIONS};
use crate::util::alloc::{zeroed_map_aligned, zeroed_vec};

/// Values of one pixel's horizontal pass: 4 cell columns x 8 orientations.
const ROW_CELLS: usize = CELLS * ORIENTATIONS;
/// Partial sums of the normalisation's norms.
const LANES: usize = 16;

/// The non-zero taps of `k_j` for every cell index, weights rounded to f32.
fn taps_f32(params: &DsiftParams) -> [Vec<(isize, f32)>; CELLS] {
    std::array::from_fn(|j| params.taps(j).into_iter().map(|(d, k)| (d as isize, k as f32)).collect())
}

/// Dense SIFT, fast path. `rgb` must be `[H >= 1, W >= 1, 3]` (checked by [`super::dense_sift`]).
pub fn dense_sift_fast(rgb: ArrayView3<f32>, params: &DsiftParams) -> Array3<f32> {
    let (h, w, _) = rgb.dim();
    let rgb = rgb.as_standard_layout();
    let Some(src) = rgb.as_slice() else { unreachable!("standard layout is contiguous") };
    let taps = taps_f32(params);

    let mut sum = zeroed_vec(h * w);
    sum.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        for (x, s) in row.iter_mut().enumerate() {
            let p = &src[(y * w + x) * 3..][..3];
            *s = (p[0] + p[1]) + p[2];
        }
    });

    let mut planes = zeroed_vec(h * w * ORIENTATIONS);
    planes.par_chunks_mut(w * ORIENTATIONS).enumerate().for_each(|(y, row)| {
        orientation_row(&sum, (h, w), y, row);
    });
    drop(sum);

    let mut horizontal = zeroed_vec(h * w * ROW_CELLS);
    horizontal.par_chunks_mut(w * ROW_CELLS).enumerate().for_each(|(y, row)| {
        horizontal_row(&planes[y * w * ORIENTATIONS..][..w * ORIENTATIONS], &taps, row);
    });
    drop(planes);

    let fade_denominator = (params.unit_field_weight() * params.min_contrast) as f32;
    let scale = params.scale as f32;
    let mut out = zeroed_map_aligned([h, w, CHANNELS]);
    let Some(dst) = out.as_slice_mut() else { unreachable!("a new map is standard layout") };
    dst.par_chunks_mut(w * CHANNELS).enumerate().for_each(|(y, row)| {
        vertical_row(&horizontal, (h, w), y, &taps, row);
        for px in row.chunks_exact_mut(CHANNELS) {
            normalise(px, fade_denominator, scale);
        }
    });
    out
}

/// Row `y` of the orientation planes from the grey sums `S` (`[h, w]`).
fn orientation_row(sum: &[f32], (h, w): (usize, usize), y: usize, out: &mut [f32]) {
    const PER_RADIAN: f32 = (ORIENTATIONS as f64 / std::f64::consts::TAU) as f32;
    let row = &sum[y * w..][..w];
    let (up, down) = (&sum[y.saturating_sub(1) * w..][..w], &sum[(y + 1).min(h - 1) * w..][..w]);
    for (x, px) in out.chunks_exact_mut(ORIENTATIONS).enumerate() {
        let gx = (row[(x + 1).min(w - 1)] - row[x.saturating_sub(1)]) / 6.0;
        let gy = (down[x] - up[x]) / 6.0;
        let m = (gx * gx + gy * gy).sqrt();
        if m == 0.0 {
            continue;
        }
        let mut theta = gy.atan2(gx);
        if theta < 0.0 {
            theta += std::f32::consts::TAU;
        }
        let t = theta * PER_RADIAN;
        let fl = t.floor();
        // `t` is in [0, 8] (8 only when θ rounds up to 2π: bin 0); NaN casts to 0.
        let o0 = (fl as usize) % ORIENTATIONS;
        let f = t - fl;
        px[o0] = m * (1.0 - f);
        px[(o0 + 1) % ORIENTATIONS] = m * f;
    }
}

/// One row of the horizontal pass: `out[x, j, o] = Σ_d k_j(d) planes[x + d, o]` over the taps
/// inside the row, by increasing `d`.
fn horizontal_row(planes: &[f32], taps: &[Vec<(isize, f32)>; CELLS], out: &mut [f32]) {
    let w = planes.len() / ORIENTATIONS;
    for (x, px) in out.chunks_exact_mut(ROW_CELLS).enumerate() {
        for (j, cell) in px.chunks_exact_mut(ORIENTATIONS).enumerate() {
            let mut acc = [0.0f32; ORIENTATIONS];
            for &(d, k) in &taps[j] {
                let xx = x as isize + d;
                if xx < 0 || xx >= w as isize {
                    continue;
                }
                let src = &planes[xx as usize * ORIENTATIONS..][..ORIENTATIONS];
                for (a, &p) in acc.iter_mut().zip(src) {
                    *a += k * p;
                }
            }
            cell.copy_from_slice(&acc);
        }
    }
}

/// Output row `y` of the vertical pass: `out[x, i, (j, o)] = Σ_d k_i(d) horizontal[y + d, x, (j, o)]`
/// over the taps inside the image, by increasing `d`.
fn vertical_row(
    horizontal: &[f32],
    (h, w): (usize, usize),
    y: usize,
    taps: &[Vec<(isize, f32)>; CELLS],
    out: &mut [f32],
) {
    for (x, px) in out.chunks_exact_mut(CHANNELS).enumerate() {
        for (i, block) in px.chunks_exact_mut(ROW_CELLS).enumerate() {
            let mut acc = [0.0f32; ROW_CELLS];
            for &(d, k) in &taps[i] {
                let yy = y as isize + d;
                if yy < 0 || yy >= h as isize {
                    continue;
                }
                let src = &horizontal[(yy as usize * w + x) * ROW_CELLS..][..ROW_CELLS];
                for (a, &q) in acc.iter_mut().zip(src) {
                    *a += k * q;
                }
            }
            block.copy_from_slice(&acc);
        }
    }
}

/// `Σ v` and `Σ v²` over 16 lanes (value `c` in lane `c mod 16`) folded pairwise.
fn sums(v: &[f32]) -> (f32, f32) {
    let (mut s1, mut s2) = ([0.0f32; LANES], [0.0f32; LANES]);
    for chunk in v.chunks_exact(LANES) {
        for l in 0..LANES {
            s1[l] += chunk[l];
            s2[l] += chunk[l] * chunk[l];
        }
    }
    let mut width = LANES / 2;
    while width > 0 {
        for l in 0..width {
            s1[l] += s1[l + width];
            s2[l] += s2[l + width];
        }
        width /= 2;
    }
    (s1[0], s2[0])
}

/// Lowe's normalisation with the contrast fade and the scale, in place, f32 (SPEC.md §9a.2):
/// `scale · min(1, ‖h‖₁ / (W₁ τ)) / ‖v‖₂ · v`, `v = min(h / ‖h‖₂, 0.2)`; zero where `‖h‖₂ = 0`.
fn normalise(px: &mut [f32], fade_denominator: f32, scale: f32) {
    debug_assert_eq!(px.len() % LANES, 0);
    let (n1, n2sq) = sums(px);
    let n2 = n2sq.sqrt();
    if n2 == 0.0 {
        px.fill(0.0);
        return;
    }
    let fade = (n1 / fade_denominator).min(1.0);
    for v in px.iter_mut() {
        *v = (*v / n2).min(CLIP as f32);
    }
    let (_, nvsq) = sums(px);
    let k = scale * fade / nvsq.sqrt();
    for v in px.iter_mut() {
        *v *= k;
    }
}
