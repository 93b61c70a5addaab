//! The fast f32 backward passes of the 3x3 convolution (SPEC.md §7.8), through the same fast
//! kernels and GEMMs as the forward pass; the f64 oracles are in [`super::backward`].
//!
//! - Input gradient, stride 1: the transposed operation is itself a stride-1 3x3 convolution of
//!   `g` with the flipped, transposed weights `w'[c, o, ky, kx] = w[o, c, 2 - ky, 2 - kx]`, run by
//!   the forward's [`super::conv2d()`] (any [`Conv2dImpl`]: direct, Winograd, im2col).
//! - Input gradient, stride 2: `D = G Wm` (`[pixels_out, c_out] x [c_out, 9 c_in]`, one sgemm per
//!   block of output rows), then every input value gathers its (at most 9) entries of `D`, taps in
//!   row-major order.
//! - Weight gradient: per fixed chunk of output rows (in parallel) a partial, the partials added in
//!   chunk order. For 32 output channels the partial is `weight_grad`'s fused chains (one
//!   FMA chain per weight over the chunk's pixels); otherwise `colsᵀ G_chunk`, the chunk's im2col
//!   matrix times its gradient (one sgemm). The bias gradient sums the output pixels in row-major
//!   order.
//!
//! Chunks are fixed by the geometry, so every result is bit-identical for any rayon thread count.

use ndarray::{Array1, Array3, Array4, ArrayView3, ArrayView4};
use rayon::prelude::*;

use super::backward::tap_target;
use super::im2col::im2col_rows;
use super::weight_grad;
use super::{conv2d_prepared_into, Conv2dImpl};
use crate::error::Result;
use crate::ops::gemm::{rows_per_chunk, sgemm, sum_of_chunks, MatRef};
use crate::ops::geometry::{Conv2dGeometry, CONV_KERNEL};
use crate::ops::prepared::PreparedConv;
use crate::ops::{expect_shape, Activation};
use crate::runtime::CpuFeatureLevel;
use crate::util::alloc::with_scratch;

/// Output pixels per chunk of the weight gradient's reduction (fixed: the chunks decide the
/// summation order).
const WEIGHT_CHUNK_PIXELS: usize = 1024;

/// Output pixels per block of the stride-2 input gradient's GEMM.
const INPUT_BLOCK_PIXELS: usize = 256;

/// The flipped, transposed weights of the stride-1 input gradient:
/// `w'[c, o, ky, kx] = w[o, c, 2 - ky, 2 - kx]`.
pub fn flipped_transposed(weight: ArrayView4<f32>) -> Array4<f32> {
    let (c_out, c_in, kh, kw) = weight.dim();
    Array4::from_shape_fn((c_in, c_out, kh, kw), |(c, o, ky, kx)| weight[[o, c, kh - 1 - ky, kw - 1 - kx]])
}

/// Gradient with respect to the input, f32, by [`Conv2dImpl::Direct`] for stride 1 (see
/// [`conv2d_backward_input_with`]). Bit-identical for any thread count.
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
    conv2d_backward_input_with(Conv2dImpl::Direct, geom, d_out, weight)
}

/// [`conv2d_backward_input_with`] for a prepared layer: at stride 1 the flipped layer is made and
/// packed once per prepared layer ([`PreparedConv::backward_input`]), not per call (training runs
/// every image of a step through the same prepared network). The same bits.
///
/// # Errors
/// As [`conv2d_backward_input_with`].
pub fn conv2d_backward_input_prepared(
    imp: Conv2dImpl,
    geom: &Conv2dGeometry,
    d_out: ArrayView3<f32>,
    layer: &PreparedConv,
) -> Result<Array3<f32>> {
    if geom.stride() != 1 {
        return conv2d_backward_input_with(imp, geom, d_out, layer.layer().weight.view());
    }
    expect_shape("conv2d_backward d_out", d_out.shape(), &geom.output_shape())?;
    expect_shape("conv2d_backward weight", layer.layer().weight.shape(), &geom.weight_shape())?;
    stride1_input_gradient(imp, geom, d_out, &layer.backward_input())
}

/// The stride-1 input gradient: `imp` (falling back to [`Conv2dImpl::Direct`] where it cannot
/// run) on the transposed geometry with the flipped layer `flipped`
/// ([`PreparedConv::transposed_of`]). Shapes checked by the caller.
fn stride1_input_gradient(
    imp: Conv2dImpl,
    geom: &Conv2dGeometry,
    d_out: ArrayView3<f32>,
    flipped: &PreparedConv,
) -> Result<Array3<f32>> {
    let [h_out, w_out, c_out] = geom.output_shape();
    let transposed = Conv2dGeometry::new(h_out, w_out, c_out, geom.c_in(), 1)?;
    let imp = if imp.supports(&transposed) { imp } else { Conv2dImpl::Direct };
    let mut out = crate::util::alloc::zeroed_map(transposed.output_shape());
    let Some(y) = out.as_slice_mut() else { unreachable!("a new array is contiguous") };
    conv2d_prepared_into(imp, &transposed, d_out, flipped, Activation::None, y, CpuFeatureLevel::get())?;
    Ok(out)
}

