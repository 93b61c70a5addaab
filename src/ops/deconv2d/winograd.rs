//! The transposed convolution by Winograd (SPEC.md §7.3, §7.11): the four parity convolutions of
//! [`super`] as **one** stride-1 3x3 convolution of the input with `4 c_out` outputs, run by the
//! Winograd kernels of [`crate::ops::conv2d::winograd`] with [`OutputLayout::Deconv`].
//!
//! Output row `o = 2m + q` takes input rows `i = m + d` with tap `k = 2 + q - 2d` (`q = 0`: `d = -1,
//! 0, 1`, `k = 4, 2, 0`; `q = 1`: `d = 0, 1`, `k = 3, 1`). A 3x3 window at `m - 1 ..= m + 1` covers
//! both, the odd parity's first tap being zero. So with parity `p = 2 q_y + q_x` the equivalent
//! convolution has weights
//!
//! ```text
//! E[p c_out + o, c, j_y, j_x] = w[c, o, k(q_y, j_y), k(q_x, j_x)]   (k(q, j) = 4 + q - 2j; 0 if 5)
//! ```
//!
//! and bias `b[o]` for each parity; its value `(m, n, p c_out + o)` is the transposed convolution's
//! output `(2m + q_y, 2n + q_x, o)`, which the kernels store there directly (plus the U-Net skip
//! value when given, one f32 addition). One input transform serves all four parities; the 9-tap
//! window of the 2-tap parities wastes `1 - 25/36` of the products, and F(4x4, 3x3) still needs
//! `36 / (16 · 25/4) = 0.36` of the direct transposed convolution's multiplications.

use ndarray::{Array1, Array3, Array4, ArrayView1, ArrayView3, ArrayView4};

use crate::error::{Error, Result};
use crate::ops::conv2d::winograd::{dispatch, OutputLayout};
use crate::ops::conv2d::{winograd_magnitude_reference, PackedWinograd, WinogradKernel, WinogradTile};
use crate::ops::{expect_len, expect_shape, Activation, Conv2dGeometry, Deconv2dGeometry};

/// The 5x5 tap that window position `j` (input `m + j - 1`) gives output parity `q`, if any.
const fn tap(q: usize, j: usize) -> Option<usize> {
    let k = 4 + q - 2 * j;
    if k < 5 {
        Some(k)
    } else {
        None
    }
}

/// The equivalent convolution: `h x w`, `c_in -> 4 c_out`, stride 1.
///
/// # Errors
/// As [`Conv2dGeometry::new`].
pub fn equivalent_geometry(geom: &Deconv2dGeometry) -> Result<Conv2dGeometry> {
    Conv2dGeometry::new(geom.h(), geom.w(), geom.c_in(), 4 * geom.c_out(), 1)
}

/// The equivalent convolution's weights `[4 c_out, c_in, 3, 3]` from the transposed convolution's
/// `[c_in, c_out, 5, 5]` (module docs); `A::default()` (zero) for the missing taps.
pub fn equivalent_weight<A: Copy + Default>(weight: ArrayView4<A>) -> Array4<A> {
    let (c_in, c_out) = (weight.shape()[0], weight.shape()[1]);
    Array4::from_shape_fn((4 * c_out, c_in, 3, 3), |(po, c, jy, jx)| {
        let (p, o) = (po / c_out, po % c_out);
        match (tap(p / 2, jy), tap(p % 2, jx)) {
            (Some(ky), Some(kx)) => weight[[c, o, ky, kx]],
            _ => A::default(),
        }
    })
}

/// The equivalent convolution's bias: `b` once per parity.
pub fn equivalent_bias<A: Copy>(bias: ArrayView1<A>) -> Array1<A> {
    let c = bias.len();
    Array1::from_shape_fn(4 * c, |i| bias[i % c])
}

/// Transforms a transposed convolution's weights `[c_in, c_out, 5, 5]` and bias `[c_out]` for
/// `tile` ([`PackedWinograd::new`] on the equivalent convolution), outputs in the
/// [`OutputLayout::Deconv`] layout.
///
/// # Errors
/// [`Error::InvalidArgument`] if a shape disagrees with `geom`.
pub fn pack_deconv_winograd(
    tile: WinogradTile,
    geom: &Deconv2dGeometry,
    weight: ArrayView4<f32>,
    bias: ArrayView1<f32>,
) -> Result<PackedWinograd> {
    expect_shape("deconv2d weight", weight.shape(), &geom.weight_shape())?;
    expect_shape("deconv2d bias", bias.shape(), &[geom.c_out()])?;
    let g = equivalent_geometry(geom)?;
    let packed =
        PackedWinograd::new(tile, &g, equivalent_weight(weight).view(), equivalent_bias(bias).view())?;
    Ok(packed.with_layout(OutputLayout::Deconv))
}

