//! Optional online photometric calibration of a keyframe's window (SPEC.md §11.9): per live frame
//! an affine brightness change relative to the keyframe (exposure, gain, offset), fitted from a
//! coarse first pass, applied to the live images before their features are extracted.
//!
//! Model: frame `i` records `I_i = g_i L + b_i` for scene radiance `L`, so at corresponding pixels
//! `I_r(x) = a_i I_i(y) - e_i` with `a_i = g_r / g_i`, `e_i = a_i b_i - b_r`. The corrected live
//! image is `a_i I_i - e_i`; the keyframe is unchanged.
//!
//! Fit ([`fit`]): a coarse RGB cost volume (level `L + 2`, at least 48 px wide, [`COARSE_BINS`]
//! bins, evidence minimum 0.25) over the same window gives a winner-take-all inverse depth; every
//! valid coarse pixel is warped into every live frame and its three colour pairs (both values in
//! [`VALID`], away from clipping) enter a Huber (`δ` = [`HUBER`] grey levels) fit of `(a_i, e_i)` by
//! [`IRLS`] iterations of reweighted least squares ([`fit_from_depth`]). [`ROUNDS`] rounds: the next
//! round's coarse volume is built from the corrected live images. Pairs are gathered per frame in
//! row-major order and every sum runs in that order in `f64`, so the fit does not depend on the
//! thread count.

use std::borrow::Cow;

use ndarray::{Array2, ArrayView2, ArrayView3};
use rayon::prelude::*;
use serde::Serialize;

use crate::costvolume::{filter_evidence, winner_take_all_costs, CostVolume};
use crate::error::{Error, Result};
use crate::geometry::{relative_pose, InverseDepthBins, PinholeCamera, Pose, Warp};
use crate::image::{sample_bilinear, RgbImage};

/// Which photometric correction runs before matching.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub enum PhotometricMode {
    /// Raw colour (DTAM's brightness constancy).
    None,
    /// Per-frame affine brightness relative to the keyframe.
    Affine,
}

impl std::str::FromStr for PhotometricMode {
    type Err = Error;

    /// `none` or `affine`.
    fn from_str(s: &str) -> Result<Self> {
        match s {
            "none" => Ok(Self::None),
            "affine" => Ok(Self::Affine),
            _ => Err(Error::invalid_argument("--photometric", format!("{s:?}: expected none or affine"))),
        }
    }
}

/// The fitted correction of one window.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct PhotometricFit {
    /// Per live frame (window order): `(a_i, e_i)`; the corrected image is `a_i I - e_i`.
    pub frames: Vec<(f64, f64)>,
    /// Colour pairs used in the last round.
    pub pairs: usize,
}

impl PhotometricFit {
    /// The identity (no correction) for `n` frames.
    pub fn identity(n: usize) -> Self {
        Self { frames: vec![(1.0, 0.0); n], pairs: 0 }
    }

    /// Live frame `i`'s (window order) corrected colour `a_i I - e_i`, computed in `f64` and rounded
    /// to `f32` per value; the image itself (no copy) for the identity `(1, 0)`, which that formula
    /// maps to the same bits.
    ///
    /// # Panics
    /// If `i` is not a frame of the fit.
    pub fn correct_live<'a>(&self, i: usize, rgb: &'a RgbImage) -> Cow<'a, RgbImage> {
        match self.frames[i] {
            (1.0, 0.0) => Cow::Borrowed(rgb),
            (a, e) => Cow::Owned(rgb.mapv(|v| (a * f64::from(v) - e) as f32)),
        }
    }
}

/// Huber threshold, grey levels.
pub const HUBER: f64 = 4.0;
/// Colour values outside this range are treated as clipped and not fitted.
pub const VALID: std::ops::RangeInclusive<f32> = 8.0..=247.0;
/// Bins of the coarse volume.
pub const COARSE_BINS: usize = 64;
/// IRLS iterations per fit.
pub const IRLS: usize = 6;
/// Coarse pass + fit rounds.
pub const ROUNDS: usize = 2;

/// The level the fit runs on for output level `level`: `level + 2`, or finer while that grid would
/// be under 48 px wide.
pub fn coarse_level(camera: &PinholeCamera, level: u32) -> u32 {
    let mut lc = level + 2;
    while lc > level && camera.at_level(lc).width < 48 {
        lc -= 1;
    }
    lc
}

