//! Backward passes of the 5x5 stride-2 transposed convolution (SPEC.md §7.8).
//!
//! With `out[2 iy - 2 + ky, 2 ix - 2 + kx, co] += in[iy, ix, ci] · w[ci, co, ky, kx]` (cropped to
//! `[2h, 2w]`), `out = b[co] + ...`, and an upstream gradient `g = dL/d out` (`[2h, 2w, c_out]`):
//!
//! ```text
//! d_in[iy, ix, ci]      = Σ_{co, ky, kx} w[ci, co, ky, kx] · g[2 iy - 2 + ky, 2 ix - 2 + kx, co]
//! d_w[ci, co, ky, kx]   = Σ_{iy, ix} in[iy, ix, ci] · g[2 iy - 2 + ky, 2 ix - 2 + kx, co]
//! d_b[co]               = Σ_{oy, ox} g[oy, ox, co]
//! ```
//!
//! (`g = 0` outside the output.) So the input gradient is exactly a 5x5, stride-2, padding-2
//! convolution (cross-correlation) of `g` with the weight read as `[ci, co, ky, kx]`. The
//! `*_reference` functions are plain loops in f64; the fast f32 versions are in
//! [`super::backward_fast`].

use ndarray::{Array1, Array3, Array4, ArrayView3, ArrayView4};

use crate::error::Result;
use crate::ops::expect_shape;
use crate::ops::geometry::{Deconv2dGeometry, DECONV_KERNEL, DECONV_PADDING, DECONV_STRIDE};

/// Output pixel `2 i - 2 + k` that input pixel `i` reaches through tap `k`, if inside `0..n_out`.
fn tap_target(i: usize, k: usize, n_out: usize) -> Option<usize> {
    (DECONV_STRIDE * i + k).checked_sub(DECONV_PADDING).filter(|&o| o < n_out)
}

/// Gradient with respect to the input, in f64, from the definition:
/// `d_in[iy, ix, ci] = Σ_{co, ky, kx} w[ci, co, ky, kx] · g[2 iy - 2 + ky, 2 ix - 2 + kx, co]`.
///
/// # Shapes
/// `d_out [2h, 2w, c_out]`, `weight [c_in, c_out, 5, 5]`, result `[h, w, c_in]`.
///
/// # Errors
/// [`crate::Error::InvalidArgument`] if an array's shape disagrees with `geom`.
pub fn deconv2d_backward_input_reference(
    geom: &Deconv2dGeometry,
    d_out: ArrayView3<f64>,
    weight: ArrayView4<f64>,
) -> Result<Array3<f64>> {
    expect_shape("deconv2d_backward d_out", d_out.shape(), &geom.output_shape())?;
    expect_shape("deconv2d_backward weight", weight.shape(), &geom.weight_shape())?;
    let [h_out, w_out, c_out] = geom.output_shape();
    let mut d_in = Array3::zeros(geom.input_shape());
    for iy in 0..geom.h() {
        for ix in 0..geom.w() {
            for ci in 0..geom.c_in() {
                let mut acc = 0.0;
                for ky in 0..DECONV_KERNEL {
                    for kx in 0..DECONV_KERNEL {
                        let oy = tap_target(iy, ky, h_out);
                        let ox = tap_target(ix, kx, w_out);
                        let (Some(oy), Some(ox)) = (oy, ox) else { continue };
                        for co in 0..c_out {
                            acc += weight[[ci, co, ky, kx]] * d_out[[oy, ox, co]];
                        }
                    }
                }
                d_in[[iy, ix, ci]] = acc;
            }
        }
    }
    Ok(d_in)
}

/// Gradients with respect to the weight and the bias, in f64, from the definition:
/// `d_w[ci, co, ky, kx] = Σ_{iy, ix} in[iy, ix, ci] · g[2 iy - 2 + ky, 2 ix - 2 + kx, co]`,
/// `d_b[co] = Σ_{oy, ox} g[oy, ox, co]`.
///
/// # Shapes
/// `input [h, w, c_in]`, `d_out [2h, 2w, c_out]`, results `[c_in, c_out, 5, 5]` and `[c_out]`.
///
/// # Errors
/// [`crate::Error::InvalidArgument`] if an array's shape disagrees with `geom`.
pub fn deconv2d_backward_weight_reference(
    geom: &Deconv2dGeometry,
    input: ArrayView3<f64>,
    d_out: ArrayView3<f64>,
) -> Result<(Array4<f64>, Array1<f64>)> {
    expect_shape("deconv2d_backward input", input.shape(), &geom.input_shape())?;
    expect_shape("deconv2d_backward d_out", d_out.shape(), &geom.output_shape())?;
    let [h_out, w_out, c_out] = geom.output_shape();
    let mut d_w = Array4::zeros(geom.weight_shape());
    for iy in 0..geom.h() {
        for ix in 0..geom.w() {
            for ci in 0..geom.c_in() {
                let v = input[[iy, ix, ci]];
                for ky in 0..DECONV_KERNEL {
                    for kx in 0..DECONV_KERNEL {
                        let oy = tap_target(iy, ky, h_out);
                        let ox = tap_target(ix, kx, w_out);
                        let (Some(oy), Some(ox)) = (oy, ox) else { continue };
                        for co in 0..c_out {
                            d_w[[ci, co, ky, kx]] += v * d_out[[oy, ox, co]];
                        }
                    }
                }
            }
        }
    }
    let mut d_b = Array1::zeros(c_out);
    for ((_, _, co), &g) in d_out.indexed_iter() {
        d_b[co] += g;
    }
    Ok((d_w, d_b))
}
