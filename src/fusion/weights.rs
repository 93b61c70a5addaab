//! Per-pixel fusion weights (SPEC.md §16.2a, issue 31): how much the TSDF trusts each depth pixel.
//! Besides the mapper's confidence `c`, the view angle (a surface seen edge-on is measured worse)
//! and the distance (a two-view depth error grows with the square of the depth):
//!
//! ```text
//! confidence:      w = c
//! angle:           w = c · max(|n · r̂|, 0.1)
//! angle-distance:  w = c · max(|n · r̂|, 0.1) / max(d, 0.5)²
//! ```
//!
//! `r̂` is the unit viewing ray of the pixel, `n` the unit normal of the depth map there: the cross
//! product of the back-projected central differences to the right and below neighbours (one-sided
//! at the border; where a neighbour has no depth the pixel's `|n · r̂|` is 1). Per pixel, in f64,
//! no reductions: the same bits for any thread count.

use ndarray::{Array2, ArrayView2};
use rayon::prelude::*;
use serde::Serialize;

use crate::geometry::PinholeCamera;
use crate::image::is_valid_depth;

/// Which factors enter the weight (module docs).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Default)]
#[serde(rename_all = "kebab-case")]
pub enum FusionWeight {
    /// The confidence alone (the rule before 2026-12-03).
    Confidence,
    /// Confidence times the view angle's cosine (at least 0.1).
    Angle,
    /// As `Angle`, divided by the squared depth (at least 0.5 m): `map`'s default, chosen on the
    /// validation scenes (SPEC.md §16.2a).
    #[default]
    AngleDistance,
}

impl FusionWeight {
    /// Parses `confidence`, `angle` or `angle-distance`.
    ///
    /// # Errors
    /// A message listing the choices.
    pub fn parse(s: &str) -> std::result::Result<Self, String> {
        match s {
            "confidence" => Ok(Self::Confidence),
            "angle" => Ok(Self::Angle),
            "angle-distance" => Ok(Self::AngleDistance),
            other => Err(format!("{other:?}: expected confidence, angle or angle-distance")),
        }
    }
}

/// Smallest view-angle factor.
pub const MIN_COS: f64 = 0.1;
/// Depth below which the distance factor stops growing, metres.
pub const MIN_DEPTH: f64 = 0.5;

/// The weights of `depth` (metres, 0 / non-finite invalid) seen by `camera`, given the per-pixel
/// `confidence` (`None`: 1), under `rule`. Invalid pixels get weight 0.
pub fn fusion_weights(
    depth: ArrayView2<f32>,
    confidence: Option<ArrayView2<f32>>,
    camera: &PinholeCamera,
    rule: FusionWeight,
) -> Array2<f32> {
    let (h, w) = depth.dim();
    let mut out = Array2::<f32>::zeros((h, w));
    let Some(slice) = out.as_slice_mut() else { unreachable!("new arrays are contiguous") };
    slice.par_chunks_mut(w.max(1)).enumerate().for_each(|(y, row)| {
        for (x, o) in row.iter_mut().enumerate() {
            let d = depth[[y, x]];
            if !is_valid_depth(d) {
                continue;
            }
            let mut wgt = f64::from(confidence.map_or(1.0, |c| c[[y, x]]));
            if rule != FusionWeight::Confidence {
                wgt *= view_cosine(depth, camera, y, x).max(MIN_COS);
            }
            if rule == FusionWeight::AngleDistance {
                let d = f64::from(d).max(MIN_DEPTH);
                wgt /= d * d;
            }
            *o = wgt as f32;
        }
    });
    out
}

