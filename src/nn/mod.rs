//! The feature network's kernels (SPEC.md §7): 3x3 convolution (stride 1 or 2), 5x5 stride-2
//! transposed convolution, 2x tent downsampling of the image, channel concatenation and addition.
//!
//! Activations are channels-last `[H, W, C]` `f32` arrays (SPEC.md §2.2); weights keep PyTorch's
//! layouts. Every op has a naive f64 `reference` implementation, kept as the oracle, and a fast
//! one checked against it (`tests/nn_kernels.rs`) within the error budget of SPEC.md §7.5. Fast
//! kernels split work over independent output rows with rayon and sum every output in a fixed
//! order, so their results are bit-identical for any thread count.
//!
//! The network itself (SPEC.md §8): [`config`] (hyper-parameters and level arithmetic),
//! [`weights`] (PyTorch names, Xavier init, safetensors), [`network`] (the forward pass),
//! [`budget`] (the network-level error bound) and [`viz`] (a PCA colouring of features).

pub mod alloc;
pub mod budget;
pub mod config;
pub mod conv2d;
pub mod deconv2d;
pub mod downsample;
pub(crate) mod gemm;
pub mod geometry;
pub mod network;
pub mod pack_cache;
pub mod profile;
pub mod viz;
pub mod weights;

pub use config::NetworkConfig;
pub use conv2d::{conv2d, conv2d_concat_into, conv2d_into, Conv2dImpl};
pub use deconv2d::{deconv2d, deconv2d_into, Deconv2dImpl};
pub use downsample::{
    add, concat_channels, concat_channels_backward, concat_channels_into, downsample2x,
    downsample2x_backward, downsample2x_reference,
};
pub use geometry::{Conv2dGeometry, Deconv2dGeometry, DownsampleGeometry};
pub use network::{FeatureNet, ForwardOutput, NetworkImpl};
pub use profile::{profile_forward, OpTotals};
pub use weights::NetworkWeights;

use crate::error::{Error, Result};

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
