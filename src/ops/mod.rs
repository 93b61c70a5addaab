//! The kernels (SPEC.md §7), the floor below the backend seam (issue 33): 3x3 convolution (stride 1
//! or 2), 5x5 stride-2 transposed convolution, 2x tent downsampling, channel concatenation and
//! addition, their backward passes, the layer geometry and parameters, and the network's level
//! arithmetic ([`config`]) and input ([`input`]).
//!
//! Activations are channels-last `[H, W, C]` `f32` arrays (SPEC.md §2.2); weights keep PyTorch's
//! layouts. Every op has a naive f64 `reference` implementation, kept as the oracle, and a fast
//! one checked against it (`tests/nn_kernels.rs`) within the error budget of SPEC.md §7.5. Fast
//! kernels split work over independent output rows with rayon and sum every output in a fixed
//! order, so their results are bit-identical for any thread count. Nothing here imports the
//! backend, the model or anything above them.

pub mod config;
pub mod conv2d;
pub mod deconv2d;
pub mod downsample;
pub(crate) mod gemm;
pub mod geometry;
pub mod input;
pub mod layer;
pub mod prepared;

pub use config::NetworkConfig;
pub use conv2d::{
    conv2d, conv2d_concat_into, conv2d_concat_prepared_into, conv2d_into, conv2d_prepared_into, Conv2dImpl,
};
pub use deconv2d::{deconv2d, deconv2d_into, deconv2d_prepared_into, Deconv2dImpl};
pub use downsample::{
    add, concat_channels, concat_channels_backward, concat_channels_into, downsample2x, downsample2x_at,
    downsample2x_backward, downsample2x_reference,
};
pub use geometry::{Conv2dGeometry, Deconv2dGeometry, DownsampleGeometry};
pub use input::{image_pyramid, pad_edge, padded_input};
pub use layer::{concat_conv_geometry, conv_geometry, deconv_geometry, LayerParams};
pub use prepared::{PreparedConv, PreparedDeconv};

use crate::error::{Error, Result};

/// Which kernels the network runs. Every combination is always compiled and tested.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct NetworkImpl {
    /// Convolution implementation.
    pub conv: Conv2dImpl,
    /// Transposed-convolution implementation.
    pub deconv: Deconv2dImpl,
}

impl NetworkImpl {
    /// The fast kernels (the default). In a network, `conv: Direct` runs every layer with
    /// [`Conv2dImpl::fastest_for`] its geometry: Winograd F(4x4, 3x3) for the stride-1 `32 -> 32`
    /// layers and Direct for the others, with the AVX-512F or AVX2+FMA kernels (the same bits),
    /// `Im2colGemm` on CPUs with neither; and `deconv: Direct` each transposed convolution with
    /// [`Deconv2dImpl::fastest_for`]: Winograd F(4x4, 3x3) on its equivalent convolution where a
    /// SIMD kernel runs it, else Direct (SPEC.md §7.3, §7.7, §7.11, §8.1).
    pub const FAST: NetworkImpl = NetworkImpl { conv: Conv2dImpl::Direct, deconv: Deconv2dImpl::Direct };
    /// The f64 reference kernels (the oracle; single-threaded and slow).
    pub const REFERENCE: NetworkImpl =
        NetworkImpl { conv: Conv2dImpl::Reference, deconv: Deconv2dImpl::Reference };
}

impl Default for NetworkImpl {
    fn default() -> Self {
        Self::FAST
    }
}

/// Activation fused into a kernel's output.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Activation {
    /// The identity.
    None,
    /// `max(0, x)`.
    Relu,
}

impl Activation {
    /// Applies the activation to an f32 value.
    #[inline]
    pub fn apply_f32(self, x: f32) -> f32 {
        match self {
            Activation::None => x,
            Activation::Relu => x.max(0.0),
        }
    }
    /// Applies the activation to an f64 value.
    #[inline]
    pub fn apply_f64(self, x: f64) -> f64 {
        match self {
            Activation::None => x,
            Activation::Relu => x.max(0.0),
        }
    }
}

/// Checks an array's shape against the one its geometry requires.
pub(crate) fn expect_shape(name: &str, actual: &[usize], expected: &[usize]) -> Result<()> {
    if actual == expected {
        Ok(())
    } else {
        Err(Error::invalid_argument(name, format!("shape {actual:?}, expected {expected:?}")))
    }
}

/// Checks a slice's length against the one its geometry requires.
pub(crate) fn expect_len(name: &str, actual: usize, expected: usize) -> Result<()> {
    if actual == expected {
        Ok(())
    } else {
        Err(Error::invalid_argument(name, format!("length {actual}, expected {expected}")))
    }
}

/// How many parallel lanes of `lane_len` floats fit in `scratch` (at least one, else an error).
pub(crate) fn scratch_lanes(name: &str, scratch: &[f32], lane_len: usize) -> Result<usize> {
    let lanes = scratch.len() / lane_len;
    if lanes == 0 {
        return Err(Error::invalid_argument(
            name,
            format!("length {}, need at least {lane_len}", scratch.len()),
        ));
    }
    Ok(lanes)
}

/// One parallel task of a fast kernel: a contiguous range of work units (blocks of output rows),
/// the output they write and the task's own scratch.
pub(crate) struct Lane<'a> {
    /// Work units of this lane.
    pub units: std::ops::Range<usize>,
    /// Output of those units, starting at unit `units.start`.
    pub out: &'a mut [f32],
    /// Scratch of this lane.
    pub scratch: &'a mut [f32],
}

/// Splits `n_units` work units over `lanes` contiguous ranges (lane `l` gets units
/// `[l n / L, (l + 1) n / L)`), with the matching disjoint pieces of `out` (`unit_out_len` values
/// per unit, the last unit possibly shorter) and one `scratch_lane_len` piece of `scratch` each.
/// Which lane computes a unit never changes the unit's arithmetic, so results do not depend on
/// `lanes`.
pub(crate) fn split_lanes<'a>(
    n_units: usize,
    lanes: usize,
    unit_out_len: usize,
    mut out: &'a mut [f32],
    scratch_lane_len: usize,
    mut scratch: &'a mut [f32],
) -> Vec<Lane<'a>> {
    let lanes = lanes.clamp(1, n_units.max(1));
    let mut result = Vec::with_capacity(lanes);
    for l in 0..lanes {
        let units = (l * n_units / lanes)..((l + 1) * n_units / lanes);
        let len = (units.len() * unit_out_len).min(out.len());
        let (lane_out, rest) = std::mem::take(&mut out).split_at_mut(len);
        out = rest;
        let (lane_scratch, rest) = std::mem::take(&mut scratch).split_at_mut(scratch_lane_len);
        scratch = rest;
        result.push(Lane { units, out: lane_out, scratch: lane_scratch });
    }
    result
}

/// Default number of scratch lanes for `n_units` work units: a few per rayon thread, so that work
/// stealing can balance a machine whose threads run at different speeds.
pub(crate) fn default_lanes(n_units: usize) -> usize {
    const LANES_PER_THREAD: usize = 4;
    (LANES_PER_THREAD * rayon::current_num_threads()).clamp(1, n_units.max(1))
}
