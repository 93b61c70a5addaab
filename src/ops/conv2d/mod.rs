//! 3x3 convolution, zero padding 1, stride 1 or 2, bias, optional fused ReLU (SPEC.md §7.2).
//!
//! Exactly `torch.nn.Conv2d(c_in, c_out, 3, stride, padding=1)` (a cross-correlation):
//!
//! ```text
//! out[y, x, o] = act( b[o] + Σ_{c, ky, kx} w[o, c, ky, kx] · in[s·y + ky - 1, s·x + kx - 1, c] )
//! ```
//!
//! with `in` zero outside the image. Output pixel `j` is centred on input pixel `s·j` (SPEC.md §2.1):
//!
//! ```text
//!  stride 2, w = 5:   pad  in0  in1  in2  in3  in4  pad
//!  out0 reads          [pad  in0  in1]
//!  out1 reads                    [in1  in2  in3]
//!  out2 reads                              [in3  in4  pad]
//! ```
//!
//! # Shapes
//! `input [h, w, c_in]` (channels-last), `weight [c_out, c_in, 3, 3]` (PyTorch layout), `bias
//! [c_out]`, output `[(h - 1)/s + 1, (w - 1)/s + 1, c_out]` ([`Conv2dGeometry`]).
//!
//! # Example
//! ```
//! use densefeat::ops::{conv2d, Activation, Conv2dGeometry, Conv2dImpl};
//! use ndarray::{array, Array4};
//! let x = array![[[1.0f32], [2.0], [3.0]], [[4.0], [5.0], [6.0]], [[7.0], [8.0], [9.0]]];
//! let g = Conv2dGeometry::new(3, 3, 1, 1, 1).unwrap();
//! let w = Array4::<f32>::ones((1, 1, 3, 3)); // sums each 3x3 neighbourhood
//! let y = conv2d(Conv2dImpl::Im2colGemm, &g, x.view(), w.view(), array![0.0f32].view(), Activation::None).unwrap();
//! assert_eq!(y.into_raw_vec_and_offset().0, vec![12.0, 21.0, 16.0, 27.0, 45.0, 33.0, 24.0, 39.0, 28.0]);
//! ```

pub mod backward;
pub mod backward_fast;
pub mod direct;
pub mod direct_concat;
pub mod im2col;
pub mod reference;
mod weight_grad;
pub mod winograd;

use ndarray::{Array3, ArrayView1, ArrayView3, ArrayView4};

pub use backward::{conv2d_backward_input_reference, conv2d_backward_weight_reference, relu_backward};
pub use backward_fast::{conv2d_backward_input, conv2d_backward_input_with, conv2d_backward_weight};
pub use direct::{conv2d_direct, conv2d_direct_with, DirectKernel};
pub use direct_concat::conv2d_direct_concat_with;
pub use im2col::{conv2d_im2col, scratch_len, PackedConv2d};
pub use reference::conv2d_reference;
pub use winograd::{
    conv2d_winograd, conv2d_winograd_with, winograd_budget, winograd_magnitude_reference, OutputLayout,
    PackedWinograd, WinogradKernel, WinogradTile,
};

use crate::error::Result;
use crate::ops::prepared::PreparedConv;
use crate::ops::{concat_channels, default_lanes, expect_len, expect_shape, Activation, Conv2dGeometry};
use crate::runtime::CpuFeatureLevel;

