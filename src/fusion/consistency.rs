//! Depth that agrees with its neighbours, before fusion (SPEC.md §16.10, issue 31).
//!
//! A keyframe's depth is fused only where other keyframes confirm it (multi-view geometric
//! consistency, as the MVS fusion scripts users compare against do) and away from depth
//! discontinuities (so no surface is bridged across an occlusion edge):
//!
//! ```text
//! X = T_wk π⁻¹(u, d)                 the keyframe's point (world)
//! p = T_wj⁻¹ X, u_j = π_j(p)          its pixel in view j
//! d_j = D_j[round(u_j)]               view j's depth there (nearest pixel; invalid: no vote)
//! p' = T_wk⁻¹ T_wj π_j⁻¹(round(u_j), d_j),  u' = π_k(p')
//! view j confirms u  iff  ‖u' − u‖ ≤ max_reprojection_px  and  |p'_z − d| ≤ max_depth_error · d
//! ```
//!
//! A pixel is kept when at least `min_views` views confirm it. The edge rule drops a pixel when a
//! valid 3x3 neighbour's depth differs from its own by more than the factor `max_ratio`. Both are
//! per-pixel decisions with no float reduction, parallel over rows: bit-identical for any thread
//! count.

use nalgebra::Vector3;
use ndarray::{Array2, ArrayView2};
use rayon::prelude::*;

use crate::geometry::{PinholeCamera, Pose};
use crate::image::is_valid_depth;

/// One view's depth map, camera and camera-to-world pose.
#[derive(Clone, Copy, Debug)]
pub struct ViewDepth<'a> {
    /// Depth `[H, W]`, metres, invalid as SPEC.md §2.8.
    pub depth: ArrayView2<'a, f32>,
    /// The camera of this depth map's grid.
    pub camera: PinholeCamera,
    /// Camera-to-world pose.
    pub pose: Pose,
}

/// The multi-view check (SPEC.md §16.10).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ConsistencyRule {
    /// Views that must confirm a pixel; 0 turns the check off.
    pub min_views: usize,
    /// Largest relative depth difference of the round trip.
    pub max_depth_error: f64,
    /// Largest round-trip reprojection distance, keyframe pixels.
    pub max_reprojection_px: f64,
}

/// How many of `others` confirm each pixel of `view` (0 where `view`'s depth is invalid).
pub fn confirmations(view: &ViewDepth<'_>, others: &[ViewDepth<'_>], rule: &ConsistencyRule) -> Array2<u16> {
    let (h, w) = view.depth.dim();
    let mut out = Array2::<u16>::zeros((h, w));
    // World → other camera, and other camera → this camera, once per view.
    let links: Vec<(Pose, Pose)> =
        others.iter().map(|o| (o.pose.inverse() * view.pose, view.pose.inverse() * o.pose)).collect();
    let Some(slice) = out.as_slice_mut() else { unreachable!("new arrays are contiguous") };
    slice.par_chunks_mut(w.max(1)).enumerate().for_each(|(y, row)| {
        for (x, out_px) in row.iter_mut().enumerate() {
            let d = view.depth[[y, x]];
            if !is_valid_depth(d) {
                continue;
            }
            let d = f64::from(d);
            let p_k = view.camera.ray(x as f64, y as f64) * d;
            let mut votes = 0u16;
            for (o, (k_to_j, j_to_k)) in others.iter().zip(&links) {
                if confirms(o, k_to_j, j_to_k, &view.camera, &p_k, (x as f64, y as f64), d, rule) {
                    votes += 1;
                }
            }
            *out_px = votes;
        }
    });
    out
}

/// Whether view `o` confirms the keyframe point `p_k` (keyframe camera coordinates) seen at
/// pixel `u` with depth `d`.
#[allow(clippy::too_many_arguments)]
#[inline]
fn confirms(
    o: &ViewDepth<'_>,
    k_to_j: &Pose,
    j_to_k: &Pose,
    cam_k: &PinholeCamera,
    p_k: &Vector3<f64>,
    u: (f64, f64),
    d: f64,
    rule: &ConsistencyRule,
) -> bool {
    let p_j = k_to_j.transform_vector(p_k) + k_to_j.translation.vector;
    let Some(uv) = o.camera.project(&p_j) else { return false };
    let (xj, yj) = (uv.x.round(), uv.y.round());
    let (hj, wj) = o.depth.dim();
    if !(xj >= 0.0 && yj >= 0.0 && xj < wj as f64 && yj < hj as f64) {
        return false;
    }
    let dj = o.depth[[yj as usize, xj as usize]];
    if !is_valid_depth(dj) {
        return false;
    }
    let q_j = o.camera.ray(xj, yj) * f64::from(dj);
    let q_k = j_to_k.transform_vector(&q_j) + j_to_k.translation.vector;
    let Some(back) = cam_k.project(&q_k) else { return false };
    let reproj = ((back.x - u.0).powi(2) + (back.y - u.1).powi(2)).sqrt();
    reproj <= rule.max_reprojection_px && (q_k.z - d).abs() <= rule.max_depth_error * d
}

/// `true` where the pixel has valid depth and no valid 3x3 neighbour differs from it by more than
/// the factor `max_ratio` (`max(a/b, b/a) > max_ratio`); `max_ratio <= 1` or not finite turns the
/// rule off (every valid pixel kept).
pub fn smooth_mask(depth: ArrayView2<'_, f32>, max_ratio: f64) -> Array2<bool> {
    let (h, w) = depth.dim();
    let off = !(max_ratio.is_finite() && max_ratio > 1.0);
    let mut out = Array2::from_elem((h, w), false);
    let Some(slice) = out.as_slice_mut() else { unreachable!("new arrays are contiguous") };
    slice.par_chunks_mut(w.max(1)).enumerate().for_each(|(y, row)| {
        for (x, out_px) in row.iter_mut().enumerate() {
            let d = depth[[y, x]];
            if !is_valid_depth(d) {
                continue;
            }
            if off {
                *out_px = true;
                continue;
            }
            let d = f64::from(d);
            let mut ok = true;
            for ny in y.saturating_sub(1)..(y + 2).min(h) {
                for nx in x.saturating_sub(1)..(x + 2).min(w) {
                    let n = depth[[ny, nx]];
                    if is_valid_depth(n) {
                        let n = f64::from(n);
                        ok &= (n / d).max(d / n) <= max_ratio;
                    }
                }
            }
            *out_px = ok;
        }
    });
    out
}

/// `view`'s depth with the pixels that fail either rule set to 0 (invalid): at least
/// `min(rule.min_views, others.len())` confirmations among `others` (skipped when that is 0: a
/// keyframe with no neighbour has nothing to be checked against) and [`smooth_mask`] with
/// `max_ratio`.
pub fn filter_depth(
    view: &ViewDepth<'_>,
    others: &[ViewDepth<'_>],
    rule: &ConsistencyRule,
    max_ratio: f64,
) -> Array2<f32> {
    let smooth = smooth_mask(view.depth, max_ratio);
    let need = rule.min_views.min(others.len());
    let votes = (need > 0).then(|| confirmations(view, others, rule));
    let mut out = view.depth.to_owned();
    for ((idx, v), &keep) in out.indexed_iter_mut().zip(smooth.iter()) {
        let confirmed = votes.as_ref().is_none_or(|c| usize::from(c[idx]) >= need);
        if !(keep && confirmed) {
            *v = 0.0;
        }
    }
    out
}
