//! The oracle: a scatter straight from PyTorch's definition, f64 accumulation, one thread.

use ndarray::{Array3, ArrayView1, ArrayView3, ArrayView4};

use crate::error::Result;
use crate::ops::expect_shape;
use crate::ops::geometry::{Deconv2dGeometry, DECONV_KERNEL, DECONV_PADDING, DECONV_STRIDE};

/// Transposed convolution from the definition, in f64: every input value `in[iy, ix, ci]` adds
/// `in[iy, ix, ci] · w[ci, co, ky, kx]` to `out[2 iy - 2 + ky, 2 ix - 2 + kx, co]` when that
/// output exists; every output starts at `b[co]`.
///
/// # Shapes
/// `input [h, w, c_in]`, `weight [c_in, c_out, 5, 5]`, `bias [c_out]`, output `[2h, 2w, c_out]`.
///
/// # Errors
/// [`crate::Error::InvalidArgument`] if an array's shape disagrees with `geom`.
pub fn deconv2d_reference(
    geom: &Deconv2dGeometry,
    input: ArrayView3<f64>,
    weight: ArrayView4<f64>,
    bias: ArrayView1<f64>,
) -> Result<Array3<f64>> {
    expect_shape("deconv2d input", input.shape(), &geom.input_shape())?;
    expect_shape("deconv2d weight", weight.shape(), &geom.weight_shape())?;
    expect_shape("deconv2d bias", bias.shape(), &[geom.c_out()])?;
    let [h_out, w_out, c_out] = geom.output_shape();
    let mut out = Array3::from_shape_fn((h_out, w_out, c_out), |(_, _, co)| bias[co]);
    for iy in 0..geom.h() {
        for ix in 0..geom.w() {
            for ci in 0..geom.c_in() {
                let v = input[[iy, ix, ci]];
                for ky in 0..DECONV_KERNEL {
                    for kx in 0..DECONV_KERNEL {
                        // o = s·i - p + k, dropped when outside 0..out (the padding crops it).
                        let oy = (DECONV_STRIDE * iy + ky).checked_sub(DECONV_PADDING).filter(|&o| o < h_out);
                        let ox = (DECONV_STRIDE * ix + kx).checked_sub(DECONV_PADDING).filter(|&o| o < w_out);
                        let (Some(oy), Some(ox)) = (oy, ox) else { continue };
                        for co in 0..c_out {
                            out[[oy, ox, co]] += v * weight[[ci, co, ky, kx]];
                        }
                    }
                }
            }
        }
    }
    Ok(out)
}