/// Which conv2d implementation to run. Every variant is always compiled and always tested.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum Conv2dImpl {
    /// Seven nested loops, f64 accumulation, one thread ([`conv2d_reference`]). The oracle.
    Reference,
    /// im2col of blocks of output rows into scratch, then `matrixmultiply::sgemm`, in parallel over
    /// the blocks ([`conv2d_im2col`]).
    Im2colGemm,
    /// Direct (implicit-GEMM) convolution, no im2col, no scratch, parallel over blocks of output
    /// rows ([`conv2d_direct`], SPEC.md §7.7). Runs the AVX-512F micro-kernel (strips of 14 pixels
    /// x 32 output channels) when the CPU has AVX-512F and `c_out = 32`, else the AVX2+FMA one
    /// (6 pixels x 16 channels) where the CPU has those, otherwise a portable Rust loop;
    /// [`direct::kernel_name`] says which.
    Direct,
    /// Winograd F(2x2, 3x3) for **stride-1** layers ([`conv2d_winograd`], SPEC.md §7.11): 2.25x fewer
    /// multiplications, parallel over tile rows, its own error budget ([`winograd_budget`]). Runs
    /// the AVX-512F kernel when the CPU has AVX-512F and `c_out` is a multiple of 32, else the AVX2+FMA one
    /// (`c_in` a multiple of 8 too), else a portable one, all with the same bits. A stride-2
    /// geometry is an [`crate::Error::InvalidArgument`].
    WinogradF2,
    /// Winograd F(4x4, 3x3), as [`Conv2dImpl::WinogradF2`] with 4x4 output tiles: 4x fewer
    /// multiplications, a larger error budget.
    WinogradF4,
}

impl Conv2dImpl {
    /// Every implementation, for tests and benches.
    pub const ALL: [Conv2dImpl; 5] = [
        Conv2dImpl::Reference,
        Conv2dImpl::Im2colGemm,
        Conv2dImpl::Direct,
        Conv2dImpl::WinogradF2,
        Conv2dImpl::WinogradF4,
    ];

    /// Whether this implementation can run `geom` (every one runs every geometry except the
    /// Winograd ones, which need stride 1).
    pub fn supports(self, geom: &Conv2dGeometry) -> bool {
        self.winograd_tile().is_none() || geom.stride() == 1
    }

    /// The Winograd variant of this implementation, if it is one.
    pub fn winograd_tile(self) -> Option<WinogradTile> {
        match self {
            Conv2dImpl::WinogradF2 => Some(WinogradTile::F2x2),
            Conv2dImpl::WinogradF4 => Some(WinogradTile::F4x4),
            _ => None,
        }
    }

    /// The fastest implementation for the network's layers (all with `c_out = 32`) on this CPU:
    /// [`Conv2dImpl::Direct`] when the CPU has AVX-512F or AVX2+FMA (its micro-kernels then run
    /// every `c_out = 32` layer faster than [`Conv2dImpl::Im2colGemm`], SPEC.md §7.7), otherwise
    /// `Im2colGemm` (Direct's portable kernel is 3-4x slower than the GEMM). [`Default`] returns
    /// this. When the geometry is known, [`Conv2dImpl::fastest_for`] also accounts for `c_out`.
    pub fn fastest() -> Conv2dImpl {
        let level = CpuFeatureLevel::get();
        if level.avx512f() || level.avx2_fma() {
            Conv2dImpl::Direct
        } else {
            Conv2dImpl::Im2colGemm
        }
    }

    /// The fastest implementation for `geom` on this CPU (SPEC.md §7.11 has the measurements):
    /// [`FASTEST_WINOGRAD`] for stride-1 layers with `c_in >= WINOGRAD_MIN_C_IN` where one of
    /// its SIMD kernels (AVX-512F, AVX2+FMA; `c_out` a multiple of 32) runs; else [`Conv2dImpl::Direct`] when
    /// one of its SIMD kernels runs `geom`; otherwise [`Conv2dImpl::Im2colGemm`].
    pub fn fastest_for(geom: &Conv2dGeometry) -> Conv2dImpl {
        Self::fastest_for_at(geom, CpuFeatureLevel::get())
    }

    /// [`Conv2dImpl::fastest_for`] at the CPU-feature level `level` (a backend passes its own).
    pub fn fastest_for_at(geom: &Conv2dGeometry, level: CpuFeatureLevel) -> Conv2dImpl {
        if geom.c_in() >= WINOGRAD_MIN_C_IN
            && WinogradKernel::select_for_at(geom, OutputLayout::Conv, level) != WinogradKernel::Portable
        {
            FASTEST_WINOGRAD
        } else if DirectKernel::select_at(geom, level) != DirectKernel::Portable {
            Conv2dImpl::Direct
        } else {
            Conv2dImpl::Im2colGemm
        }
    }
}

