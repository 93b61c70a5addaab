//! Keyframe selection along a sequence and each keyframe's window (SPEC.md §16.8).
//!
//! **View overlap** `O(a, b)`: the fraction of a 16x12 grid of frame `a`'s pixels (cell centres)
//! that, back-projected at the nominal depth `z_0` and seen from frame `b`, lands inside `b`'s
//! image in front of it. **Rule**: the first frame of the range is a keyframe; a later frame `i`
//! becomes one when, against the last keyframe `k`, the baseline `‖c_i - c_k‖ >= baseline` or
//! `O(k, i) < overlap`. **Window**: from the keyframe outwards on each side, frames are taken while
//! `O(keyframe, j) >= window_overlap`, within the frame range and at most `past` / `future`
//! frames; if that leaves none, the nearer neighbour in the range is taken alone.

use serde::Serialize;

use crate::error::{Error, Result};
use crate::geometry::{PinholeCamera, Pose};

/// Grid of sample pixels for the overlap, columns x rows.
const OVERLAP_GRID: (usize, usize) = (16, 12);

/// The keyframe rule's parameters.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct KeyframeRule {
    /// A frame this far (metres) from the last keyframe's centre becomes a keyframe.
    pub baseline: f64,
    /// A frame whose view overlap with the last keyframe falls below this becomes a keyframe.
    pub overlap: f64,
    /// Depth at which overlaps are measured, metres.
    pub nominal_depth: f64,
    /// Live frames need at least this overlap with their keyframe.
    pub window_overlap: f64,
}

impl Default for KeyframeRule {
    fn default() -> Self {
        Self { baseline: 0.1, overlap: 0.7, nominal_depth: 2.0, window_overlap: 0.5 }
    }
}

impl KeyframeRule {
    /// Check every field.
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] naming the flag.
    pub fn validate(&self) -> Result<()> {
        let bad = |flag: &str, v: f64, want: &str| {
            Err(Error::invalid_argument(flag, format!("{v}: must be {want}")))
        };
        if !(self.baseline.is_finite() && self.baseline > 0.0) {
            return bad("--kf-baseline", self.baseline, "a finite distance > 0 (metres)");
        }
        if !(0.0..=1.0).contains(&self.overlap) {
            return bad("--kf-overlap", self.overlap, "a fraction in [0, 1]");
        }
        if !(self.nominal_depth.is_finite() && self.nominal_depth > 0.0) {
            return bad("--kf-depth", self.nominal_depth, "a finite depth > 0 (metres)");
        }
        if !(0.0..=1.0).contains(&self.window_overlap) {
            return bad("--window-overlap", self.window_overlap, "a fraction in [0, 1]");
        }
        Ok(())
    }
}

/// View overlap `O(a, b)` at depth `depth` (module docs).
pub fn view_overlap(camera: &PinholeCamera, t_wa: &Pose, t_wb: &Pose, depth: f64) -> f64 {
    let t_ba = t_wb.inverse() * t_wa;
    let (gx, gy) = OVERLAP_GRID;
    let mut inside = 0;
    for j in 0..gy {
        for i in 0..gx {
            let u = (i as f64 + 0.5) * camera.width as f64 / gx as f64 - 0.5;
            let v = (j as f64 + 0.5) * camera.height as f64 / gy as f64 - 0.5;
            let p = t_ba * nalgebra::Point3::from(camera.ray(u, v) * depth);
            if let Some(q) = camera.project(&p.coords) {
                inside += usize::from(camera.contains(q.x, q.y));
            }
        }
    }
    inside as f64 / (gx * gy) as f64
}

/// Keyframes of `frames` (indices into `poses`, in order) by the rule (module docs).
pub fn select_keyframes(
    camera: &PinholeCamera,
    poses: &[Pose],
    frames: &[usize],
    rule: &KeyframeRule,
) -> Vec<usize> {
    let mut out: Vec<usize> = Vec::new();
    for &i in frames {
        let take = match out.last() {
            None => true,
            Some(&k) => {
                let baseline = (poses[i].translation.vector - poses[k].translation.vector).norm();
                baseline >= rule.baseline
                    || view_overlap(camera, &poses[k], &poses[i], rule.nominal_depth) < rule.overlap
            }
        };
        if take {
            out.push(i);
        }
    }
    out
}

/// `(past, future)` live frames of keyframe `key` inside the inclusive range `[first, last]`, at
/// most `max_past` / `max_future` (module docs). `(0, 0)` only for a one-frame range.
pub fn keyframe_window(
    camera: &PinholeCamera,
    poses: &[Pose],
    key: usize,
    (first, last): (usize, usize),
    (max_past, max_future): (usize, usize),
    rule: &KeyframeRule,
) -> (usize, usize) {
    let ok =
        |j: usize| view_overlap(camera, &poses[key], &poses[j], rule.nominal_depth) >= rule.window_overlap;
    let past = (1..=max_past).take_while(|&d| key >= first + d && ok(key - d)).count();
    let future = (1..=max_future).take_while(|&d| key + d <= last && ok(key + d)).count();
    if past + future > 0 {
        return (past, future);
    }
    if key < last && max_future > 0 {
        (0, 1)
    } else if key > first && max_past > 0 {
        (1, 0)
    } else if key < last {
        (0, 1)
    } else {
        (usize::from(key > first), 0)
    }
}
