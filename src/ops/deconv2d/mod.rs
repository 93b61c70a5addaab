//! 5x5 transposed convolution, stride 2, padding 2, output padding 1, bias (SPEC.md §7.3).
//!
//! Exactly `torch.nn.ConvTranspose2d(c_in, c_out, 5, stride=2, padding=2, output_padding=1)`:
//!
//! ```text
//! out[oy, ox, co] = b[co] + Σ_{ci} Σ_{(iy, ky): oy = 2 iy - 2 + ky} Σ_{(ix, kx): ox = 2 ix - 2 + kx}
//!                   in[iy, ix, ci] · w[ci, co, ky, kx]
//! ```
//!
//! Input pixel `i` spreads its (unflipped) kernel over outputs `2i - 2 ..= 2i + 2`, the centre tap
//! `k = 2` landing on `2i`, where coarse pixel `i` sits (SPEC.md §2.1). The output is `2h x 2w`;
//! contributions that would land outside it are cropped:
//!
//! ```text
//!  h = 3:      input i = 0           1           2
//!  output o:   -2 -1  0  1  2  3  4  5 |6      (o < 0 and o >= 2h = 6 are cropped)
//!  i = 0 adds  [k=0 ........ k=4]
//!  i = 1 adds         [k=0 ........ k=4]
//!  i = 2 adds               [k=0 ....... |k=4]
//! ```
//!
//! # Shapes
//! `input [h, w, c_in]`, `weight [c_in, c_out, 5, 5]` (PyTorch layout), `bias [c_out]`, output
//! `[2h, 2w, c_out]` ([`Deconv2dGeometry`]).

pub mod backward;
pub mod backward_fast;
pub mod direct;
pub mod fast;
pub mod reference;
pub mod winograd;

use ndarray::{Array3, ArrayView1, ArrayView3, ArrayView4};

pub use backward::{deconv2d_backward_input_reference, deconv2d_backward_weight_reference};
pub use backward_fast::{deconv2d_backward_input, deconv2d_backward_weight};
pub use direct::{deconv2d_direct, deconv2d_direct_with};
pub use fast::{deconv2d_fast, scratch_len, PackedDeconv2d};
pub use reference::deconv2d_reference;
pub use winograd::{
    deconv2d_winograd, deconv2d_winograd_magnitude_reference, deconv2d_winograd_with, pack_deconv_winograd,
};

use crate::error::Result;
use crate::ops::conv2d::{OutputLayout, WinogradKernel, WinogradTile, WINOGRAD_MIN_C_IN};
use crate::ops::prepared::PreparedDeconv;
use crate::ops::{default_lanes, expect_len, expect_shape, Deconv2dGeometry};
use crate::runtime::CpuFeatureLevel;

/// Which transposed-convolution implementation to run. Every variant is always compiled and tested.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum Deconv2dImpl {
    /// Scatter from the definition, f64 accumulation, one thread ([`deconv2d_reference`]).
    Reference,
    /// Gather as four parity sub-convolutions, each a GEMM, parallel over output row pairs
    /// ([`deconv2d_fast`]).
    ParityGemm,
    /// The four parity convolutions run by the direct strip kernel of the 3x3 convolution
    /// ([`deconv2d_direct`]: AVX-512F, else AVX2+FMA) where the CPU has one and `c_out = 32`;
    /// [`Deconv2dImpl::ParityGemm`] otherwise.
    Direct,
    /// The four parity convolutions as one stride-1 3x3 convolution with `4 c_out` outputs run by
    /// Winograd F(2x2, 3x3) ([`deconv2d_winograd`], SPEC.md §7.3, §7.11), each value stored at its
    /// output pixel: its own error budget ([`crate::ops::conv2d::winograd_budget`] against
    /// [`deconv2d_winograd_magnitude_reference`]). AVX-512F kernel where the CPU has it and `c_out`
    /// is a multiple of 16, else AVX2+FMA (`c_out` a multiple of 8, `c_in` too), else portable,
    /// all with the same bits.
    WinogradF2,
    /// As [`Deconv2dImpl::WinogradF2`] with F(4x4, 3x3): 0.36 of the direct multiplications.
    WinogradF4,
}

impl Deconv2dImpl {
    /// Every implementation, for tests and benches.
    pub const ALL: [Deconv2dImpl; 5] = [
        Deconv2dImpl::Reference,
        Deconv2dImpl::ParityGemm,
        Deconv2dImpl::Direct,
        Deconv2dImpl::WinogradF2,
        Deconv2dImpl::WinogradF4,
    ];

    /// The Winograd variant of this implementation, if it is one.
    pub fn winograd_tile(self) -> Option<WinogradTile> {
        match self {
            Deconv2dImpl::WinogradF2 => Some(WinogradTile::F2x2),
            Deconv2dImpl::WinogradF4 => Some(WinogradTile::F4x4),
            _ => None,
        }
    }

    /// The fastest implementation for `geom` on this CPU (SPEC.md §7.3 has the measurements):
    /// [`FASTEST_WINOGRAD_DECONV`] with `c_in >= WINOGRAD_MIN_C_IN` where one of the SIMD Winograd
    /// kernels runs the equivalent convolution, else [`Deconv2dImpl::Direct`] (which falls back to
    /// [`Deconv2dImpl::ParityGemm`] itself).
    pub fn fastest_for(geom: &Deconv2dGeometry) -> Deconv2dImpl {
        Self::fastest_for_at(geom, CpuFeatureLevel::get())
    }

