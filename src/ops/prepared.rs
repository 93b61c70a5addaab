//! One layer's weights packed for the fast kernels, owned by whoever prepared the layer (SPEC.md
//! §7.9): the CPU backend's prepared layers ([`crate::backend::Backend::prepare_layer`]) hold
//! them for as long as the network they belong to lives, so a layer is packed once per network,
//! not once per call, and no process-wide cache exists.
//!
//! Each packing (the GEMM / direct layout, and the Winograd transforms F(2x2) and F(4x4)) is made
//! the first time an implementation needs it, from the geometry of that call, and re-targeted to
//! the geometry of every later call ([`PackedConv2d::with_geometry`] and its siblings: no copy of
//! the weights). Packing is a pure function of the weights (a permutation, or the fixed f64
//! Winograd weight transform), so a packing made once and one made per call give the same bits.
//! The weights of a prepared layer never change: training prepares its network again after each
//! optimiser step.

use std::sync::{Arc, Mutex};

use ndarray::{ArrayView1, ArrayView4};

use crate::error::Result;
use crate::ops::conv2d::{PackedConv2d, PackedWinograd, WinogradTile};
use crate::ops::deconv2d::winograd::{equivalent_geometry, pack_deconv_winograd};
use crate::ops::deconv2d::PackedDeconv2d;
use crate::ops::geometry::{Conv2dGeometry, Deconv2dGeometry};
use crate::ops::{expect_shape, LayerParams};

/// The index of a Winograd tile in the prepared layers' arrays.
fn tile_index(tile: WinogradTile) -> usize {
    match tile {
        WinogradTile::F2x2 => 0,
        WinogradTile::F4x4 => 1,
    }
}

/// A packing made on first use, behind a lock: a thread that finds it being made waits for it
/// instead of making it again (the two images of a training pair run at once on one network).
#[derive(Debug)]
struct Slot<P>(Mutex<Option<P>>);

impl<P> Default for Slot<P> {
    fn default() -> Self {
        Slot(Mutex::new(None))
    }
}

impl<P: Clone> Clone for Slot<P> {
    fn clone(&self) -> Self {
        Slot(Mutex::new(self.0.lock().unwrap_or_else(|e| e.into_inner()).clone()))
    }
}

impl<P: Clone> Slot<P> {
    /// The slot's packing re-targeted by `retarget`, or `pack()` stored there first.
    fn get(&self, pack: impl FnOnce() -> Result<P>, retarget: impl FnOnce(&P) -> Result<P>) -> Result<P> {
        let mut slot = self.0.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(p) = slot.as_ref() {
            return retarget(p);
        }
        let p = pack()?;
        *slot = Some(p.clone());
        Ok(p)
    }
}

/// A 3x3 convolution layer (`weight [c_out, c_in, 3, 3]`, `bias [c_out]`) with its packings.
#[derive(Clone, Debug)]
pub struct PreparedConv {
    layer: Arc<LayerParams>,
    gemm: Slot<PackedConv2d>,
    winograd: [Slot<PackedWinograd>; 2],
    /// The layer whose convolution is this one's input gradient at stride 1 (SPEC.md §13.2): the
    /// weights flipped and transposed, zero bias; made on first use.
    backward_input: Slot<Arc<PreparedConv>>,
}

impl PreparedConv {
    /// The layer, nothing packed yet.
    pub fn new(layer: Arc<LayerParams>) -> Self {
        PreparedConv {
            layer,
            gemm: Slot::default(),
            winograd: Default::default(),
            backward_input: Slot::default(),
        }
    }

    /// A copy of `weight` and `bias` (the plain ops' per-call layer), nothing packed yet.
    pub fn from_views(weight: ArrayView4<f32>, bias: ArrayView1<f32>) -> Self {
        Self::new(Arc::new(LayerParams { weight: weight.to_owned(), bias: bias.to_owned() }))
    }

    /// The layer whose stride-1 convolution is the input gradient of a convolution with `weight`
    /// (`[c_out, c_in, 3, 3]`): weights `w'[c, o, ky, kx] = w[o, c, 2 - ky, 2 - kx]`, zero bias
    /// (the transposed convolution as a convolution, SPEC.md §13.2).
    pub fn transposed_of(weight: ArrayView4<f32>) -> Self {
        let weight = crate::ops::conv2d::backward_fast::flipped_transposed(weight);
        let bias = ndarray::Array1::zeros(weight.shape()[0]);
        Self::new(Arc::new(LayerParams { weight, bias }))
    }

