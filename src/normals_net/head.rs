//! The normal head and its loss (SPEC.md §13.11): a 3x3 convolution `C -> 3` on the aggregated
//! features, the output normalised per pixel and oriented towards the camera, and the angular loss
//! `1 - cos` against ground-truth normals with its gradient.
//!
//! Symbols: `r` the head's raw output at a pixel, `d = K_l⁻¹ũ` the pixel's ray at the head's level
//! `l`, `s = -1` if `rᵀd > 0` else `+1`, `n = s r / ‖r‖` the prediction, `g` the ground-truth unit
//! normal. Per pixel `ℓ = 1 - nᵀg`, `∂ℓ/∂r = -s (g - (r̂ᵀg) r̂) / ‖r‖` (`s` is piecewise constant:
//! its kink, `rᵀd = 0`, is a set of measure zero) where `‖r‖ >= τ`; below the floor `τ` (the
//! trainer's [`RAW_NORM_FLOOR`], 0 for none) `ℓ = 1 - s rᵀg / τ`, `∂ℓ/∂r = -s g / τ` (the same
//! value at the floor; a bounded gradient). The loss is the mean of `ℓ` over the pixels with a ground-truth
//! normal and `r ≠ 0`; the reported angle is always that of the unit `n`.
//!
//! Two implementations share the per-pixel maths ([`pixel_terms`], f64): the fast one runs the
//! convolution and its backward passes with the network's f32 kernels ([`head_forward`],
//! [`head_backward`]); the reference runs them in f64 from the definition ([`head_forward_reference`],
//! [`head_backward_reference`]). The loss sums run over pixels in row-major order, serially.

use ndarray::{Array3, Array4, ArrayView1, ArrayView3, ArrayView4};

use crate::error::Result;
use crate::geometry::PinholeCamera;
use crate::ops::conv2d::{
    conv2d, conv2d_backward_input_reference, conv2d_backward_input_with, conv2d_backward_weight,
    conv2d_backward_weight_reference, Conv2dImpl,
};
use crate::ops::LayerParams;
use crate::ops::{Activation, Conv2dGeometry};

/// What one pixel contributes to the loss.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PixelTerms {
    /// `1 - nᵀg`.
    pub loss: f64,
    /// The angle between `n` and `g`, degrees.
    pub angle_deg: f64,
    /// `∂ℓ/∂r`.
    pub d_raw: [f64; 3],
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// The pixel's ray `K⁻¹ũ = ((x - c_x)/f_x, (y - c_y)/f_y, 1)` on `camera`'s grid.
pub fn ray(camera: &PinholeCamera, x: usize, y: usize) -> [f64; 3] {
    [(x as f64 - camera.cx) / camera.fx, (y as f64 - camera.cy) / camera.fy, 1.0]
}

/// `r / ‖r‖` oriented towards the camera (`nᵀd <= 0`), with the sign `s` used and `‖r‖`; `None`
/// when `r` is zero or not finite.
pub fn orient(r: [f64; 3], d: [f64; 3]) -> Option<([f64; 3], f64, f64)> {
    let norm = dot(r, r).sqrt();
    if !(norm > 0.0 && norm.is_finite()) {
        return None;
    }
    let s = if dot(r, d) > 0.0 { -1.0 } else { 1.0 };
    Some(([s * r[0] / norm, s * r[1] / norm, s * r[2] / norm], s, norm))
}

/// The training default of the raw-output norm below which the loss is linear in `r` (module docs,
/// SPEC.md §13.11; `train-normals --raw-norm-floor`). It is in the units of the head's output: with
/// the shipped trunk `‖r‖` has a median near 160 and 0.1 % of the pixels below 11, down to 0.8 (the
/// first 2 800 steps of a run); `∂ℓ/∂r` grows as `1/‖r‖`, so without a floor a few such pixels
/// dominated a batch's gradient (global norms up to 160 against 2-4), and two runs collapsed
/// (2026-12-03: at step ~600 with lr 3e-4, ~1400 with 1e-4). The floor bounds one pixel's gradient
/// at about 16 times a median pixel's.
pub const RAW_NORM_FLOOR: f64 = 10.0;

