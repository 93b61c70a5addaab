//! [`Conv2dImpl::Direct`](super::Conv2dImpl::Direct) on the channel concatenation of two maps,
//! without forming it (SPEC.md §7.10): the network's blocks after the first convolve
//! `concat(out_{k-1}, image)` (§8.1), and writing that map (43 MB at 640x480) cost 6-9 % of a pass.
//!
//! Each parallel work unit (a block of output rows) first copies the input rows it reads,
//! concatenated, into a staging buffer of its own (a few hundred KB, so it stays in L2), then runs
//! the direct kernel's row function on that window of rows:
//!
//! ```text
//!  a [h, w, ca] ─┐  rows s y0 - 1 ..= s (y1 - 1) + 1  ┌──────────────────────┐
//!                ├───────────────────────────────────►│ staging [rows, w, c] │──► conv rows y0 .. y1
//!  b [h, w, cb] ─┘  (clipped to the image)            └──────────────────────┘
//! ```
//!
//! The staged rows are bit-for-bit the rows of `concat(a, b)`, and the row function reads them at
//! the same offsets relative to the window, so every output has exactly the bits of
//! [`conv2d_direct_with`](super::conv2d_direct_with) on the concatenated map (same kernel, same
//! summation order). Work units are fixed by the geometry, so results do not depend on the thread
//! count.

use rayon::prelude::*;

use super::direct::{rows_per_block, DirectKernel};
use super::PackedConv2d;
use crate::error::{Error, Result};
use crate::ops::geometry::{Conv2dGeometry, CONV_KERNEL, CONV_PADDING};
use crate::ops::{expect_len, Activation};

/// Output rows per work unit at least this many input rows' worth, so that the rows shared by
/// neighbouring output rows (one per output row at stride 2, two at stride 1) are staged once per
/// unit rather than once per output row.
const MIN_STAGED_ROWS: usize = 8;

/// Output rows per work unit of [`conv2d_direct_concat_with`] (fixed by the geometry).
pub fn concat_rows_per_block(geom: &Conv2dGeometry) -> usize {
    let s = geom.stride();
    rows_per_block(geom).max(MIN_STAGED_ROWS.div_ceil(s)).min(geom.h_out())
}

/// Input rows `lo .. hi` that output rows `y0 .. y1` read (clipped to the image).
fn input_rows(geom: &Conv2dGeometry, y0: usize, y1: usize) -> (usize, usize) {
    let s = geom.stride();
    let lo = (s * y0).saturating_sub(CONV_PADDING);
    let hi = (s * (y1 - 1) + CONV_KERNEL - CONV_PADDING).min(geom.h());
    (lo, hi)
}

/// Copies rows `lo .. hi` of `concat(a, b)` into `dst` (`(hi - lo) w (ca + cb)` floats).
fn stage_rows(
    a: &[f32],
    ca: usize,
    b: &[f32],
    cb: usize,
    w: usize,
    (lo, hi): (usize, usize),
    dst: &mut [f32],
) {
    let c = ca + cb;
    let pixels = lo * w..hi * w;
    let (a, b) = (&a[pixels.start * ca..pixels.end * ca], &b[pixels.start * cb..pixels.end * cb]);
    for ((px, pa), pb) in dst.chunks_exact_mut(c).zip(a.chunks_exact(ca)).zip(b.chunks_exact(cb)) {
        px[..ca].copy_from_slice(pa);
        px[ca..].copy_from_slice(pb);
    }
}

/// The direct convolution of `concat(a, b)` (channels-last `[h, w, ca]` and `[h, w, cb]`, `a`'s
/// channels first, `ca + cb = c_in`) into `out` (`[h_out, w_out, c_out]`, fully overwritten) with
/// `kernel`, parallel over blocks of output rows ([`concat_rows_per_block`]). Bit-identical to
/// [`super::conv2d_direct_with`] on the concatenated map.
///
/// # Errors
/// [`Error::InvalidArgument`] if `ca` or `cb` is zero, `ca + cb != c_in`, a slice has the wrong
/// length, or `kernel` cannot run this geometry on this CPU ([`DirectKernel::supports`]).
pub fn conv2d_direct_concat_with(
    kernel: DirectKernel,
    packed: &PackedConv2d,
    (a, ca): (&[f32], usize),
    (b, cb): (&[f32], usize),
    activation: Activation,
    out: &mut [f32],
) -> Result<()> {
    let geom = packed.geometry();
    let [h, w, c_in] = geom.input_shape();
    let [_, w_out, c_out] = geom.output_shape();
    if ca == 0 || cb == 0 || ca + cb != c_in {
        return Err(Error::invalid_argument(
            "conv2d concat channels",
            format!("{ca} + {cb}, expected two non-zero parts of c_in = {c_in}"),
        ));
    }
    expect_len("conv2d concat input a", a.len(), h * w * ca)?;
    expect_len("conv2d concat input b", b.len(), h * w * cb)?;
    expect_len("conv2d output", out.len(), geom.output_shape().iter().product())?;
    kernel.check(geom)?;
    let row_len = w_out * c_out;
    let rows = concat_rows_per_block(geom);
    out.par_chunks_mut(rows * row_len).enumerate().for_each_init(Vec::new, |staging, (blk, block)| {
        let y0 = blk * rows;
        let y1 = y0 + block.len() / row_len;
        let (lo, hi) = input_rows(geom, y0, y1);
        staging.resize((hi - lo) * w * c_in, 0.0);
        stage_rows(a, ca, b, cb, w, (lo, hi), staging);
        for (i, out_row) in block.chunks_exact_mut(row_len).enumerate() {
            // SAFETY: `check` passed; `staging` holds input rows lo .. hi, which include every row
            // output row y0 + i reads (input_rows), and out_row holds w_out · c_out floats.
            unsafe { kernel.conv_row(packed, staging, lo, y0 + i, activation, out_row) };
        }
    });
    Ok(())
}