/// `|n · r̂|` at pixel `(y, x)` (valid depth), 1 where the normal is undefined (module docs).
fn view_cosine(depth: ArrayView2<f32>, camera: &PinholeCamera, y: usize, x: usize) -> f64 {
    let (h, w) = depth.dim();
    let point = |(y, x): (usize, usize)| {
        let d = depth[[y, x]];
        is_valid_depth(d).then(|| camera.ray(x as f64, y as f64) * f64::from(d))
    };
    // The back-projected difference b − a, where both have depth.
    let diff = |a: Option<(usize, usize)>, b: Option<(usize, usize)>| Some(point(b?)? - point(a?)?);
    let here = Some((y, x));
    let (left, right) = (x.checked_sub(1).map(|l| (y, l)), (x + 1 < w).then_some((y, x + 1)));
    let (up, down) = (y.checked_sub(1).map(|u| (u, x)), (y + 1 < h).then_some((y + 1, x)));
    // Central where both neighbours have depth, else one-sided.
    let ex = diff(left, right).or_else(|| diff(here, right)).or_else(|| diff(left, here));
    let ey = diff(up, down).or_else(|| diff(here, down)).or_else(|| diff(up, here));
    let (Some(ex), Some(ey), Some(r)) = (ex, ey, point((y, x))) else { return 1.0 };
    let n = ex.cross(&ey);
    let (nn, rn) = (n.norm(), r.norm());
    if nn > 0.0 && rn > 0.0 {
        (n.dot(&r) / (nn * rn)).abs()
    } else {
        1.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn camera() -> PinholeCamera {
        PinholeCamera { fx: 100.0, fy: 100.0, cx: 15.5, cy: 11.5, width: 32, height: 24 }
    }

    /// A plane `z = z0 + k x` (tilted about the y axis), as a depth map.
    fn plane(z0: f64, k: f64) -> Array2<f32> {
        let c = camera();
        Array2::from_shape_fn((c.height, c.width), |(_, x)| {
            // Ray (a, b, 1) with a = (x - cx) / fx meets z = z0 + k X at z = z0 / (1 - k a).
            let a = (x as f64 - c.cx) / c.fx;
            (z0 / (1.0 - k * a)) as f32
        })
    }

    #[test]
    fn weights_follow_the_view_angle_and_the_distance() {
        let c = camera();
        let conf = Array2::from_elem((c.height, c.width), 0.5f32);
        // Fronto-parallel at 2 m: the centre's cosine is ~1; confidence alone is the confidence.
        let flat = plane(2.0, 0.0);
        let w0 = fusion_weights(flat.view(), Some(conf.view()), &c, FusionWeight::Confidence);
        assert!(w0.iter().all(|&v| v == 0.5));
        let wa = fusion_weights(flat.view(), Some(conf.view()), &c, FusionWeight::Angle);
        assert!((f64::from(wa[[12, 16]]) - 0.5).abs() < 1e-3, "{}", wa[[12, 16]]);
        // Tilted by 60°: the cosine at the centre is about 0.5.
        let tilted = plane(2.0, 3f64.sqrt());
        let wt = fusion_weights(tilted.view(), Some(conf.view()), &c, FusionWeight::Angle);
        assert!((f64::from(wt[[12, 15]]) / 0.5 - 0.5).abs() < 0.03, "{}", wt[[12, 15]]);
        // Twice as far: a quarter of the weight.
        let far = plane(4.0, 0.0);
        let (wn, wf) = (
            fusion_weights(flat.view(), None, &c, FusionWeight::AngleDistance),
            fusion_weights(far.view(), None, &c, FusionWeight::AngleDistance),
        );
        assert!((f64::from(wf[[12, 16]]) * 4.0 - f64::from(wn[[12, 16]])).abs() < 1e-4);
        // Invalid depth: weight 0; a pixel whose neighbours have no depth keeps cosine 1.
        let mut holes = flat.clone();
        holes[[5, 5]] = 0.0;
        holes[[5, 7]] = f32::NAN;
        let wh = fusion_weights(holes.view(), None, &c, FusionWeight::AngleDistance);
        assert_eq!(wh[[5, 5]], 0.0);
        assert_eq!(wh[[5, 7]], 0.0);
        assert!(wh.iter().all(|v| v.is_finite() && *v >= 0.0));
    }

    #[test]
    fn weights_are_the_same_bits_for_any_thread_count() {
        let c = camera();
        let d = plane(2.5, 0.7);
        let run = |n: usize| {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(n).build().unwrap();
            pool.install(|| fusion_weights(d.view(), None, &c, FusionWeight::AngleDistance))
        };
        let one = run(1);
        for n in [2, 3, 8] {
            assert!(run(n).iter().zip(one.iter()).all(|(a, b)| a.to_bits() == b.to_bits()));
        }
    }
}