/// One pixel's loss, angle and gradient with floor `floor` (module docs; 0: none); `None` when `g`
/// is not a finite non-zero vector (no ground truth) or `r` is zero.
pub fn pixel_terms(r: [f64; 3], d: [f64; 3], g: [f64; 3], floor: f64) -> Option<PixelTerms> {
    if g.iter().any(|v| !v.is_finite()) || dot(g, g) == 0.0 {
        return None;
    }
    let (n, s, norm) = orient(r, d)?;
    let cos = dot(n, g);
    let angle_deg = cos.clamp(-1.0, 1.0).acos().to_degrees();
    if norm < floor {
        let d_raw = std::array::from_fn(|k| -s * g[k] / floor);
        return Some(PixelTerms { loss: 1.0 - s * dot(r, g) / floor, angle_deg, d_raw });
    }
    let unit = [r[0] / norm, r[1] / norm, r[2] / norm];
    let along = dot(unit, g);
    let d_raw = std::array::from_fn(|k| -s * (g[k] - along * unit[k]) / norm);
    Some(PixelTerms { loss: 1.0 - cos, angle_deg, d_raw })
}

/// Sums of a loss evaluation.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct NormalLossSums {
    /// Pixels with a ground-truth normal and a non-zero prediction.
    pub pixels: usize,
    /// `Σ (1 - cos)`.
    pub loss: f64,
    /// `Σ angle`, degrees.
    pub angle_deg: f64,
}

impl NormalLossSums {
    /// Mean loss (0 without pixels).
    pub fn mean(&self) -> f64 {
        self.loss / self.pixels.max(1) as f64
    }
    /// Mean angular error, degrees (NaN without pixels).
    pub fn mean_angle_deg(&self) -> f64 {
        if self.pixels == 0 {
            f64::NAN
        } else {
            self.angle_deg / self.pixels as f64
        }
    }
    /// `self += other`.
    pub fn accumulate(&mut self, other: &NormalLossSums) {
        self.pixels += other.pixels;
        self.loss += other.loss;
        self.angle_deg += other.angle_deg;
    }
}

/// The loss of raw head outputs `raw [h, w, 3]` against ground-truth normals `gt [h, w, 3]` (NaN:
/// none) on `camera`'s grid with [`pixel_terms`]'s `floor`, and the gradient of `weight · mean ℓ`
/// with respect to `raw` (f64). Pixels in row-major order, serially.
///
/// # Errors
/// [`crate::Error::InvalidArgument`] if the shapes disagree with each other or the camera.
pub fn normal_loss_f64<T: Copy + Into<f64>>(
    raw: ArrayView3<T>,
    gt: ArrayView3<f32>,
    camera: &PinholeCamera,
    weight: f64,
    floor: f64,
) -> Result<(NormalLossSums, Array3<f64>)> {
    let (h, w, c) = raw.dim();
    crate::ops::expect_shape("normal loss gt", gt.shape(), &[h, w, 3])?;
    crate::ops::expect_shape("normal loss raw", &[h, w, c], &[camera.height, camera.width, 3])?;
    let mut sums = NormalLossSums::default();
    let mut grad = Array3::<f64>::zeros((h, w, 3));
    for y in 0..h {
        for x in 0..w {
            let r = std::array::from_fn(|k| raw[[y, x, k]].into());
            let g = std::array::from_fn(|k| f64::from(gt[[y, x, k]]));
            let Some(t) = pixel_terms(r, ray(camera, x, y), g, floor) else { continue };
            sums.pixels += 1;
            sums.loss += t.loss;
            sums.angle_deg += t.angle_deg;
            for k in 0..3 {
                grad[[y, x, k]] = t.d_raw[k];
            }
        }
    }
    let scale = weight / sums.pixels.max(1) as f64;
    grad.mapv_inplace(|v| v * scale);
    Ok((sums, grad))
}

/// [`normal_loss_f64`] on f32 head outputs with the gradient rounded to f32 (the fast path).
///
/// # Errors
/// As [`normal_loss_f64`].
pub fn normal_loss(
    raw: ArrayView3<f32>,
    gt: ArrayView3<f32>,
    camera: &PinholeCamera,
    weight: f64,
    floor: f64,
) -> Result<(NormalLossSums, Array3<f32>)> {
    let (sums, grad) = normal_loss_f64(raw, gt, camera, weight, floor)?;
    Ok((sums, grad.mapv(|v| v as f32)))
}

