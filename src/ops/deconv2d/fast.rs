//! Transposed convolution as a deterministic gather: four parity sub-convolutions, each a GEMM.
//!
//! Output row `o = 2m + q` (parity `q`) receives input row `i = m + d` through kernel row
//! `k = o + 2 - 2i = 2 + q - 2d`, `0 <= k < 5`. So even rows see `d ∈ {-1, 0, 1}` (`k = 4, 2, 0`)
//! and odd rows `d ∈ {0, 1}` (`k = 3, 1`); columns alike. An output pixel of parity `(qy, qx)`
//! therefore sums 3x3, 3x2, 2x3 or 2x2 taps of a small ordinary convolution of the input, with
//! weights `w[ci, co, 2 + qy - 2dy, 2 + qx - 2dx]`.
//!
//! For each input row `m`, and each parity, the gathered taps of the row (`w` pixels times
//! `taps · c_in` values, zeros outside the input) multiply the parity's packed weights
//! `[taps · c_in, c_out]`, and the product is added (`matrixmultiply::sgemm`) into every other pixel
//! of output row `2m + qy` starting at column `qx`, prefilled with the bias.
//!
//! Determinism: each output value is written by exactly one GEMM (that of its row and parity)
//! whose summation order depends only on its inner dimension; tasks own disjoint output rows.

use std::sync::Arc;

use ndarray::{ArrayView1, ArrayView4};
use rayon::prelude::*;

use crate::error::Result;
use crate::ops::geometry::{Deconv2dGeometry, DECONV_KERNEL, DECONV_PADDING, DECONV_STRIDE};
use crate::ops::{expect_len, expect_shape, scratch_lanes, split_lanes};

/// Number of output parities along one axis (the stride).
pub(crate) const PARITIES: usize = DECONV_STRIDE;

/// Input offsets `d` and kernel indices `k` reaching an output of parity `q`: all `d` with
/// `k = 2 + q - 2d` (that is `p + q - s·d`) in `0..5`, in increasing `d`.
fn parity_taps(q: usize) -> Vec<(isize, usize)> {
    (-2isize..=2)
        .filter_map(|d| {
            let k = (DECONV_PADDING + q) as isize - DECONV_STRIDE as isize * d;
            (0..DECONV_KERNEL as isize).contains(&k).then_some((d, k as usize))
        })
        .collect()
}

/// Transposed-convolution weights repacked per output parity (see the module docs). Clones share
/// the packed values.
#[derive(Clone, Debug)]
pub struct PackedDeconv2d {
    geom: Deconv2dGeometry,
    /// `taps[q]`: `(d, k)` pairs for parity `q`.
    taps: [Vec<(isize, usize)>; PARITIES],
    /// `weights[PARITIES · qy + qx]`: `[ty, tx, ci] × [co]`, row-major.
    weights: Arc<[Vec<f32>]>,
    bias: Arc<[f32]>,
}

impl PackedDeconv2d {
    /// Repacks PyTorch-layout weights `[c_in, c_out, 5, 5]` and a bias `[c_out]`.
    ///
    /// # Errors
    /// [`crate::Error::InvalidArgument`] if a shape disagrees with `geom`.
    pub fn new(geom: &Deconv2dGeometry, weight: ArrayView4<f32>, bias: ArrayView1<f32>) -> Result<Self> {
        expect_shape("deconv2d weight", weight.shape(), &geom.weight_shape())?;
        expect_shape("deconv2d bias", bias.shape(), &[geom.c_out()])?;
        let (c_in, c_out) = (geom.c_in(), geom.c_out());
        let taps = [parity_taps(0), parity_taps(1)];
        let mut weights = Vec::with_capacity(PARITIES * PARITIES);
        for qy in 0..PARITIES {
            for qx in 0..PARITIES {
                let mut packed = Vec::with_capacity(taps[qy].len() * taps[qx].len() * c_in * c_out);
                for &(_, ky) in &taps[qy] {
                    for &(_, kx) in &taps[qx] {
                        for ci in 0..c_in {
                            packed.extend((0..c_out).map(|co| weight[[ci, co, ky, kx]]));
                        }
                    }
                }
                weights.push(packed);
            }
        }
        Ok(PackedDeconv2d { geom: *geom, taps, weights: weights.into(), bias: bias.to_vec().into() })
    }
    /// The same packed weights for another input size with the same `c_in`, `c_out`; no copy.
    ///
    /// # Errors
    /// [`crate::Error::InvalidArgument`] if `geom`'s channel counts differ.
    pub fn with_geometry(&self, geom: &Deconv2dGeometry) -> Result<Self> {
        expect_shape("deconv2d weight", &self.geom.weight_shape(), &geom.weight_shape())?;
        Ok(PackedDeconv2d { geom: *geom, ..self.clone() })
    }
    /// The geometry the weights were packed for.
    pub fn geometry(&self) -> &Deconv2dGeometry {
        &self.geom
    }

