//! im2col + GEMM convolution, parallel over blocks of output rows.
//!
//! For a block of output rows, the im2col matrix `A` has one row per output pixel and `k = 9 c_in`
//! columns ordered `(ky, kx, c)` (so each 3x3 tap copies one contiguous channel run of the
//! channels-last input, or zeros outside the image). The weights are repacked once into
//! `B [k, c_out]` with `B[(3 ky + kx) c_in + c, o] = w[o, c, ky, kx]`. The block's output
//! `[pixels, c_out]` is contiguous in the `[H_out, W_out, C_out]` result, is prefilled with the
//! bias and receives `C ← A B + C` (`matrixmultiply::sgemm`), then the activation.
//!
//! Determinism: blocks are fixed by the geometry alone, every output value is computed by exactly
//! one block, and sgemm's summation order for a value depends only on `k` (not on the block's row
//! count or on the thread running it), so the result is bit-identical for any thread count.

use std::sync::Arc;

use ndarray::{ArrayView1, ArrayView4};
use rayon::prelude::*;

use crate::error::Result;
use crate::ops::geometry::{Conv2dGeometry, CONV_KERNEL, CONV_PADDING};
use crate::ops::{expect_len, expect_shape, scratch_lanes, split_lanes, Activation};

/// Output pixels per block to aim for: big enough for an efficient GEMM, small enough for the
/// im2col block (`pixels · 9 c_in` floats) to stay in L2.
const TARGET_BLOCK_PIXELS: usize = 256;

/// Convolution weights and bias repacked for the GEMM (see the module docs). Pack once per layer;
/// clones share the packed values.
#[derive(Clone, Debug)]
pub struct PackedConv2d {
    geom: Conv2dGeometry,
    /// `[k, c_out]`, row-major.
    weights: Arc<[f32]>,
    bias: Arc<[f32]>,
}

impl PackedConv2d {
    /// Repacks PyTorch-layout weights `[c_out, c_in, 3, 3]` and a bias `[c_out]`.
    ///
    /// # Errors
    /// [`crate::Error::InvalidArgument`] if a shape disagrees with `geom`.
    pub fn new(geom: &Conv2dGeometry, weight: ArrayView4<f32>, bias: ArrayView1<f32>) -> Result<Self> {
        expect_shape("conv2d weight", weight.shape(), &geom.weight_shape())?;
        expect_shape("conv2d bias", bias.shape(), &[geom.c_out()])?;
        let (c_in, c_out) = (geom.c_in(), geom.c_out());
        let mut weights = vec![0.0; geom.k() * c_out];
        for ky in 0..CONV_KERNEL {
            for kx in 0..CONV_KERNEL {
                for c in 0..c_in {
                    let row = (ky * CONV_KERNEL + kx) * c_in + c;
                    for o in 0..c_out {
                        weights[row * c_out + o] = weight[[o, c, ky, kx]];
                    }
                }
            }
        }
        Ok(PackedConv2d { geom: *geom, weights: weights.into(), bias: bias.to_vec().into() })
    }
    /// The same packed weights for another geometry with the same `c_in`, `c_out` (another map
    /// size or stride); no copy.
    ///
    /// # Errors
    /// [`crate::Error::InvalidArgument`] if `geom`'s channel counts differ.
    pub fn with_geometry(&self, geom: &Conv2dGeometry) -> Result<Self> {
        expect_shape("conv2d weight", &self.geom.weight_shape(), &geom.weight_shape())?;
        Ok(PackedConv2d { geom: *geom, ..self.clone() })
    }
    /// The geometry the weights were packed for.
    pub fn geometry(&self) -> &Conv2dGeometry {
        &self.geom
    }
    /// The packed weights `[9 c_in, c_out]`, row `(3 ky + kx) c_in + c` (the direct kernels read
    /// the same layout as `[ky][kx][c][c_out]`).
    pub fn weights(&self) -> &[f32] {
        &self.weights
    }
    /// The bias `[c_out]`.
    pub fn bias(&self) -> &[f32] {
        &self.bias
    }
}

/// Output rows per block (fixed by the geometry, so results never depend on the thread count).
pub fn rows_per_block(geom: &Conv2dGeometry) -> usize {
    (TARGET_BLOCK_PIXELS / geom.w_out()).clamp(1, geom.h_out())
}

/// Number of blocks of output rows.
pub fn n_blocks(geom: &Conv2dGeometry) -> usize {
    geom.h_out().div_ceil(rows_per_block(geom))
}

/// Scratch floats one lane (one parallel task) needs: one block's im2col matrix. Pass
/// `lanes · scratch_len(geom)` floats to [`conv2d_im2col`] to run up to `lanes` tasks at once.
pub fn scratch_len(geom: &Conv2dGeometry) -> usize {
    rows_per_block(geom) * geom.w_out() * geom.k()
}