/// The Winograd variant [`Conv2dImpl::fastest_for`] picks (SPEC.md §7.11 has the measurements).
pub const FASTEST_WINOGRAD: Conv2dImpl = Conv2dImpl::WinogradF4;

/// The fewest input channels for which [`Conv2dImpl::fastest_for`] picks Winograd: below it the
/// transforms cost more than the saved multiplications (the network's `3 -> 32` layer).
pub const WINOGRAD_MIN_C_IN: usize = 16;

impl Default for Conv2dImpl {
    /// [`Conv2dImpl::fastest`].
    fn default() -> Self {
        Conv2dImpl::fastest()
    }
}

/// Runs the chosen implementation on f32 arrays, allocating the output and any scratch. (The
/// reference computes in f64 and rounds once to f32.)
///
/// # Errors
/// [`crate::Error::InvalidArgument`] if an array's shape disagrees with `geom`.
pub fn conv2d(
    imp: Conv2dImpl,
    geom: &Conv2dGeometry,
    input: ArrayView3<f32>,
    weight: ArrayView4<f32>,
    bias: ArrayView1<f32>,
    activation: Activation,
) -> Result<Array3<f32>> {
    let mut out = crate::util::alloc::zeroed_map(geom.output_shape());
    let Some(y) = out.as_slice_mut() else { unreachable!("a new array is contiguous") };
    conv2d_into(imp, geom, input, weight, bias, activation, y)?;
    Ok(out)
}

/// [`conv2d`] into a caller-provided output slice (`[h_out, w_out, c_out]`, row-major, every value
/// overwritten; its previous contents do not matter). The weights are packed for this call; a
/// caller that runs a layer repeatedly prepares it once ([`PreparedConv`], the CPU backend's
/// prepared layers) and calls [`conv2d_prepared_into`].
///
/// # Errors
/// [`crate::Error::InvalidArgument`] if an array's shape or `out`'s length disagrees with `geom`.
pub fn conv2d_into(
    imp: Conv2dImpl,
    geom: &Conv2dGeometry,
    input: ArrayView3<f32>,
    weight: ArrayView4<f32>,
    bias: ArrayView1<f32>,
    activation: Activation,
    out: &mut [f32],
) -> Result<()> {
    let layer = PreparedConv::from_views(weight, bias);
    conv2d_prepared_into(imp, geom, input, &layer, activation, out, CpuFeatureLevel::get())
}

/// [`conv2d_into`] with the layer's packed weights from `layer` (packed on first use, SPEC.md
/// §7.9).
///
/// # Errors
/// [`crate::Error::InvalidArgument`] if an array's shape or `out`'s length disagrees with `geom`.
#[allow(clippy::too_many_arguments)]
pub fn conv2d_prepared_into(
    imp: Conv2dImpl,
    geom: &Conv2dGeometry,
    input: ArrayView3<f32>,
    layer: &PreparedConv,
    activation: Activation,
    out: &mut [f32],
    level: CpuFeatureLevel,
) -> Result<()> {
    expect_shape("conv2d input", input.shape(), &geom.input_shape())?;
    expect_len("conv2d output", out.len(), geom.output_shape().iter().product())?;
    match imp {
        Conv2dImpl::Reference => {
            layer.check(geom)?;
            let l = layer.layer();
            let r = conv2d_reference(
                geom,
                input.mapv(f64::from).view(),
                l.weight.mapv(f64::from).view(),
                l.bias.mapv(f64::from).view(),
                activation,
            )?;
            for (o, v) in out.iter_mut().zip(r.iter()) {
                *o = *v as f32;
            }
            Ok(())
        }
        Conv2dImpl::Im2colGemm => {
            let packed = layer.packed(geom)?;
            let input = input.as_standard_layout();
            let lanes = default_lanes(im2col::n_blocks(geom));
            let mut scratch = vec![0.0; lanes * scratch_len(geom)];
            let Some(x) = input.as_slice() else { unreachable!("standard-layout arrays are contiguous") };
            conv2d_im2col(&packed, x, activation, &mut scratch, out)
        }
        Conv2dImpl::Direct => {
            let packed = layer.packed(geom)?;
            let input = input.as_standard_layout();
            let Some(x) = input.as_slice() else { unreachable!("standard-layout arrays are contiguous") };
            conv2d_direct_with(DirectKernel::select_at(geom, level), &packed, x, activation, out)
        }
        Conv2dImpl::WinogradF2 | Conv2dImpl::WinogradF4 => {
            let tile = imp.winograd_tile().unwrap_or(WinogradTile::F2x2);
            let packed = layer.winograd(tile, geom)?;
            let input = input.as_standard_layout();
            let Some(x) = input.as_slice() else { unreachable!("standard-layout arrays are contiguous") };
            let kernel = WinogradKernel::select_for_at(geom, OutputLayout::Conv, level);
            conv2d_winograd_with(kernel, &packed, x, activation, out)
        }
    }
}