/// The transposed convolution of a channels-last input slice `[h, w, c_in]` into `out` (`[2h, 2w,
/// c_out]`, fully overwritten), plus `skip` (same length) when given, with the best Winograd
/// kernel for this CPU, parallel over tile rows. Returns the kernel that ran.
///
/// # Errors
/// [`Error::InvalidArgument`] if `packed` is not a transposed convolution's
/// ([`pack_deconv_winograd`]) or a slice has the wrong length.
pub fn deconv2d_winograd(
    packed: &PackedWinograd,
    input: &[f32],
    skip: Option<&[f32]>,
    out: &mut [f32],
) -> Result<WinogradKernel> {
    let kernel = WinogradKernel::select_for(packed.geometry(), OutputLayout::Deconv);
    deconv2d_winograd_with(kernel, packed, input, skip, out)?;
    Ok(kernel)
}

/// [`deconv2d_winograd`] with a chosen kernel.
///
/// # Errors
/// As [`deconv2d_winograd`], and if `kernel` cannot run this geometry on this CPU
/// ([`WinogradKernel::supports_layout`]).
pub fn deconv2d_winograd_with(
    kernel: WinogradKernel,
    packed: &PackedWinograd,
    input: &[f32],
    skip: Option<&[f32]>,
    out: &mut [f32],
) -> Result<()> {
    if packed.layout() != OutputLayout::Deconv {
        return Err(Error::invalid_argument(
            "deconv2d Winograd weights",
            "packed for a convolution (use pack_deconv_winograd)",
        ));
    }
    let g = packed.geometry();
    let [h, w, c_in] = g.input_shape();
    expect_len("deconv2d input", input.len(), h * w * c_in)?;
    // [2h, 2w, c_out / 4]: as many values as the equivalent convolution's [h, w, c_out].
    expect_len("deconv2d output", out.len(), h * w * g.c_out())?;
    if let Some(s) = skip {
        expect_len("deconv2d skip", s.len(), out.len())?;
    }
    dispatch(kernel, packed, input, Activation::None, skip, out)
}

/// `M_W` of [`crate::ops::conv2d::winograd_magnitude_reference`] for the transposed convolution:
/// that of the equivalent convolution (module docs), each value at its output pixel. Plain f64
/// loops; takes absolute values itself.
///
/// # Errors
/// [`Error::InvalidArgument`] if a shape disagrees with `geom`.
pub fn deconv2d_winograd_magnitude_reference(
    tile: WinogradTile,
    geom: &Deconv2dGeometry,
    input: ArrayView3<f64>,
    weight: ArrayView4<f64>,
    bias: ArrayView1<f64>,
) -> Result<Array3<f64>> {
    expect_shape("deconv2d weight", weight.shape(), &geom.weight_shape())?;
    expect_shape("deconv2d bias", bias.shape(), &[geom.c_out()])?;
    let g = equivalent_geometry(geom)?;
    let m = winograd_magnitude_reference(
        tile,
        &g,
        input,
        equivalent_weight(weight).view(),
        equivalent_bias(bias).view(),
    )?;
    let c = geom.c_out();
    Ok(Array3::from_shape_fn(geom.output_shape(), |(oy, ox, o)| {
        m[[oy / 2, ox / 2, (2 * (oy % 2) + ox % 2) * c + o]]
    }))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn taps_follow_the_parity_rule() {
        // Output o = 2m + q, window position j reads input i = m + j - 1, whose tap on o is
        // k = o - 2i + 2 (SPEC.md §7.3: input i spreads over 2i - 2 ..= 2i + 2).
        for m in 0..4isize {
            for q in 0..2 {
                for j in 0..3 {
                    let (o, i) = (2 * m + q as isize, m + j as isize - 1);
                    let k = o - 2 * i + 2;
                    let want = (0..5).contains(&k).then_some(k as usize);
                    assert_eq!(tap(q, j), want, "m {m} q {q} j {j}");
                }
            }
        }
    }
}
