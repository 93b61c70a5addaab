//! The photometric warp check: warp a target frame into a reference frame with the reference's
//! ground-truth depth and the two poses, and compare the mean absolute grey-level error with the
//! error of no warp at all (identity). Correct intrinsics, pose direction, depth scale and pixel
//! convention make the warped error several times smaller; any one of them wrong does not.

use crate::error::{Error, Result};
use crate::geometry::{relative_pose, Warp};
use crate::image::{is_valid_depth, sample_bilinear, to_gray};
use crate::sequence::Frame;

/// Result of [`photometric_warp_check`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct WarpCheck {
    /// Mean |I_ref(u) - I_tgt(warp(u))| over pixels with valid depth that land inside the target.
    pub warped_error: f64,
    /// Mean |I_ref(u) - I_tgt(u)| over the same pixels.
    pub identity_error: f64,
    /// Mean |I_ref(u) - (a I_tgt(warp(u)) + b)| after the least-squares affine brightness fit
    /// `(a, b)` over the same pixels: what remains once exposure / gain changes are explained.
    pub affine_error: f64,
    /// The fitted brightness transfer `(a, b)`.
    pub affine: (f64, f64),
    /// Number of pixels compared.
    pub pixels: usize,
    /// Fraction of reference pixels with valid depth whose warp lands inside the target.
    pub in_view: f64,
}

impl WarpCheck {
    /// `identity_error / warped_error`: how many times better the warp is than no warp.
    pub fn gain(&self) -> f64 {
        self.identity_error / self.warped_error.max(1e-12)
    }
}

/// Warp `target` into `reference` (each in its own [`Frame::camera`]) using the reference's depth
/// and both poses. The identity error compares the same pixel position in both images (where the
/// target has it).
///
/// # Errors
/// [`Error::InvalidArgument`] if the reference has no depth or no pixel lands in the target.
pub fn photometric_warp_check(reference: &Frame, target: &Frame) -> Result<WarpCheck> {
    let depth = reference.depth.as_ref().ok_or_else(|| {
        Error::invalid_argument("reference frame", format!("frame {} has no depth", reference.index))
    })?;
    let warp = Warp::new(&reference.camera, &target.camera, &relative_pose(&reference.pose, &target.pose));
    let (g_ref, g_tgt) = (to_gray(&reference.rgb), to_gray(&target.rgb));
    let g_tgt3 = g_tgt.view().insert_axis(ndarray::Axis(2));
    let (mut sum_w, mut sum_i, mut n, mut n_depth) = (0.0f64, 0.0f64, 0usize, 0usize);
    let mut pairs: Vec<(f64, f64)> = Vec::new();
    let mut s = [0.0f32];
    for ((y, x), &z) in depth.indexed_iter() {
        if !is_valid_depth(z) {
            continue;
        }
        n_depth += 1;
        let Some(w) = warp.apply(x as f64, y as f64, 1.0 / z as f64) else { continue };
        if !sample_bilinear(&g_tgt3, w.uv.x, w.uv.y, &mut s) {
            continue;
        }
        let r = g_ref[[y, x]];
        sum_w += (r - s[0]).abs() as f64;
        sum_i += (r - g_tgt.get((y, x)).copied().unwrap_or(r)).abs() as f64;
        pairs.push((r as f64, s[0] as f64));
        n += 1;
    }
    if n == 0 {
        return Err(Error::invalid_argument(
            "frame pair",
            format!(
                "no pixel of frame {} with valid depth lands inside frame {}",
                reference.index, target.index
            ),
        ));
    }
    let (a, b) = affine_fit(&pairs);
    let affine_error = pairs.iter().map(|&(r, s)| (r - (a * s + b)).abs()).sum::<f64>() / n as f64;
    Ok(WarpCheck {
        warped_error: sum_w / n as f64,
        affine_error,
        affine: (a, b),
        identity_error: sum_i / n as f64,
        pixels: n,
        in_view: n as f64 / n_depth as f64,
    })
}

/// Least-squares `(a, b)` minimising `Σ (r - (a s + b))²`; `(1, 0)` when `s` is constant.
fn affine_fit(pairs: &[(f64, f64)]) -> (f64, f64) {
    let n = pairs.len() as f64;
    let (mr, ms) = pairs.iter().fold((0.0, 0.0), |(ar, as_), &(r, s)| (ar + r, as_ + s));
    let (mr, ms) = (mr / n, ms / n);
    let (mut sss, mut srs) = (0.0, 0.0);
    for &(r, s) in pairs {
        sss += (s - ms) * (s - ms);
        srs += (s - ms) * (r - mr);
    }
    if sss <= f64::EPSILON * n {
        return (1.0, mr - ms);
    }
    let a = srs / sss;
    (a, mr - a * ms)
}
