//! [`Observed`]: a backend that runs every op on another backend and reports each network op to an
//! [`Observer`] with its inputs, output and wall time (SPEC.md §15.1). The forward pass
//! ([`crate::nn::network::run_network`]) takes a `&dyn Backend`, so the training tape, the per-op
//! profiler and the per-layer error check are observers on the product's own path: the same ops,
//! the same bits, nothing re-implemented.

use std::fmt::Debug;
use std::sync::{Arc, Mutex};
use std::time::Instant;

use ndarray::{Array3, ArrayView3};

use super::{Backend, LayerOp, PreparedLayer, Tensor, Traffic, VolumeBuilder};
use crate::costvolume::WtaDepth;
use crate::dtam::{DtamProblem, DtamReport, DtamResult};
use crate::error::Result;
use crate::geometry::{InverseDepthBins, PinholeCamera};
use crate::ops::{Activation, LayerParams, NetworkConfig};

/// One network op as [`Observed`] ran it, with its inputs and output. In every variant `output`
/// is the op's result, `layer` the prepared layer, `stride` and `act` the convolution's.
#[derive(Clone, Copy, Debug)]
#[allow(missing_docs)] // the fields are named for the op's arguments (see the variant's op)
pub enum NetworkOp<'a> {
    /// [`Backend::image_pyramid`]: the levels.
    Pyramid(&'a [Tensor]),
    /// [`Backend::conv3x3`] (or its reusing form) of `input`.
    Conv { input: &'a Tensor, layer: &'a PreparedLayer, stride: usize, act: Activation, output: &'a Tensor },
    /// [`Backend::conv3x3_concat`]: the convolution of `concat(a, b)`, which the backend may never
    /// form (SPEC.md §7.10).
    ConcatConv {
        a: &'a Tensor,
        b: &'a Tensor,
        layer: &'a PreparedLayer,
        stride: usize,
        act: Activation,
        output: &'a Tensor,
    },
    /// [`Backend::deconv5x5s2`].
    Deconv { input: &'a Tensor, layer: &'a PreparedLayer, output: &'a Tensor },
    /// [`Backend::deconv5x5s2_add`] (or its reusing form): `skip + deconv(input)`.
    DeconvAdd { input: &'a Tensor, layer: &'a PreparedLayer, skip: &'a Tensor, output: &'a Tensor },
    /// [`Backend::downsample2x`].
    Downsample { input: &'a Tensor, output: &'a Tensor },
    /// [`Backend::concat`] (or its reusing form).
    Concat { a: &'a Tensor, b: &'a Tensor, output: &'a Tensor },
    /// [`Backend::add`].
    Add { a: &'a Tensor, b: &'a Tensor, output: &'a Tensor },
    /// [`Backend::crop`] of `input` (before the crop).
    Crop { input: &'a Tensor, output: &'a Tensor },
}

/// What an [`Observed`] backend reports to.
pub trait Observer: Send {
    /// `op` ran, taking `seconds` of wall time (its output is in `op`). An observer that finds
    /// something wrong records it; it cannot fail the op.
    fn observe(&mut self, op: NetworkOp<'_>, seconds: f64);
}

/// `inner` with every network op reported to `observer`; the mapping ops (cost volume, WTA, DTAM)
/// pass through unobserved. It has `inner`'s name, so layers prepared by `inner` run on it.
pub struct Observed<'a, O> {
    inner: &'a dyn Backend,
    observer: Mutex<O>,
}

impl<'a, O: Observer> Observed<'a, O> {
    /// `inner`, observed by `observer`.
    pub fn new(inner: &'a dyn Backend, observer: O) -> Self {
        Self { inner, observer: Mutex::new(observer) }
    }

    /// The observer, with everything it recorded.
    pub fn into_observer(self) -> O {
        self.observer.into_inner().unwrap_or_else(|e| e.into_inner())
    }

    /// Runs `f` on the inner backend, timed.
    fn timed<T>(&self, f: impl FnOnce(&dyn Backend) -> Result<T>) -> Result<(T, f64)> {
        let start = Instant::now();
        let out = f(self.inner)?;
        Ok((out, start.elapsed().as_secs_f64()))
    }

    fn report(&self, op: NetworkOp<'_>, seconds: f64) {
        self.observer.lock().unwrap_or_else(|e| e.into_inner()).observe(op, seconds);
    }
}

impl<O> Debug for Observed<'_, O> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Observed").field("inner", &self.inner.name()).finish()
    }
}

impl<O: Observer> Backend for Observed<'_, O> {
    fn name(&self) -> &'static str {
        self.inner.name()
    }
    fn device(&self) -> String {
        self.inner.device()
    }
    fn cpu_level(&self) -> crate::runtime::CpuFeatureLevel {
        self.inner.cpu_level()
    }
    fn upload(&self, x: ArrayView3<f32>) -> Result<Tensor> {
        self.inner.upload(x)
    }
    fn upload_owned(&self, x: Array3<f32>) -> Result<Tensor> {
        self.inner.upload_owned(x)
    }
    fn download(&self, x: &Tensor) -> Result<Array3<f32>> {
        self.inner.download(x)
    }
    fn synchronize(&self) -> Result<()> {
        self.inner.synchronize()
    }
    fn traffic(&self) -> Traffic {
        self.inner.traffic()
    }
    fn prepare_layer(&self, layer: Arc<LayerParams>, op: LayerOp) -> Result<PreparedLayer> {
        self.inner.prepare_layer(layer, op)
    }

    fn conv3x3(&self, x: &Tensor, layer: &PreparedLayer, stride: usize, act: Activation) -> Result<Tensor> {
        let (output, s) = self.timed(|b| b.conv3x3(x, layer, stride, act))?;
        self.report(NetworkOp::Conv { input: x, layer, stride, act, output: &output }, s);
        Ok(output)
    }
    fn conv3x3_reusing(
        &self,
        x: &Tensor,
        layer: &PreparedLayer,
        stride: usize,
        act: Activation,
        spare: Option<Tensor>,
    ) -> Result<Tensor> {
        let (output, s) = self.timed(|b| b.conv3x3_reusing(x, layer, stride, act, spare))?;
        self.report(NetworkOp::Conv { input: x, layer, stride, act, output: &output }, s);
        Ok(output)
    }
    fn conv3x3_concat(
        &self,
        a: &Tensor,
        b: &Tensor,
        layer: &PreparedLayer,
        stride: usize,
        act: Activation,
        spare: Option<Tensor>,
    ) -> Result<Tensor> {
        let (output, s) = self.timed(|be| be.conv3x3_concat(a, b, layer, stride, act, spare))?;
        self.report(NetworkOp::ConcatConv { a, b, layer, stride, act, output: &output }, s);
        Ok(output)
    }
    fn deconv5x5s2(&self, x: &Tensor, layer: &PreparedLayer) -> Result<Tensor> {
        let (output, s) = self.timed(|b| b.deconv5x5s2(x, layer))?;
        self.report(NetworkOp::Deconv { input: x, layer, output: &output }, s);
        Ok(output)
    }
    fn deconv5x5s2_add(&self, x: &Tensor, layer: &PreparedLayer, skip: &Tensor) -> Result<Tensor> {
        let (output, s) = self.timed(|b| b.deconv5x5s2_add(x, layer, skip))?;
        self.report(NetworkOp::DeconvAdd { input: x, layer, skip, output: &output }, s);
        Ok(output)
    }
    fn deconv5x5s2_add_reusing(
        &self,
        x: &Tensor,
        layer: &PreparedLayer,
        skip: &Tensor,
        spare: Option<Tensor>,
    ) -> Result<Tensor> {
        let (output, s) = self.timed(|b| b.deconv5x5s2_add_reusing(x, layer, skip, spare))?;
        self.report(NetworkOp::DeconvAdd { input: x, layer, skip, output: &output }, s);
        Ok(output)
    }
    fn downsample2x(&self, x: &Tensor) -> Result<Tensor> {
        let (output, s) = self.timed(|b| b.downsample2x(x))?;
        self.report(NetworkOp::Downsample { input: x, output: &output }, s);
        Ok(output)
    }
    fn concat(&self, a: &Tensor, b: &Tensor) -> Result<Tensor> {
        let (output, s) = self.timed(|be| be.concat(a, b))?;
        self.report(NetworkOp::Concat { a, b, output: &output }, s);
        Ok(output)
    }
    fn concat_reusing(&self, a: &Tensor, b: &Tensor, spare: Option<Tensor>) -> Result<Tensor> {
        let (output, s) = self.timed(|be| be.concat_reusing(a, b, spare))?;
        self.report(NetworkOp::Concat { a, b, output: &output }, s);
        Ok(output)
    }
    fn add(&self, a: &Tensor, b: &Tensor) -> Result<Tensor> {
        let (output, s) = self.timed(|be| be.add(a, b))?;
        self.report(NetworkOp::Add { a, b, output: &output }, s);
        Ok(output)
    }
    fn crop(&self, x: Tensor, h: usize, w: usize) -> Result<Tensor> {
        let input = x.clone();
        let (output, s) = self.timed(|b| b.crop(x, h, w))?;
        self.report(NetworkOp::Crop { input: &input, output: &output }, s);
        Ok(output)
    }
    fn image_pyramid(
        &self,
        config: &NetworkConfig,
        image: ArrayView3<f32>,
        max_level: usize,
    ) -> Result<Vec<Tensor>> {
        let (levels, s) = self.timed(|b| b.image_pyramid(config, image, max_level))?;
        self.report(NetworkOp::Pyramid(&levels), s);
        Ok(levels)
    }

    fn cost_volume(
        &self,
        reference: &Tensor,
        camera: PinholeCamera,
        bins: InverseDepthBins,
        truncation: f32,
    ) -> Result<Box<dyn VolumeBuilder>> {
        self.inner.cost_volume(reference, camera, bins, truncation)
    }
    fn winner_take_all(&self, costs: ArrayView3<f32>, bins: &InverseDepthBins) -> Result<WtaDepth> {
        self.inner.winner_take_all(costs, bins)
    }
    fn dtam_solve(&self, problem: &DtamProblem) -> Result<(DtamResult, DtamReport)> {
        self.inner.dtam_solve(problem)
    }
}