/// Fit the window's correction. `key` is the keyframe's colour and pose, `live` the live frames'
/// colour, pose and full-resolution camera (window order), the images already at level `lc` =
/// [`coarse_level`] of the keyframe's full-resolution `camera`.
///
/// # Errors
/// Cost-volume and image-shape errors (none for a consistent sequence).
pub fn fit(
    key: (&RgbImage, &Pose),
    live: &[(RgbImage, Pose, PinholeCamera)],
    camera: &PinholeCamera,
    bins: &InverseDepthBins,
    lc: u32,
) -> Result<PhotometricFit> {
    let n = live.len();
    if n == 0 {
        return Ok(PhotometricFit::identity(0));
    }
    let cam = camera.at_level(lc);
    let key_c = key.0;
    let live_c: Vec<ArrayView3<f32>> = live.iter().map(|(rgb, _, _)| rgb.view()).collect();
    let poses: Vec<Pose> = live.iter().map(|(_, p, _)| relative_pose(key.1, p)).collect();
    let cams: Vec<PinholeCamera> = live.iter().map(|(_, _, c)| c.at_level(lc)).collect();
    let coarse_bins = InverseDepthBins::new(bins.rho_min, bins.rho_max, COARSE_BINS)?;
    let mut current = PhotometricFit::identity(n);
    for _ in 0..ROUNDS {
        let mut cv = CostVolume::new(key_c.clone(), cam, coarse_bins)?;
        for (i, ((img, _, _), pose)) in live.iter().zip(&poses).enumerate() {
            cv.add_frame_seen_by(current.correct_live(i, img).view(), &cams[i], pose)?;
        }
        let mut costs = cv.costs();
        filter_evidence(&mut costs, cv.counts_view(), 0.25);
        let wta = winner_take_all_costs(costs.view(), &coarse_bins);
        let views: Vec<_> = live_c.iter().zip(&cams).map(|(v, c)| (*v, *c)).collect();
        current =
            fit_from_depth(key_c.view(), &views, &poses, &cam, wta.inverse_depth.view(), wta.valid.view());
    }
    Ok(current)
}

/// The Huber IRLS fit of `(a_i, e_i)` per live frame from a keyframe inverse depth (`valid` pixels
/// with `ρ > 0`) on `camera`'s grid; `live[i]` is frame `i`'s image and its camera (at the same
/// level), `poses[i]` its `T_nr`. A frame with fewer than two distinct pairs keeps the identity.
pub fn fit_from_depth(
    key: ArrayView3<f32>,
    live: &[(ArrayView3<f32>, PinholeCamera)],
    poses: &[Pose],
    camera: &PinholeCamera,
    inverse_depth: ArrayView2<f32>,
    valid: ArrayView2<bool>,
) -> PhotometricFit {
    let frames: Vec<((f64, f64), usize)> = live
        .par_iter()
        .zip(poses)
        .map(|((img, live_camera), pose)| {
            let pairs = collect_pairs(key, *img, (camera, live_camera), pose, inverse_depth, valid);
            (fit_affine(&pairs), pairs.len())
        })
        .collect();
    PhotometricFit {
        pairs: frames.iter().map(|f| f.1).sum(),
        frames: frames.into_iter().map(|f| f.0).collect(),
    }
}

/// `(r, l)` colour pairs of one frame, row-major, channels innermost.
fn collect_pairs(
    key: ArrayView3<f32>,
    live: ArrayView3<f32>,
    (camera, live_camera): (&PinholeCamera, &PinholeCamera),
    t_nr: &Pose,
    inverse_depth: ArrayView2<f32>,
    valid: ArrayView2<bool>,
) -> Vec<(f64, f64)> {
    let warp = Warp::new(camera, live_camera, t_nr);
    let (h, w) = valid.dim();
    let mut out = Vec::new();
    let mut sample = [0.0f32; 3];
    for y in 0..h {
        for x in 0..w {
            let rho = inverse_depth[[y, x]];
            if !valid[[y, x]] || rho <= 0.0 {
                continue;
            }
            let Some(p) = warp.apply(x as f64, y as f64, f64::from(rho)) else { continue };
            if !sample_bilinear(&live, p.uv.x, p.uv.y, &mut sample) {
                continue;
            }
            for (ch, &l) in sample.iter().enumerate() {
                let r = key[[y, x, ch]];
                if VALID.contains(&r) && VALID.contains(&l) {
                    out.push((f64::from(r), f64::from(l)));
                }
            }
        }
    }
    out
}

/// Huber IRLS for `r ≈ a l - e`, starting from the identity.
fn fit_affine(pairs: &[(f64, f64)]) -> (f64, f64) {
    let (mut a, mut e) = (1.0, 0.0);
    for _ in 0..IRLS {
        // Weighted normal equations of the regressors (l, -1).
        let (mut sw, mut sl, mut sll, mut sr, mut slr) = (0.0, 0.0, 0.0, 0.0, 0.0);
        for &(r, l) in pairs {
            let res = a * l - e - r;
            let w = if res.abs() <= HUBER { 1.0 } else { HUBER / res.abs() };
            sw += w;
            sl += w * l;
            sll += w * l * l;
            sr += w * r;
            slr += w * l * r;
        }
        let det = sw * sll - sl * sl;
        if det.is_nan() || det <= 1e-9 * sw * sll {
            return (1.0, 0.0);
        }
        a = (sw * slr - sl * sr) / det;
        e = (sl * slr - sll * sr) / det;
    }
    (a, e)
}

/// The inverse depth of a depth map (0 where invalid) and its validity: the input of
/// [`fit_from_depth`] from ground truth.
pub fn inverse_depth_of(depth: ArrayView2<f32>) -> (Array2<f32>, Array2<bool>) {
    (depth.mapv(|z| if z > 0.0 { 1.0 / z } else { 0.0 }), depth.mapv(|z| z > 0.0))
}