    /// [`Deconv2dImpl::fastest_for`] at the CPU-feature level `level` (a backend passes its own).
    pub fn fastest_for_at(geom: &Deconv2dGeometry, level: CpuFeatureLevel) -> Deconv2dImpl {
        let simd = winograd::equivalent_geometry(geom).is_ok_and(|g| {
            WinogradKernel::select_for_at(&g, OutputLayout::Deconv, level) != WinogradKernel::Portable
        });
        if simd && geom.c_in() >= WINOGRAD_MIN_C_IN {
            FASTEST_WINOGRAD_DECONV
        } else {
            Deconv2dImpl::Direct
        }
    }
}

/// The Winograd variant [`Deconv2dImpl::fastest_for`] picks.
pub const FASTEST_WINOGRAD_DECONV: Deconv2dImpl = Deconv2dImpl::WinogradF4;

/// Runs the chosen implementation on f32 arrays, allocating the output and any scratch. (The
/// reference computes in f64 and rounds once to f32.)
///
/// # Errors
/// [`crate::Error::InvalidArgument`] if an array's shape disagrees with `geom`.
pub fn deconv2d(
    imp: Deconv2dImpl,
    geom: &Deconv2dGeometry,
    input: ArrayView3<f32>,
    weight: ArrayView4<f32>,
    bias: ArrayView1<f32>,
) -> Result<Array3<f32>> {
    let mut out = crate::util::alloc::zeroed_map(geom.output_shape());
    let Some(y) = out.as_slice_mut() else { unreachable!("a new array is contiguous") };
    deconv2d_into(imp, geom, input, weight, bias, None, y)?;
    Ok(out)
}

/// [`deconv2d`] into a caller-provided output slice (`[2h, 2w, c_out]`, row-major, every value
/// overwritten), plus `skip` (same length) when given: `out = skip + deconv` (the U-Net sum, one
/// f32 addition per value, fused into the store by [`Deconv2dImpl::Direct`], a second pass
/// otherwise; the same bits either way). The weights are packed for this call; a caller that runs
/// a layer repeatedly prepares it once ([`PreparedDeconv`]) and calls [`deconv2d_prepared_into`].
///
/// # Errors
/// [`crate::Error::InvalidArgument`] if an array's shape or a slice's length disagrees with `geom`.
pub fn deconv2d_into(
    imp: Deconv2dImpl,
    geom: &Deconv2dGeometry,
    input: ArrayView3<f32>,
    weight: ArrayView4<f32>,
    bias: ArrayView1<f32>,
    skip: Option<&[f32]>,
    out: &mut [f32],
) -> Result<()> {
    let layer = PreparedDeconv::from_views(weight, bias);
    deconv2d_prepared_into(imp, geom, input, &layer, skip, out, CpuFeatureLevel::get())
}

/// [`deconv2d_into`] with the layer's packed weights from `layer` (packed on first use, SPEC.md
/// §7.9).
///
/// # Errors
/// As [`deconv2d_into`].
pub fn deconv2d_prepared_into(
    imp: Deconv2dImpl,
    geom: &Deconv2dGeometry,
    input: ArrayView3<f32>,
    layer: &PreparedDeconv,
    skip: Option<&[f32]>,
    out: &mut [f32],
    level: CpuFeatureLevel,
) -> Result<()> {
    expect_shape("deconv2d input", input.shape(), &geom.input_shape())?;
    expect_len("deconv2d output", out.len(), geom.output_shape().iter().product())?;
    if let Some(s) = skip {
        expect_len("deconv2d skip", s.len(), out.len())?;
    }
    match imp {
        Deconv2dImpl::Reference => {
            layer.check(geom)?;
            let l = layer.layer();
            let r = deconv2d_reference(
                geom,
                input.mapv(f64::from).view(),
                l.weight.mapv(f64::from).view(),
                l.bias.mapv(f64::from).view(),
            )?;
            for (o, v) in out.iter_mut().zip(r.iter()) {
                *o = *v as f32;
            }
        }
        Deconv2dImpl::Direct if direct::supported_at(geom, level) => {
            let packed = layer.packed(geom)?;
            let input = input.as_standard_layout();
            let Some(x) = input.as_slice() else { unreachable!("standard-layout arrays are contiguous") };
            return deconv2d_direct_with(direct::select_at(geom, level), &packed, x, skip, out);
        }
        Deconv2dImpl::WinogradF2 | Deconv2dImpl::WinogradF4 => {
            let tile = imp.winograd_tile().unwrap_or(WinogradTile::F2x2);
            let packed = layer.winograd(tile, geom)?;
            let input = input.as_standard_layout();
            let Some(x) = input.as_slice() else { unreachable!("standard-layout arrays are contiguous") };
            let kernel = WinogradKernel::select_for_at(packed.geometry(), OutputLayout::Deconv, level);
            return deconv2d_winograd_with(kernel, &packed, x, skip, out);
        }
        Deconv2dImpl::ParityGemm | Deconv2dImpl::Direct => {
            let packed = layer.packed(geom)?;
            let input = input.as_standard_layout();
            let lanes = default_lanes(geom.h());
            let mut scratch = vec![0.0; lanes * scratch_len(geom)];
            let Some(x) = input.as_slice() else { unreachable!("standard-layout arrays are contiguous") };
            deconv2d_fast(&packed, x, &mut scratch, out)?;
        }
    }
    if let Some(s) = skip {
        // The separate `add`'s arithmetic: one f32 addition per value (commutative, so the
        // same bits as `skip + up`).
        for (o, &k) in out.iter_mut().zip(s) {
            *o += k;
        }
    }
    Ok(())
}
