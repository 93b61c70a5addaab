//! How well a keyframe's depth can be triangulated at all (SPEC.md §16.11): per pixel, the largest
//! angle under which the keyframe's live cameras see its estimated point, and the keyframe's median.
//! A camera that turns on the spot sees every point under a fraction of a degree, where no matcher
//! can fix depth to a few per cent; `map` reports the angle per keyframe and warns below
//! [`MIN_TRIANGULATION_DEG`].

use nalgebra::{Point3, Vector3};
use rayon::prelude::*;

use crate::geometry::{PinholeCamera, Pose};
use crate::image::{is_valid_depth, DepthMap};

/// Below this median triangulation angle (degrees, the median over keyframes of each keyframe's
/// median) `map` warns that the motion is rotation-dominant. Every hand-held validation keyframe is
/// above 1.4°, every keyframe of the rendered turning scenes below 0.6° (docs/map/results.md).
pub const MIN_TRIANGULATION_DEG: f64 = 1.0;

/// The angle (degrees) between the rays from `a` and from `b` to `x`; 0 when either has no length.
#[inline]
fn angle_deg(x: &Vector3<f64>, a: &Vector3<f64>, b: &Vector3<f64>) -> f64 {
    let (u, v) = (x - a, x - b);
    let den = u.norm() * v.norm();
    if den > 0.0 {
        (u.dot(&v) / den).clamp(-1.0, 1.0).acos().to_degrees()
    } else {
        0.0
    }
}

/// Per valid pixel of `depth` (camera `camera`, camera-to-world `pose`), the largest angle between
/// the ray from the keyframe's centre and the ray from any of `live_centres` (world) to its point;
/// the median over those pixels (the lower middle of the sorted angles), or `None` without a valid
/// pixel or a live centre. The same for any thread count (each pixel's angle is its own; the sort
/// is total).
pub fn median_triangulation_angle(
    depth: &DepthMap,
    camera: &PinholeCamera,
    pose: &Pose,
    live_centres: &[Vector3<f64>],
) -> Option<f64> {
    if live_centres.is_empty() {
        return None;
    }
    let centre = pose.translation.vector;
    let w = depth.ncols();
    let standard = depth.as_standard_layout();
    let angles: Vec<f64> = standard
        .as_slice()
        .expect("standard layout")
        .par_iter()
        .enumerate()
        .filter(|(_, &z)| is_valid_depth(z))
        .map(|(i, &z)| {
            let (y, x) = (i / w, i % w);
            let p = (pose * Point3::from(camera.ray(x as f64, y as f64) * z as f64)).coords;
            live_centres.iter().map(|c| angle_deg(&p, &centre, c)).fold(0.0, f64::max)
        })
        .collect();
    lower_median(angles)
}

/// The median of the keyframes' medians (lower middle), over those that have one.
pub fn median_over_keyframes(per_keyframe: &[Option<f64>]) -> Option<f64> {
    lower_median(per_keyframe.iter().flatten().copied().collect())
}

/// The lower middle of `v` sorted by `f64::total_cmp`; `None` when empty.
fn lower_median(mut v: Vec<f64>) -> Option<f64> {
    if v.is_empty() {
        return None;
    }
    v.sort_by(f64::total_cmp);
    Some(v[(v.len() - 1) / 2])
}