/// [`conv2d_into`] on `concat(a, b)` (`a`'s channels first, SPEC.md §7.4), the input of every block
/// after the first (§8.1). [`Conv2dImpl::Direct`] never forms the concatenation: each work unit
/// stages the rows it reads ([`direct_concat`], SPEC.md §7.10), with the same bits as the direct
/// convolution of the concatenated map; the other implementations concatenate, then convolve.
///
/// # Errors
/// [`crate::Error::InvalidArgument`] if `a` and `b` differ in height or width, their channels do
/// not add up to `geom`'s input, or a shape or `out`'s length disagrees with `geom`.
#[allow(clippy::too_many_arguments)]
pub fn conv2d_concat_into(
    imp: Conv2dImpl,
    geom: &Conv2dGeometry,
    a: ArrayView3<f32>,
    b: ArrayView3<f32>,
    weight: ArrayView4<f32>,
    bias: ArrayView1<f32>,
    activation: Activation,
    out: &mut [f32],
) -> Result<()> {
    let layer = PreparedConv::from_views(weight, bias);
    conv2d_concat_prepared_into(imp, geom, a, b, &layer, activation, out, CpuFeatureLevel::get())
}

/// [`conv2d_concat_into`] with the layer's packed weights from `layer` (SPEC.md §7.9).
///
/// # Errors
/// As [`conv2d_concat_into`].
#[allow(clippy::too_many_arguments)]
pub fn conv2d_concat_prepared_into(
    imp: Conv2dImpl,
    geom: &Conv2dGeometry,
    a: ArrayView3<f32>,
    b: ArrayView3<f32>,
    layer: &PreparedConv,
    activation: Activation,
    out: &mut [f32],
    level: CpuFeatureLevel,
) -> Result<()> {
    let [h, w, c_in] = geom.input_shape();
    let (ca, cb) = (a.dim().2, b.dim().2);
    expect_shape("conv2d concat input a", a.shape(), &[h, w, ca])?;
    expect_shape("conv2d concat input b", b.shape(), &[h, w, c_in.saturating_sub(ca)])?;
    if imp != Conv2dImpl::Direct || ca == 0 || cb == 0 {
        let x = concat_channels(a, b)?;
        return conv2d_prepared_into(imp, geom, x.view(), layer, activation, out, level);
    }
    let packed = layer.packed(geom)?;
    let (a, b) = (a.as_standard_layout(), b.as_standard_layout());
    let (Some(sa), Some(sb)) = (a.as_slice(), b.as_slice()) else {
        unreachable!("standard-layout arrays are contiguous")
    };
    let kernel = DirectKernel::select_at(geom, level);
    conv2d_direct_concat_with(kernel, &packed, (sa, ca), (sb, cb), activation, out)
}