/// Writes the im2col matrix of output rows `y0 .. y0 + rows` into `cols` (`rows · w_out · 9 c_in`
/// floats, row-major, columns ordered `(ky, kx, c)`). A pure gather: values are copied bit-exactly,
/// and taps outside the input are `0`.
///
/// # Panics
/// If `input` is not `h · w · c_in` long, `cols` is shorter than needed, or the rows exceed `h_out`.
pub fn im2col_rows(geom: &Conv2dGeometry, input: &[f32], y0: usize, rows: usize, cols: &mut [f32]) {
    let [h, w, c_in] = geom.input_shape();
    let (w_out, s) = (geom.w_out(), geom.stride());
    assert_eq!(input.len(), h * w * c_in, "im2col input length");
    assert!(y0 + rows <= geom.h_out(), "im2col rows past the output");
    let cols = &mut cols[..rows * w_out * geom.k()];
    // Taps in order (y, x, ky, kx): one run of c_in values each.
    let mut taps = cols.chunks_exact_mut(c_in);
    for y in y0..y0 + rows {
        for x in 0..w_out {
            for ky in 0..CONV_KERNEL {
                // Input row s·y + ky - 1, absent (zero padding) when outside 0..h.
                let iy = (s * y + ky).checked_sub(CONV_PADDING).filter(|&iy| iy < h);
                for kx in 0..CONV_KERNEL {
                    let ix = (s * x + kx).checked_sub(CONV_PADDING).filter(|&ix| ix < w);
                    // Invariant: `cols` holds exactly rows · w_out · 9 taps of c_in values.
                    let Some(dst) = taps.next() else { unreachable!("im2col tap count") };
                    match (iy, ix) {
                        (Some(iy), Some(ix)) => {
                            let at = (iy * w + ix) * c_in;
                            copy_run(dst, &input[at..at + c_in]);
                        }
                        _ => dst.fill(0.0),
                    }
                }
            }
        }
    }
}

/// The convolution of one block of output rows into `out` (that block's `rows · w_out · c_out`
/// values).
fn conv_block(
    packed: &PackedConv2d,
    input: &[f32],
    y0: usize,
    rows: usize,
    cols: &mut [f32],
    out: &mut [f32],
    activation: Activation,
) {
    let geom = &packed.geom;
    let (k, c_out) = (geom.k(), geom.c_out());
    let m = rows * geom.w_out();
    debug_assert_eq!(out.len(), m * c_out);
    im2col_rows(geom, input, y0, rows, cols);
    for pixel in out.chunks_exact_mut(c_out) {
        pixel.copy_from_slice(&packed.bias);
    }
    // SAFETY: `cols` holds at least m·k floats (im2col_rows checked it) read as an m×k row-major
    // matrix; `weights` holds k·c_out floats read as k×c_out row-major; `out` holds exactly
    // m·c_out floats written as m×c_out row-major, and does not alias the inputs (it is a distinct
    // `&mut`). Strides are lengths of allocated slices, so they fit in isize.
    unsafe {
        matrixmultiply::sgemm(
            m,
            k,
            c_out,
            1.0,
            cols.as_ptr(),
            k as isize,
            1,
            packed.weights.as_ptr(),
            c_out as isize,
            1,
            1.0,
            out.as_mut_ptr(),
            c_out as isize,
            1,
        );
    }
    if activation != Activation::None {
        for v in out.iter_mut() {
            *v = activation.apply_f32(*v);
        }
    }
}

/// Convolution (SPEC.md §7.2) of a channels-last input slice `[h, w, c_in]` into `out`
/// (`[h_out, w_out, c_out]`, fully overwritten), parallel over blocks of output rows with up to
/// `scratch.len() / scratch_len(geom)` tasks.
///
/// # Errors
/// [`crate::Error::InvalidArgument`] if `input` or `out` has the wrong length, or `scratch` is shorter
/// than [`scratch_len`].
pub fn conv2d_im2col(
    packed: &PackedConv2d,
    input: &[f32],
    activation: Activation,
    scratch: &mut [f32],
    out: &mut [f32],
) -> Result<()> {
    let geom = &packed.geom;
    let [h_out, w_out, c_out] = geom.output_shape();
    expect_len("conv2d input", input.len(), geom.input_shape().iter().product())?;
    expect_len("conv2d output", out.len(), h_out * w_out * c_out)?;
    let lane_len = scratch_len(geom);
    let lanes = scratch_lanes("conv2d scratch", scratch, lane_len)?;
    let rpb = rows_per_block(geom);
    let block_out = rpb * w_out * c_out;
    split_lanes(n_blocks(geom), lanes, block_out, out, lane_len, scratch).into_par_iter().for_each(|lane| {
        for (b, out_block) in lane.units.zip(lane.out.chunks_mut(block_out)) {
            let y0 = b * rpb;
            let rows = rpb.min(h_out - y0);
            conv_block(packed, input, y0, rows, lane.scratch, out_block, activation);
        }
    });
    Ok(())
}

/// `dst.copy_from_slice(src)`, with the network's run lengths (16, 32, 64 channels) copied as
/// fixed-size arrays: a few vector moves inline instead of a `memcpy` call per tap.
///
/// # Panics
/// If the lengths differ.
#[inline(always)]
pub(crate) fn copy_run(dst: &mut [f32], src: &[f32]) {
    fn fixed<const N: usize>(dst: &mut [f32], src: &[f32]) -> bool {
        match (<&mut [f32; N]>::try_from(dst), <&[f32; N]>::try_from(src)) {
            (Ok(d), Ok(s)) => {
                *d = *s;
                true
            }
            _ => false,
        }
    }
    let done = match dst.len() {
        32 => fixed::<32>(dst, src),
        16 => fixed::<16>(dst, src),
        64 => fixed::<64>(dst, src),
        _ => false,
    };
    if !done {
        dst.copy_from_slice(src);
    }
}
