//! One layer's parameters and the validated geometry of a layer on a map (SPEC.md §7.1, §8.3).

use ndarray::{Array1, Array4};

use crate::error::Result;
use crate::ops::geometry::{Conv2dGeometry, Deconv2dGeometry};

/// Weight and bias of one (transposed) convolution, in PyTorch layout.
#[derive(Clone, Debug, PartialEq)]
pub struct LayerParams {
    /// `[c_out, c_in, 3, 3]` (convolution) or `[c_in, c_out, 5, 5]` (transposed convolution).
    pub weight: Array4<f32>,
    /// `[c_out]`.
    pub bias: Array1<f32>,
}

/// The validated geometry of `layer` (a 3x3 conv, weight `[c_out, c_in, 3, 3]`) applied to a map
/// of shape `(h, w, c_in)`.
///
/// # Errors
/// [`crate::Error::InvalidArgument`] for an empty map or a bad stride.
pub fn conv_geometry(
    (h, w, c_in): (usize, usize, usize),
    layer: &LayerParams,
    stride: usize,
) -> Result<Conv2dGeometry> {
    Conv2dGeometry::new(h, w, c_in, layer.weight.shape()[0], stride)
}

/// The validated geometry of `layer` applied to `concat(a, b)` (shapes `(h, w, ca)`, `(h, w, cb)`):
/// [`conv_geometry`] of `(h, w, ca + cb)`; the spatial match is the concatenation's to check.
///
/// # Errors
/// As [`conv_geometry`].
pub fn concat_conv_geometry(
    (h, w, ca): (usize, usize, usize),
    (_, _, cb): (usize, usize, usize),
    layer: &LayerParams,
    stride: usize,
) -> Result<Conv2dGeometry> {
    conv_geometry((h, w, ca + cb), layer, stride)
}

/// The validated geometry of `layer` (a 5x5 transposed conv, weight `[c_in, c_out, 5, 5]`) on a
/// map of shape `(h, w, c_in)`.
///
/// # Errors
/// [`crate::Error::InvalidArgument`] for an empty map.
pub fn deconv_geometry((h, w, c_in): (usize, usize, usize), layer: &LayerParams) -> Result<Deconv2dGeometry> {
    Deconv2dGeometry::new(h, w, c_in, layer.weight.shape()[1])
}
