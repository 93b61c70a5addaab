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
//! differences of [`conv2d_reference`](super::conv2d_reference)); [`conv2d_backward_input`] and
//! [`conv2d_backward_weight`] are the fast f32 versions. Both fast versions sum every output value
//! in an order fixed by the geometry alone, so their results are bit-identical for any rayon thread
//! count.

use ndarray::{Array1, Array3, Array4, ArrayView, ArrayView3, ArrayView4, Dimension};
use rayon::prelude::*;

use crate::error::Result;
use crate::nn::geometry::{Conv2dGeometry, CONV_KERNEL, CONV_PADDING};
use crate::nn::{add_transposed_tap, axpy, expect_shape};

/// Input pixel read by output pixel `j` through tap `k` along one axis: `s j + k - 1`, or `None`
/// in the zero padding.
fn tap_source(j: usize, k: usize, s: usize, n: usize) -> Option<usize> {
    (s * j + k).checked_sub(CONV_PADDING).filter(|&i| i < n)
}

/// Output pixel that reads input pixel `i` through tap `k` along one axis: the `j` with
/// `s j + k - 1 = i`, if it exists in `0..n_out`.
fn tap_target(i: usize, k: usize, s: usize, n_out: usize) -> Option<usize> {
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

/// Gradient with respect to the input, f32, as a gather: input pixel `(iy, ix)` sums, into its
/// `c_in` channels, `w[o, c, ky, kx] · g[y, x, o]` over `ky`, `kx` (row-major) and then `o`, for
/// the output pixels `(y, x)` that read it through tap `(ky, kx)`, always in that order. Parallel
/// over input rows; each row is written by one task, so the result does not depend on the thread
/// count. At most `9 c_out` products per value.
///
/// # Shapes
/// `d_out [h_out, w_out, c_out]`, `weight [c_out, c_in, 3, 3]`, result `[h, w, c_in]`.
///
/// # Errors
/// [`crate::Error::InvalidArgument`] if an array's shape disagrees with `geom`.
pub fn conv2d_backward_input(
    geom: &Conv2dGeometry,
    d_out: ArrayView3<f32>,
    weight: ArrayView4<f32>,
) -> Result<Array3<f32>> {
    expect_shape("conv2d_backward d_out", d_out.shape(), &geom.output_shape())?;
    expect_shape("conv2d_backward weight", weight.shape(), &geom.weight_shape())?;
    let [h_out, w_out, c_out] = geom.output_shape();
    let (w, c_in, s) = (geom.w(), geom.c_in(), geom.stride());
    // Weights repacked to [ky][kx][o][c], so the inner loop over c is contiguous.
    let mut packed = vec![0.0f32; CONV_KERNEL * CONV_KERNEL * c_out * c_in];
    for ((o, c, ky, kx), &v) in weight.indexed_iter() {
        packed[((ky * CONV_KERNEL + kx) * c_out + o) * c_in + c] = v;
    }
    let d_out = d_out.as_standard_layout();
    let Some(g) = d_out.as_slice() else { unreachable!("standard-layout arrays are contiguous") };
    let mut d_in = Array3::zeros(geom.input_shape());
    let Some(d_in_slice) = d_in.as_slice_mut() else { unreachable!("new arrays are contiguous") };
    d_in_slice.par_chunks_mut(w * c_in).enumerate().for_each(|(iy, row)| {
        for (ix, px) in row.chunks_exact_mut(c_in).enumerate() {
            for ky in 0..CONV_KERNEL {
                let Some(y) = tap_target(iy, ky, s, h_out) else { continue };
                for kx in 0..CONV_KERNEL {
                    let Some(x) = tap_target(ix, kx, s, w_out) else { continue };
                    let g_px = &g[(y * w_out + x) * c_out..][..c_out];
                    let w_tap = &packed[(ky * CONV_KERNEL + kx) * c_out * c_in..][..c_out * c_in];
                    add_transposed_tap(px, g_px, w_tap);
                }
            }
        }
    });
    Ok(d_in)
}

/// Gradients with respect to the weight and the bias, f32. Parallel over output channels `o`: one
/// task owns `d_w[o, ..]` and `d_b[o]` and sums the output pixels in row-major order, so every
/// value's summation order depends only on the geometry and the result not on the thread count.
/// `h_out w_out` products per value.
///
/// # Shapes
/// `input [h, w, c_in]`, `d_out [h_out, w_out, c_out]`, results `[c_out, c_in, 3, 3]` and `[c_out]`.
///
/// # Errors
/// [`crate::Error::InvalidArgument`] if an array's shape disagrees with `geom`.
pub fn conv2d_backward_weight(
    geom: &Conv2dGeometry,
    input: ArrayView3<f32>,
    d_out: ArrayView3<f32>,
) -> Result<(Array4<f32>, Array1<f32>)> {
    expect_shape("conv2d_backward input", input.shape(), &geom.input_shape())?;
    expect_shape("conv2d_backward d_out", d_out.shape(), &geom.output_shape())?;
    let [h_out, w_out, c_out] = geom.output_shape();
    let (h, w, c_in, s) = (geom.h(), geom.w(), geom.c_in(), geom.stride());
    let input = input.as_standard_layout();
    let d_out = d_out.as_standard_layout();
    let (Some(x_in), Some(g)) = (input.as_slice(), d_out.as_slice()) else {
        unreachable!("standard-layout arrays are contiguous")
    };
    let taps = CONV_KERNEL * CONV_KERNEL;
    // Per channel o: accumulators [ky][kx][c] (c contiguous, like the input pixels) and the bias.
    let per_o: Vec<(Vec<f32>, f32)> = (0..c_out)
        .into_par_iter()
        .map(|o| {
            let mut acc = vec![0.0f32; taps * c_in];
            let mut acc_b = 0.0f32;
            for y in 0..h_out {
                for x in 0..w_out {
                    let gv = g[(y * w_out + x) * c_out + o];
                    acc_b += gv;
                    for ky in 0..CONV_KERNEL {
                        let Some(iy) = tap_source(y, ky, s, h) else { continue };
                        for kx in 0..CONV_KERNEL {
                            let Some(ix) = tap_source(x, kx, s, w) else { continue };
                            let px = &x_in[(iy * w + ix) * c_in..][..c_in];
                            let a = &mut acc[(ky * CONV_KERNEL + kx) * c_in..][..c_in];
                            axpy(a, gv, px);
                        }
                    }
                }
            }
            (acc, acc_b)
        })
        .collect();
    let d_w = Array4::from_shape_fn(geom.weight_shape(), |(o, c, ky, kx)| {
        per_o[o].0[(ky * CONV_KERNEL + kx) * c_in + c]
    });
    let d_b = Array1::from_shape_fn(c_out, |o| per_o[o].1);
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