/// Gradient with respect to the input, f32. Stride 1: the forward convolution `imp` (falling back
/// to [`Conv2dImpl::Direct`] where `imp` cannot run it) of `g` with [`flipped_transposed`]
/// weights, zero bias; its error budget is `imp`'s (SPEC.md §7.5, §7.11) with `K = 9 c_out`.
/// Other strides: one sgemm per block of output rows and a gather (module docs), `imp` unused.
///
/// # Errors
/// [`crate::Error::InvalidArgument`] if an array's shape disagrees with `geom`.
pub fn conv2d_backward_input_with(
    imp: Conv2dImpl,
    geom: &Conv2dGeometry,
    d_out: ArrayView3<f32>,
    weight: ArrayView4<f32>,
) -> Result<Array3<f32>> {
    expect_shape("conv2d_backward d_out", d_out.shape(), &geom.output_shape())?;
    expect_shape("conv2d_backward weight", weight.shape(), &geom.weight_shape())?;
    let [h_out, w_out, c_out] = geom.output_shape();
    let (w, c_in, s) = (geom.w(), geom.c_in(), geom.stride());
    if s == 1 {
        return stride1_input_gradient(imp, geom, d_out, &PreparedConv::transposed_of(weight));
    }
    let k = geom.k();
    // Wm [c_out, k]: Wm[o, (3 ky + kx) c_in + c] = w[o, c, ky, kx].
    let mut wm = vec![0.0f32; c_out * k];
    for ((o, c, ky, kx), &v) in weight.indexed_iter() {
        wm[o * k + (ky * CONV_KERNEL + kx) * c_in + c] = v;
    }
    let d_out = d_out.as_standard_layout();
    let Some(g) = d_out.as_slice() else { unreachable!("standard-layout arrays are contiguous") };
    let mut d_in = Array3::zeros(geom.input_shape());
    with_scratch(h_out * w_out * k, |d_col| {
        let block = rows_per_chunk(w_out, h_out, INPUT_BLOCK_PIXELS) * w_out;
        d_col.par_chunks_mut(block * k).enumerate().for_each(|(b, out)| {
            let m = out.len() / k;
            let g_rows = &g[b * block * c_out..][..m * c_out];
            sgemm(MatRef::row_major(g_rows, m, c_out), MatRef::row_major(&wm, c_out, k), 0.0, out);
        });
        let d_col = &*d_col;
        let Some(d_in_slice) = d_in.as_slice_mut() else { unreachable!("new arrays are contiguous") };
        d_in_slice.par_chunks_mut(w * c_in).enumerate().for_each(|(iy, row)| {
            for (ix, px) in row.chunks_exact_mut(c_in).enumerate() {
                for ky in 0..CONV_KERNEL {
                    let Some(y) = tap_target(iy, ky, s, h_out) else { continue };
                    for kx in 0..CONV_KERNEL {
                        let Some(x) = tap_target(ix, kx, s, w_out) else { continue };
                        let src = &d_col[(y * w_out + x) * k + (ky * CONV_KERNEL + kx) * c_in..][..c_in];
                        for (a, &v) in px.iter_mut().zip(src) {
                            *a += v;
                        }
                    }
                }
            }
        });
    });
    Ok(d_in)
}

/// Gradients with respect to the weight and the bias, f32: per fixed chunk of output rows one
/// sgemm `colsᵀ G_chunk` (`[9 c_in, pixels] x [pixels, c_out]`), the partials added in chunk order;
/// the bias sums the output pixels in row-major order. Bit-identical for any thread count.
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
    let (c_in, k) = (geom.c_in(), geom.k());
    let input = input.as_standard_layout();
    let d_out = d_out.as_standard_layout();
    let (Some(x_in), Some(g)) = (input.as_slice(), d_out.as_slice()) else {
        unreachable!("standard-layout arrays are contiguous")
    };
    let rpc = rows_per_chunk(w_out, h_out, WEIGHT_CHUNK_PIXELS);
    let chunks = h_out.div_ceil(rpc);
    let level = CpuFeatureLevel::get();
    // d_wᵀ [k, c_out], row (3 ky + kx) c_in + c.
    let d_wt = sum_of_chunks(chunks, k * c_out, |i| {
        let y0 = i * rpc;
        let rows = rpc.min(h_out - y0);
        let m = rows * w_out;
        let mut part = vec![0.0f32; k * c_out];
        if weight_grad::supports(geom) {
            weight_grad::chunk(geom, x_in, g, y0, rows, &mut part, level);
            return part;
        }
        let g_rows = &g[y0 * w_out * c_out..][..m * c_out];
        with_scratch(m * k, |cols| {
            im2col_rows(geom, x_in, y0, rows, cols);
            sgemm(MatRef::row_major(cols, m, k).t(), MatRef::row_major(g_rows, m, c_out), 0.0, &mut part);
        });
        part
    });
    let d_w = Array4::from_shape_fn(geom.weight_shape(), |(o, c, ky, kx)| {
        d_wt[((ky * CONV_KERNEL + kx) * c_in + c) * c_out + o]
    });
    Ok((d_w, bias_gradient(g, c_out)))
}

/// `d_b[o] = Σ_p g[p, o]` over the pixels in row-major order.
pub(crate) fn bias_gradient(g: &[f32], c_out: usize) -> Array1<f32> {
    let mut d_b = vec![0.0f32; c_out];
    for px in g.chunks_exact(c_out) {
        for (b, &v) in d_b.iter_mut().zip(px) {
            *b += v;
        }
    }
    Array1::from(d_b)
}
