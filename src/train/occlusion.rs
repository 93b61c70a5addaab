//! Occlusion masking of the training loss (`--occlusion-mask TAU`, SPEC.md §13.1c).
//!
//! The loss (§13.1) asks a reference pixel's feature to match the live frame's feature at the
//! pixel's true match `u' = π(T_lr π⁻¹(u, ρ*))`. Where the reference point is hidden in the live
//! frame behind a nearer surface, the live feature there is the occluder's, and the loss teaches
//! the network that the two look alike: a wall pixel beside a box learns the box's features, and
//! at run time matches the box's motion, i.e. takes the box's depth. This mask removes such pixels
//! from the loss, as pixels whose match leaves the live image are removed.
//!
//! A reference pixel with ground-truth depth `z` is **occluded** in a live frame when its point,
//! at depth `z' = 1/ρ'` in the live camera (`ρ'` of [`Warp::apply`]), projects to `u'` inside the
//! live image and every valid depth `z_t` among the live depth map's bilinear taps of `u'`
//! (SPEC.md §2.1: the up to four pixels around it) is nearer than the point by more than the
//! tolerance: `z_t < (1 − τ) z'`, with at least one valid tap. A tap at the point's own depth, or
//! behind it, keeps the pixel (the rule is conservative at depth edges, where a sub-pixel match
//! may still see the point). Everything is per pixel, in f64, with no reduction, so the mask does
//! not depend on the thread count.

use ndarray::{Array2, ArrayView2};

use crate::geometry::Warp;
use crate::image::is_valid_depth;

/// Whether the reference pixel `(u, v)` at depth `z` (valid) is hidden in the live frame of
/// `warp` (reference camera to live camera, full frames) whose depth map is `live_depth`
/// (`[H, W]` of the live camera, metres, 0 invalid), with tolerance `tau` (module docs). `false`
/// when the point is behind the live camera or projects outside its image (the loss masks those
/// already), or when no tap has a valid depth.
pub fn occluded(warp: &Warp, live_depth: ArrayView2<f32>, u: f64, v: f64, z: f32, tau: f64) -> bool {
    let Some(m) = warp.apply(u, v, 1.0 / f64::from(z)) else { return false };
    let cam = warp.target();
    if !cam.contains(m.uv.x, m.uv.y) {
        return false;
    }
    // `z` is valid and the point is in front (`apply`), so `ρ' > 0`.
    let z_point = 1.0 / m.rho;
    let (h, w) = live_depth.dim();
    let (x0, y0) = (m.uv.x.floor() as usize, m.uv.y.floor() as usize);
    let (x1, y1) = ((x0 + 1).min(w - 1), (y0 + 1).min(h - 1));
    let mut any = false;
    for (y, x) in [(y0, x0), (y0, x1), (y1, x0), (y1, x1)] {
        let zt = live_depth[[y, x]];
        if !is_valid_depth(zt) {
            continue;
        }
        if f64::from(zt) >= (1.0 - tau) * z_point {
            return false;
        }
        any = true;
    }
    any
}

/// Sets to 0 (invalid, so the loss masks it) every pixel of `depth`, a reference window whose
/// pixel `(x, y)` is full-frame pixel `(x + origin.0, y + origin.1)`, that is [`occluded`] in any
/// of `lives` (each the warp from the full reference camera to a live frame's full camera, and
/// that frame's depth). Returns how many pixels were masked. `tau = 0` or no live frame masks
/// nothing.
pub fn mask_occluded(
    depth: &mut Array2<f32>,
    origin: (usize, usize),
    lives: &[(Warp, ArrayView2<'_, f32>)],
    tau: f64,
) -> usize {
    if tau <= 0.0 {
        return 0;
    }
    let mut masked = 0;
    for ((y, x), z) in depth.indexed_iter_mut() {
        if !is_valid_depth(*z) {
            continue;
        }
        let (u, v) = ((x + origin.0) as f64, (y + origin.1) as f64);
        if lives.iter().any(|(warp, ld)| occluded(warp, *ld, u, v, *z, tau)) {
            *z = 0.0;
            masked += 1;
        }
    }
    masked
}
