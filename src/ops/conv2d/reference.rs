//! The oracle: seven nested loops, f64 accumulation, one thread. Keep it naive.

use ndarray::{Array3, ArrayView1, ArrayView3, ArrayView4};

use super::super::{expect_shape, Activation};
use crate::error::Result;
use crate::ops::geometry::{Conv2dGeometry, CONV_KERNEL, CONV_PADDING};

/// 3x3 convolution straight from the definition, in f64:
/// `out[y, x, o] = act(b[o] + Σ_{ky, kx, c} w[o, c, ky, kx] · in[s y + ky - 1, s x + kx - 1, c])`,
/// with `in` zero outside the image.
///
/// # Shapes
/// `input [h, w, c_in]`, `weight [c_out, c_in, 3, 3]`, `bias [c_out]`, output `[h_out, w_out, c_out]`.
///
/// # Errors
/// [`crate::Error::InvalidArgument`] if an array's shape disagrees with `geom`.
pub fn conv2d_reference(
    geom: &Conv2dGeometry,
    input: ArrayView3<f64>,
    weight: ArrayView4<f64>,
    bias: ArrayView1<f64>,
    activation: Activation,
) -> Result<Array3<f64>> {
    expect_shape("conv2d input", input.shape(), &geom.input_shape())?;
    expect_shape("conv2d weight", weight.shape(), &geom.weight_shape())?;
    expect_shape("conv2d bias", bias.shape(), &[geom.c_out()])?;
    let [h_out, w_out, c_out] = geom.output_shape();
    let (h, w, s) = (geom.h() as isize, geom.w() as isize, geom.stride() as isize);
    let pad = CONV_PADDING as isize;
    let mut out = Array3::zeros((h_out, w_out, c_out));
    for y in 0..h_out {
        for x in 0..w_out {
            for o in 0..c_out {
                let mut acc = bias[o];
                for ky in 0..CONV_KERNEL {
                    for kx in 0..CONV_KERNEL {
                        let iy = s * y as isize + ky as isize - pad;
                        let ix = s * x as isize + kx as isize - pad;
                        if iy < 0 || iy >= h || ix < 0 || ix >= w {
                            continue; // zero padding
                        }
                        for c in 0..geom.c_in() {
                            acc += weight[[o, c, ky, kx]] * input[[iy as usize, ix as usize, c]];
                        }
                    }
                }
                out[[y, x, o]] = activation.apply_f64(acc);
            }
        }
    }
    Ok(out)
}
