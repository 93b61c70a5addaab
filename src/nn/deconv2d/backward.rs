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
//! `*_reference` functions are plain loops in f64; [`deconv2d_backward_input`] and
//! [`deconv2d_backward_weight`] are the fast f32 versions, bit-identical for any thread count.

use ndarray::{Array1, Array3, Array4, ArrayView3, ArrayView4};
use rayon::prelude::*;

use crate::error::Result;
use crate::nn::geometry::{Deconv2dGeometry, DECONV_KERNEL, DECONV_PADDING, DECONV_STRIDE};
use crate::nn::{add_transposed_tap, axpy, expect_shape};

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

/// Gradient with respect to the input, f32, as a gather (the strided 5x5 convolution of `g`):
/// input pixel `(iy, ix)` sums, into its `c_in` channels, `w[ci, co, ky, kx] · g[2 iy - 2 + ky,
/// 2 ix - 2 + kx, co]` over `ky`, `kx` (row-major) and then `co`, always in that order. Parallel
/// over input rows, one task per row, so the result does not depend on the thread count. At most
/// `25 c_out` products per value.
///
/// # Shapes
/// `d_out [2h, 2w, c_out]`, `weight [c_in, c_out, 5, 5]`, result `[h, w, c_in]`.
///
/// # Errors
/// [`crate::Error::InvalidArgument`] if an array's shape disagrees with `geom`.
pub fn deconv2d_backward_input(
    geom: &Deconv2dGeometry,
    d_out: ArrayView3<f32>,
    weight: ArrayView4<f32>,
) -> Result<Array3<f32>> {
    expect_shape("deconv2d_backward d_out", d_out.shape(), &geom.output_shape())?;
    expect_shape("deconv2d_backward weight", weight.shape(), &geom.weight_shape())?;
    let [h_out, w_out, c_out] = geom.output_shape();
    let (w, c_in) = (geom.w(), geom.c_in());
    // Weights repacked to [ky][kx][co][ci], so the inner loop over ci is contiguous.
    let mut packed = vec![0.0f32; DECONV_KERNEL * DECONV_KERNEL * c_out * c_in];
    for ((ci, co, ky, kx), &v) in weight.indexed_iter() {
        packed[((ky * DECONV_KERNEL + kx) * c_out + co) * c_in + ci] = v;
    }
    let d_out = d_out.as_standard_layout();
    let Some(g) = d_out.as_slice() else { unreachable!("standard-layout arrays are contiguous") };
    let mut d_in = Array3::zeros(geom.input_shape());
    let Some(d_in_slice) = d_in.as_slice_mut() else { unreachable!("new arrays are contiguous") };
    d_in_slice.par_chunks_mut(w * c_in).enumerate().for_each(|(iy, row)| {
        for (ix, px) in row.chunks_exact_mut(c_in).enumerate() {
            for ky in 0..DECONV_KERNEL {
                let Some(oy) = tap_target(iy, ky, h_out) else { continue };
                for kx in 0..DECONV_KERNEL {
                    let Some(ox) = tap_target(ix, kx, w_out) else { continue };
                    let g_px = &g[(oy * w_out + ox) * c_out..][..c_out];
                    let w_tap = &packed[(ky * DECONV_KERNEL + kx) * c_out * c_in..][..c_out * c_in];
                    add_transposed_tap(px, g_px, w_tap);
                }
            }
        }
    });
    Ok(d_in)
}

/// Gradients with respect to the weight and the bias, f32. Parallel over output channels `co`: one
/// task owns `d_w[.., co, .., ..]` and `d_b[co]`; the weight sums run over input pixels in
/// row-major order (`h w` products per value), the bias sum over output pixels in row-major order
/// (`4 h w` terms), so the result does not depend on the thread count.
///
/// # Shapes
/// `input [h, w, c_in]`, `d_out [2h, 2w, c_out]`, results `[c_in, c_out, 5, 5]` and `[c_out]`.
///
/// # Errors
/// [`crate::Error::InvalidArgument`] if an array's shape disagrees with `geom`.
pub fn deconv2d_backward_weight(
    geom: &Deconv2dGeometry,
    input: ArrayView3<f32>,
    d_out: ArrayView3<f32>,
) -> Result<(Array4<f32>, Array1<f32>)> {
    expect_shape("deconv2d_backward input", input.shape(), &geom.input_shape())?;
    expect_shape("deconv2d_backward d_out", d_out.shape(), &geom.output_shape())?;
    let [h_out, w_out, c_out] = geom.output_shape();
    let (h, w, c_in) = (geom.h(), geom.w(), geom.c_in());
    let input = input.as_standard_layout();
    let d_out = d_out.as_standard_layout();
    let (Some(x_in), Some(g)) = (input.as_slice(), d_out.as_slice()) else {
        unreachable!("standard-layout arrays are contiguous")
    };
    let taps = DECONV_KERNEL * DECONV_KERNEL;
    // Per channel co: accumulators [ky][kx][ci] (ci contiguous, like the input pixels) and the bias.
    let per_co: Vec<(Vec<f32>, f32)> = (0..c_out)
        .into_par_iter()
        .map(|co| {
            let mut acc = vec![0.0f32; taps * c_in];
            for iy in 0..h {
                for ix in 0..w {
                    let px = &x_in[(iy * w + ix) * c_in..][..c_in];
                    for ky in 0..DECONV_KERNEL {
                        let Some(oy) = tap_target(iy, ky, h_out) else { continue };
                        for kx in 0..DECONV_KERNEL {
                            let Some(ox) = tap_target(ix, kx, w_out) else { continue };
                            let gv = g[(oy * w_out + ox) * c_out + co];
                            let a = &mut acc[(ky * DECONV_KERNEL + kx) * c_in..][..c_in];
                            axpy(a, gv, px);
                        }
                    }
                }
            }
            let acc_b = g.iter().skip(co).step_by(c_out).fold(0.0f32, |s, &v| s + v);
            (acc, acc_b)
        })
        .collect();
    let d_w = Array4::from_shape_fn(geom.weight_shape(), |(ci, co, ky, kx)| {
        per_co[co].0[(ky * DECONV_KERNEL + kx) * c_in + ci]
    });
    let d_b = Array1::from_shape_fn(c_out, |co| per_co[co].1);
    Ok((d_w, d_b))
}
