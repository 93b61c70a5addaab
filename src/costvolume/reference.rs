//! The oracle: for every cell, warp with [`Warp::apply_volume`], sample with [`sample_bilinear`], and add
//! the `f64` L1 distance, truncated at `τ` (SPEC.md §9.13), to an `f64` running sum. One thread, no
//! hoisting. Keep it naive.

use ndarray::ArrayView3;

use crate::geometry::Warp;
use crate::image::sample_bilinear;

/// Add one live frame into `sums` / `counts` (`[H, W, K]`, hypothesis fastest).
pub(super) fn add_frame(
    reference: &ArrayView3<f32>,
    live: &ArrayView3<f32>,
    warp: &Warp,
    rhos: &[f64],
    truncation: f64,
    sums: &mut [f64],
    counts: &mut [u16],
) {
    let (h, w, c) = reference.dim();
    let k_count = rhos.len();
    let mut sample = vec![0.0f32; c];
    for y in 0..h {
        for x in 0..w {
            for (k, &rho) in rhos.iter().enumerate() {
                let Some(uv) = warp.apply_volume(x as f64, y as f64, rho) else {
                    continue; // behind the live camera
                };
                if !sample_bilinear(live, uv.x, uv.y, &mut sample) {
                    continue; // outside the live image
                }
                let l1: f64 =
                    (0..c).map(|ch| (f64::from(reference[[y, x, ch]]) - f64::from(sample[ch])).abs()).sum();
                let i = (y * w + x) * k_count + k;
                sums[i] += l1.min(truncation);
                counts[i] += 1;
            }
        }
    }
}