/// Oriented unit normals of raw head outputs on `camera`'s grid (NaN where `r` is zero).
pub fn unit_normals(raw: ArrayView3<f32>, camera: &PinholeCamera) -> Array3<f32> {
    let (h, w, _) = raw.dim();
    let mut out = Array3::from_elem((h, w, 3), f32::NAN);
    for y in 0..h {
        for x in 0..w {
            let r = std::array::from_fn(|k| f64::from(raw[[y, x, k]]));
            if let Some((n, _, _)) = orient(r, ray(camera, x, y)) {
                for k in 0..3 {
                    out[[y, x, k]] = n[k] as f32;
                }
            }
        }
    }
    out
}

fn head_geometry(features: (usize, usize, usize), head: (usize, usize)) -> Result<Conv2dGeometry> {
    Conv2dGeometry::new(features.0, features.1, features.2, head.0, 1).and_then(|g| {
        crate::ops::expect_shape("head weight", &[head.0, head.1, 3, 3], &g.weight_shape())?;
        Ok(g)
    })
}

/// The head's raw output `[h, w, 3]`: 3x3 convolution, zero padding 1, stride 1, bias, linear, by
/// [`Conv2dImpl::fastest_for`] its geometry.
///
/// # Errors
/// [`crate::Error::InvalidArgument`] if the head does not fit the features.
pub fn head_forward(head: &LayerParams, features: ArrayView3<f32>) -> Result<Array3<f32>> {
    let s = head.weight.shape();
    let g = head_geometry(features.dim(), (s[0], s[1]))?;
    conv2d(Conv2dImpl::fastest_for(&g), &g, features, head.weight.view(), head.bias.view(), Activation::None)
}

/// [`head_forward`] in f64 from the definition (SPEC.md §7.2's sum, zero outside the map).
///
/// # Errors
/// As [`head_forward`].
pub fn head_forward_reference(
    weight: ArrayView4<f64>,
    bias: ArrayView1<f64>,
    features: ArrayView3<f64>,
) -> Result<Array3<f64>> {
    let (c_out, c_in, _, _) = weight.dim();
    let g = head_geometry(features.dim(), (c_out, c_in))?;
    let (h, w) = (g.h(), g.w());
    Ok(Array3::from_shape_fn((h, w, c_out), |(y, x, o)| {
        let mut acc = bias[o];
        for ky in 0..3 {
            for kx in 0..3 {
                let (Some(iy), Some(ix)) = ((y + ky).checked_sub(1), (x + kx).checked_sub(1)) else {
                    continue;
                };
                if iy >= h || ix >= w {
                    continue;
                }
                for c in 0..c_in {
                    acc += weight[[o, c, ky, kx]] * features[[iy, ix, c]];
                }
            }
        }
        acc
    }))
}

/// Gradients of the head: with respect to the features (the trunk's `d_features`), and the head's
/// weight and bias, from `d_raw` (the network's deterministic f32 backward kernels, SPEC.md §7.8).
///
/// # Errors
/// As [`head_forward`].
pub fn head_backward(
    head: &LayerParams,
    features: ArrayView3<f32>,
    d_raw: ArrayView3<f32>,
) -> Result<(Array3<f32>, LayerParams)> {
    let s = head.weight.shape();
    let g = head_geometry(features.dim(), (s[0], s[1]))?;
    let d_features = conv2d_backward_input_with(Conv2dImpl::fastest_for(&g), &g, d_raw, head.weight.view())?;
    let (weight, bias) = conv2d_backward_weight(&g, features, d_raw)?;
    Ok((d_features, LayerParams { weight, bias }))
}

/// [`head_backward`] in f64 (the §7.8 oracles): `(d_features, d_weight, d_bias)`.
///
/// # Errors
/// As [`head_forward`].
pub fn head_backward_reference(
    weight: ArrayView4<f64>,
    features: ArrayView3<f64>,
    d_raw: ArrayView3<f64>,
) -> Result<(Array3<f64>, Array4<f64>, ndarray::Array1<f64>)> {
    let (c_out, c_in, _, _) = weight.dim();
    let g = head_geometry(features.dim(), (c_out, c_in))?;
    let d_features = conv2d_backward_input_reference(&g, d_raw, weight)?;
    let (d_w, d_b) = conv2d_backward_weight_reference(&g, features, d_raw)?;
    Ok((d_features, d_w, d_b))
}