    /// The layer's parameters.
    pub fn layer(&self) -> &LayerParams {
        &self.layer
    }

    /// Checks the weight and bias against `geom`.
    pub(crate) fn check(&self, geom: &Conv2dGeometry) -> Result<()> {
        expect_shape("conv2d weight", self.layer.weight.shape(), &geom.weight_shape())?;
        expect_shape("conv2d bias", self.layer.bias.shape(), &[geom.c_out()])
    }

    /// The GEMM / direct packing ([`PackedConv2d`]) for `geom`.
    ///
    /// # Errors
    /// Weight or bias shapes that disagree with `geom`.
    pub fn packed(&self, geom: &Conv2dGeometry) -> Result<PackedConv2d> {
        self.check(geom)?;
        let l = &self.layer;
        self.gemm.get(|| PackedConv2d::new(geom, l.weight.view(), l.bias.view()), |p| p.with_geometry(geom))
    }

    /// [`PreparedConv::transposed_of`] this layer's weights, made on first use and then shared.
    pub fn backward_input(&self) -> Arc<PreparedConv> {
        let made = self
            .backward_input
            .get(|| Ok(Arc::new(Self::transposed_of(self.layer.weight.view()))), |p| Ok(p.clone()));
        made.unwrap_or_else(|_| unreachable!("making the flipped layer cannot fail"))
    }

    /// The Winograd packing ([`PackedWinograd`]) of `tile` for `geom`.
    ///
    /// # Errors
    /// Shapes that disagree with `geom`; a stride-2 geometry.
    pub fn winograd(&self, tile: WinogradTile, geom: &Conv2dGeometry) -> Result<PackedWinograd> {
        self.check(geom)?;
        let l = &self.layer;
        self.winograd[tile_index(tile)].get(
            || PackedWinograd::new(tile, geom, l.weight.view(), l.bias.view()),
            |p| p.with_geometry(geom),
        )
    }
}

/// A 5x5 stride-2 transposed convolution layer (`weight [c_in, c_out, 5, 5]`, `bias [c_out]`)
/// with its packings.
#[derive(Clone, Debug)]
pub struct PreparedDeconv {
    layer: Arc<LayerParams>,
    gemm: Slot<PackedDeconv2d>,
    winograd: [Slot<PackedWinograd>; 2],
}

impl PreparedDeconv {
    /// The layer, nothing packed yet.
    pub fn new(layer: Arc<LayerParams>) -> Self {
        PreparedDeconv { layer, gemm: Slot::default(), winograd: Default::default() }
    }

    /// A copy of `weight` and `bias` (the plain ops' per-call layer), nothing packed yet.
    pub fn from_views(weight: ArrayView4<f32>, bias: ArrayView1<f32>) -> Self {
        Self::new(Arc::new(LayerParams { weight: weight.to_owned(), bias: bias.to_owned() }))
    }

    /// The layer's parameters.
    pub fn layer(&self) -> &LayerParams {
        &self.layer
    }

    /// Checks the weight and bias against `geom`.
    pub(crate) fn check(&self, geom: &Deconv2dGeometry) -> Result<()> {
        expect_shape("deconv2d weight", self.layer.weight.shape(), &geom.weight_shape())?;
        expect_shape("deconv2d bias", self.layer.bias.shape(), &[geom.c_out()])
    }

    /// The parity packing ([`PackedDeconv2d`]) for `geom`.
    ///
    /// # Errors
    /// Weight or bias shapes that disagree with `geom`.
    pub fn packed(&self, geom: &Deconv2dGeometry) -> Result<PackedDeconv2d> {
        self.check(geom)?;
        let l = &self.layer;
        self.gemm.get(|| PackedDeconv2d::new(geom, l.weight.view(), l.bias.view()), |p| p.with_geometry(geom))
    }

    /// The Winograd packing of the equivalent convolution (SPEC.md §7.3) of `tile` for `geom`.
    ///
    /// # Errors
    /// Weight or bias shapes that disagree with `geom`.
    pub fn winograd(&self, tile: WinogradTile, geom: &Deconv2dGeometry) -> Result<PackedWinograd> {
        self.check(geom)?;
        let l = &self.layer;
        let g = equivalent_geometry(geom)?;
        self.winograd[tile_index(tile)]
            .get(|| pack_deconv_winograd(tile, geom, l.weight.view(), l.bias.view()), |p| p.with_geometry(&g))
    }
}
