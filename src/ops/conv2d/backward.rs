//! Backward passes of the 3x3 convolution (SPEC.md §7.8), without its activation: the ReLU's
//! backward is the separate elementwise [`relu_backward`].
//!
//! With `out[y, x, o] = b[o] + Σ_{c, ky, kx} w[o, c, ky, kx] · in[s y + ky - 1, s x + kx - 1, c]` and
//! an upstream gradient `g = dL/d out` (`[h_out, w_out, c_out]`):
//!
//! ```text
//! d_in[iy, ix, c]        = Σ_{o, ky, kx : iy = s y + ky - 1, ix = s x + kx - 1} w[o, c, ky, kx] · g[y, x, o]
//! d_w[o, c, ky, kx]      = Σ_{y, x} g[y, x, o] · in[s y + ky - 1, s x + kx - 1, c]   (in = 0 outside)
//! d_b[o]                 = Σ_{y, x} g[y, x, o]
//! ```
//!
//! The `*_reference` functions are plain loops in f64 (the oracles, checked against central finite
//! differences of [`conv2d_reference`](super::conv2d_reference)); the fast f32 versions are in
//! [`super::backward_fast`].

use ndarray::{Array1, Array3, Array4, ArrayView, ArrayView3, ArrayView4, Dimension};

use crate::error::Result;
use crate::ops::expect_shape;
use crate::ops::geometry::{Conv2dGeometry, CONV_KERNEL, CONV_PADDING};

/// Input pixel read by output pixel `j` through tap `k` along one axis: `s j + k - 1`, or `None`
/// in the zero padding.
pub(super) fn tap_source(j: usize, k: usize, s: usize, n: usize) -> Option<usize> {
    (s * j + k).checked_sub(CONV_PADDING).filter(|&i| i < n)
}

/// Output pixel that reads input pixel `i` through tap `k` along one axis: the `j` with
/// `s j + k - 1 = i`, if it exists in `0..n_out`.
pub(super) fn tap_target(i: usize, k: usize, s: usize, n_out: usize) -> Option<usize> {
    let t = (i + CONV_PADDING).checked_sub(k)?;
    (t % s == 0 && t / s < n_out).then_some(t / s)
}

/// Gradient with respect to the input, in f64, straight from the definition: every output
/// gradient `g[y, x, o]` adds `w[o, c, ky, kx] · g[y, x, o]` to `d_in[s y + ky - 1, s x + kx - 1, c]`
/// when that input pixel exists (a scatter, the transpose of [`conv2d_reference`](super::conv2d_reference)).
///
/// # Shapes
/// `d_out [h_out, w_out, c_out]`, `weight [c_out, c_in, 3, 3]`, result `[h, w, c_in]`.
///
/// # Errors
/// [`crate::Error::InvalidArgument`] if an array's shape disagrees with `geom`.
pub fn conv2d_backward_input_reference(
    geom: &Conv2dGeometry,
    d_out: ArrayView3<f64>,
    weight: ArrayView4<f64>,
) -> Result<Array3<f64>> {
    expect_shape("conv2d_backward d_out", d_out.shape(), &geom.output_shape())?;
    expect_shape("conv2d_backward weight", weight.shape(), &geom.weight_shape())?;
    let [h_out, w_out, c_out] = geom.output_shape();
    let s = geom.stride();
    let mut d_in = Array3::zeros(geom.input_shape());
    for y in 0..h_out {
        for x in 0..w_out {
            for o in 0..c_out {
                let g = d_out[[y, x, o]];
                for ky in 0..CONV_KERNEL {
                    for kx in 0..CONV_KERNEL {
                        let iy = tap_source(y, ky, s, geom.h());
                        let ix = tap_source(x, kx, s, geom.w());
                        let (Some(iy), Some(ix)) = (iy, ix) else { continue };
                        for c in 0..geom.c_in() {
                            d_in[[iy, ix, c]] += weight[[o, c, ky, kx]] * g;
                        }
                    }
                }
            }
        }
    }
    Ok(d_in)
}

/// Gradients with respect to the weight and the bias, in f64, straight from the definition:
/// `d_w[o, c, ky, kx] = Σ_{y, x} g[y, x, o] · in[s y + ky - 1, s x + kx - 1, c]` (zero padding) and
/// `d_b[o] = Σ_{y, x} g[y, x, o]`.
///
/// # Shapes
/// `input [h, w, c_in]`, `d_out [h_out, w_out, c_out]`, results `[c_out, c_in, 3, 3]` and `[c_out]`.
///
/// # Errors
/// [`crate::Error::InvalidArgument`] if an array's shape disagrees with `geom`.
pub fn conv2d_backward_weight_reference(
    geom: &Conv2dGeometry,
    input: ArrayView3<f64>,
    d_out: ArrayView3<f64>,
) -> Result<(Array4<f64>, Array1<f64>)> {
    expect_shape("conv2d_backward input", input.shape(), &geom.input_shape())?;
    expect_shape("conv2d_backward d_out", d_out.shape(), &geom.output_shape())?;
    let [h_out, w_out, c_out] = geom.output_shape();
    let s = geom.stride();
    let mut d_w = Array4::zeros(geom.weight_shape());
    let mut d_b = Array1::zeros(c_out);
    for y in 0..h_out {
        for x in 0..w_out {
            for o in 0..c_out {
                let g = d_out[[y, x, o]];
                d_b[o] += g;
                for ky in 0..CONV_KERNEL {
                    for kx in 0..CONV_KERNEL {
                        let iy = tap_source(y, ky, s, geom.h());
                        let ix = tap_source(x, kx, s, geom.w());
                        let (Some(iy), Some(ix)) = (iy, ix) else { continue };
                        for c in 0..geom.c_in() {
                            d_w[[o, c, ky, kx]] += g * input[[iy, ix, c]];
                        }
                    }
                }
            }
        }
    }
    Ok((d_w, d_b))
}

/// Backward of the ReLU, elementwise: `d_pre = d_out` where `activation > 0`, else `0`.
///
/// `activation` may be either the pre-activation `z` or the ReLU's output `max(0, z)`: both are
/// positive exactly where `z > 0`, so the mask is the same. At `z = 0` the gradient is `0`, as in
/// PyTorch (`d/dz relu(z) = 0` at `z = 0`); a NaN activation also gives `0`.
///
/// # Errors
/// [`crate::Error::InvalidArgument`] if the shapes differ.
pub fn relu_backward<D: Dimension>(
    activation: ArrayView<f32, D>,
    d_out: ArrayView<f32, D>,
) -> Result<ndarray::Array<f32, D>> {
    expect_shape("relu_backward d_out", d_out.shape(), activation.shape())?;
    Ok(ndarray::Zip::from(&activation).and(&d_out).map_collect(|&a, &g| if a > 0.0 { g } else { 0.0 }))
}