    /// The input offsets `d` reaching output parity `q`, increasing.
    pub(crate) fn offsets(&self, q: usize) -> Vec<isize> {
        self.taps[q].iter().map(|&(d, _)| d).collect()
    }

    /// Parity `(qy, qx)`'s packed weights, `[t_y][t_x][c_in][c_out]`.
    pub(crate) fn parity_weights(&self, qy: usize, qx: usize) -> &[f32] {
        &self.weights[PARITIES * qy + qx]
    }

    /// The bias, `[c_out]`.
    pub(crate) fn bias(&self) -> &[f32] {
        &self.bias
    }
}

/// Scratch floats one lane (one parallel task) needs: the gathered taps of one input row for the
/// widest parity, `w · 9 c_in`.
pub fn scratch_len(geom: &Deconv2dGeometry) -> usize {
    geom.w() * geom.k()
}

/// Output rows `2m` and `2m + 1` (`out`, `2 · 2w · c_out` values) from input row `m`.
fn deconv_row_pair(packed: &PackedDeconv2d, input: &[f32], m: usize, cols: &mut [f32], out: &mut [f32]) {
    let geom = &packed.geom;
    let [h, w, c_in] = geom.input_shape();
    let (w_out, c_out) = (geom.w_out(), geom.c_out());
    debug_assert_eq!(out.len(), PARITIES * w_out * c_out);
    for pixel in out.chunks_exact_mut(c_out) {
        pixel.copy_from_slice(&packed.bias);
    }
    for qy in 0..PARITIES {
        for qx in 0..PARITIES {
            let (ty, tx) = (&packed.taps[qy], &packed.taps[qx]);
            let k = ty.len() * tx.len() * c_in;
            let cols = &mut cols[..w * k];
            let mut runs = cols.chunks_exact_mut(c_in);
            for n in 0..w {
                for &(dy, _) in ty {
                    let iy = m.checked_add_signed(dy).filter(|&i| i < h);
                    for &(dx, _) in tx {
                        let ix = n.checked_add_signed(dx).filter(|&i| i < w);
                        // Invariant: `cols` holds exactly w · |ty| · |tx| runs of c_in values.
                        let Some(dst) = runs.next() else { unreachable!("deconv tap count") };
                        match (iy, ix) {
                            (Some(iy), Some(ix)) => {
                                let at = (iy * w + ix) * c_in;
                                dst.copy_from_slice(&input[at..at + c_in]);
                            }
                            _ => dst.fill(0.0),
                        }
                    }
                }
            }
            let weights = &packed.weights[PARITIES * qy + qx];
            debug_assert_eq!(weights.len(), k * c_out);
            let c_offset = (qy * w_out + qx) * c_out;
            // SAFETY: `cols` is w·k floats read as a w×k row-major matrix; `weights` is k·c_out
            // floats read as k×c_out row-major. C is the w×c_out matrix at `out[c_offset..]` with
            // row stride 2·c_out: its last element is at c_offset + (w-1)·2·c_out + c_out - 1 =
            // (qy + 1)·w_out·c_out - (1 - qx)·c_out - 1 < out.len() since w_out = 2w, qx <= 1,
            // qy <= 1. Its elements are distinct, and `out` is a `&mut` disjoint from the inputs.
            unsafe {
                matrixmultiply::sgemm(
                    w,
                    k,
                    c_out,
                    1.0,
                    cols.as_ptr(),
                    k as isize,
                    1,
                    weights.as_ptr(),
                    c_out as isize,
                    1,
                    1.0,
                    out.as_mut_ptr().add(c_offset),
                    (PARITIES * c_out) as isize,
                    1,
                );
            }
        }
    }
}

/// Transposed convolution (SPEC.md §7.3) of a channels-last input slice `[h, w, c_in]` into `out`
/// (`[2h, 2w, c_out]`, fully overwritten), parallel over pairs of output rows with up to
/// `scratch.len() / scratch_len(geom)` tasks.
///
/// # Errors
/// [`crate::Error::InvalidArgument`] if `input` or `out` has the wrong length, or `scratch` is shorter
/// than [`scratch_len`].
pub fn deconv2d_fast(
    packed: &PackedDeconv2d,
    input: &[f32],
    scratch: &mut [f32],
    out: &mut [f32],
) -> Result<()> {
    let geom = &packed.geom;
    let [h_out, w_out, c_out] = geom.output_shape();
    expect_len("deconv2d input", input.len(), geom.input_shape().iter().product())?;
    expect_len("deconv2d output", out.len(), h_out * w_out * c_out)?;
    let lane_len = scratch_len(geom);
    let lanes = scratch_lanes("deconv2d scratch", scratch, lane_len)?;
    let pair_len = PARITIES * w_out * c_out;
    split_lanes(geom.h(), lanes, pair_len, out, lane_len, scratch).into_par_iter().for_each(|lane| {
        for (m, pair) in lane.units.zip(lane.out.chunks_exact_mut(pair_len)) {
            deconv_row_pair(packed, input, m, lane.scratch, pair);
        }
    });
    Ok(())
}
