//! The fast f32 backward passes of the 5x5 stride-2 transposed convolution (SPEC.md §7.8), as
//! GEMMs over one im2col matrix of the upstream gradient; the f64 oracles are in
//! [`super::backward`].
//!
//! For input pixel `(iy, ix)` the row of `cols` holds `g[2 iy - 2 + ky, 2 ix - 2 + kx, co]` (0
//! outside the output), columns ordered `(ky, kx, co)`, `25 c_out` of them. Then
//!
//! - `d_in = cols W2` with `W2[(5 ky + kx) c_out + co, ci] = w[ci, co, ky, kx]`, one sgemm per
//!   block of input rows (each value computed by one call);
//! - `d_w = Σ_chunks colsᵀ in_chunk` over fixed chunks of input rows, partials added in chunk
//!   order; `d_b` sums the output pixels in row-major order.
//!
//! Chunks are fixed by the geometry, so every result is bit-identical for any rayon thread count.

use ndarray::{Array1, Array3, Array4, ArrayView3, ArrayView4};
use rayon::prelude::*;

use crate::error::Result;
use crate::ops::conv2d::backward_fast::bias_gradient;
use crate::ops::conv2d::im2col::copy_run;
use crate::ops::expect_shape;
use crate::ops::gemm::{rows_per_chunk, sgemm, sum_of_chunks, MatRef};
use crate::ops::geometry::{Deconv2dGeometry, DECONV_KERNEL, DECONV_PADDING, DECONV_STRIDE};
use crate::util::alloc::with_scratch;

/// Input pixels per block of the input gradient's GEMM.
const INPUT_BLOCK_PIXELS: usize = 256;

/// Input pixels per chunk of the weight gradient's reduction (fixed: the chunks decide the
/// summation order).
const WEIGHT_CHUNK_PIXELS: usize = 512;

/// The rows of `cols` for input rows `iy0 .. iy0 + rows` (module docs) into `cols`
/// (`rows · w · 25 c_out` floats).
fn gradient_cols(geom: &Deconv2dGeometry, g: &[f32], iy0: usize, rows: usize, cols: &mut [f32]) {
    let [h_out, w_out, c_out] = geom.output_shape();
    let w = geom.w();
    let mut taps = cols.chunks_exact_mut(c_out);
    let target =
        |i: usize, k: usize, n: usize| (DECONV_STRIDE * i + k).checked_sub(DECONV_PADDING).filter(|&o| o < n);
    for iy in iy0..iy0 + rows {
        for ix in 0..w {
            for ky in 0..DECONV_KERNEL {
                let oy = target(iy, ky, h_out);
                for kx in 0..DECONV_KERNEL {
                    let ox = target(ix, kx, w_out);
                    let Some(dst) = taps.next() else { unreachable!("gradient_cols tap count") };
                    match (oy, ox) {
                        (Some(oy), Some(ox)) => copy_run(dst, &g[(oy * w_out + ox) * c_out..][..c_out]),
                        _ => dst.fill(0.0),
                    }
                }
            }
        }
    }
}

/// Gradient with respect to the input, f32 (module docs): the 5x5 stride-2 convolution of `g` as
/// one sgemm per block of input rows. At most `25 c_out` products per value.
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
    let (h, w, c_in, c_out) = (geom.h(), geom.w(), geom.c_in(), geom.c_out());
    let k = DECONV_KERNEL * DECONV_KERNEL * c_out;
    let mut w2 = vec![0.0f32; k * c_in];
    for ((ci, co, ky, kx), &v) in weight.indexed_iter() {
        w2[((ky * DECONV_KERNEL + kx) * c_out + co) * c_in + ci] = v;
    }
    let d_out = d_out.as_standard_layout();
    let Some(g) = d_out.as_slice() else { unreachable!("standard-layout arrays are contiguous") };
    let mut d_in = Array3::zeros(geom.input_shape());
    let Some(d_in_slice) = d_in.as_slice_mut() else { unreachable!("new arrays are contiguous") };
    let rpb = rows_per_chunk(w, h, INPUT_BLOCK_PIXELS);
    d_in_slice.par_chunks_mut(rpb * w * c_in).enumerate().for_each(|(b, out)| {
        let m = out.len() / c_in;
        with_scratch(m * k, |cols| {
            gradient_cols(geom, g, b * rpb, m / w, cols);
            sgemm(MatRef::row_major(cols, m, k), MatRef::row_major(&w2, k, c_in), 0.0, out);
        });
    });
    Ok(d_in)
}

/// Gradients with respect to the weight and the bias, f32 (module docs): per fixed chunk of input
/// rows one sgemm `colsᵀ in_chunk` (`[25 c_out, pixels] x [pixels, c_in]`), the partials added in
/// chunk order; the bias sums the output pixels in row-major order (`4 h w` terms).
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
    let (h, w, c_in, c_out) = (geom.h(), geom.w(), geom.c_in(), geom.c_out());
    let k = DECONV_KERNEL * DECONV_KERNEL * c_out;
    let input = input.as_standard_layout();
    let d_out = d_out.as_standard_layout();
    let (Some(x_in), Some(g)) = (input.as_slice(), d_out.as_slice()) else {
        unreachable!("standard-layout arrays are contiguous")
    };
    let rpc = rows_per_chunk(w, h, WEIGHT_CHUNK_PIXELS);
    let chunks = h.div_ceil(rpc);
    // [k, c_in], row (5 ky + kx) c_out + co.
    let d_wt = sum_of_chunks(chunks, k * c_in, |i| {
        let iy0 = i * rpc;
        let rows = rpc.min(h - iy0);
        let m = rows * w;
        let x_rows = &x_in[iy0 * w * c_in..][..m * c_in];
        let mut part = vec![0.0f32; k * c_in];
        with_scratch(m * k, |cols| {
            gradient_cols(geom, g, iy0, rows, cols);
            sgemm(MatRef::row_major(cols, m, k).t(), MatRef::row_major(x_rows, m, c_in), 0.0, &mut part);
        });
        part
    });
    let d_w = Array4::from_shape_fn(geom.weight_shape(), |(ci, co, ky, kx)| {
        d_wt[((ky * DECONV_KERNEL + kx) * c_out + co) * c_in + ci]
    });
    Ok((d_w, bias_gradient(g, c_out)))
}
