//! Where a forward pass spends its time: an [`Executor`] that runs the fast kernels and times each
//! operation, grouped by kind (`densefeat bench forward --profile`).

use std::collections::BTreeMap;
use std::time::Instant;

use ndarray::{Array3, ArrayView3};

use super::network::{run_features, Executor, PooledExecutor};
use super::FeatureNet;
use crate::backend::{Backend, PreparedLayer, Tensor};
use crate::error::Result;
use crate::ops::Activation;
use crate::ops::{concat_conv_geometry, conv_geometry, deconv_geometry};

/// Accumulated time and FLOPs of one kind of operation.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct OpTotals {
    /// Calls.
    pub calls: usize,
    /// Wall time, milliseconds.
    pub ms: f64,
    /// Floating-point operations (multiply and add each count one).
    pub flops: f64,
}

/// Times every operation of the fast kernels.
#[derive(Debug)]
pub struct ProfileExecutor<'a> {
    inner: PooledExecutor<'a>,
    /// Totals per operation kind (e.g. `conv s1 32->32`).
    pub totals: BTreeMap<String, OpTotals>,
}

impl<'a> ProfileExecutor<'a> {
    /// A profiler around `backend`'s ops.
    pub fn new(backend: &'a dyn Backend) -> Self {
        Self { inner: PooledExecutor::new(backend), totals: BTreeMap::new() }
    }

    fn record<T>(&mut self, kind: String, flops: f64, f: impl FnOnce(&mut PooledExecutor<'a>) -> T) -> T {
        let start = Instant::now();
        let out = f(&mut self.inner);
        let e = self.totals.entry(kind).or_default();
        e.calls += 1;
        e.ms += start.elapsed().as_secs_f64() * 1e3;
        e.flops += flops;
        out
    }
}

impl Executor for ProfileExecutor<'_> {
    type Map = Tensor;
    fn image(&mut self, image: &Array3<f32>) -> Result<Tensor> {
        self.record("image upload".into(), 0.0, |e| e.image(image))
    }
    fn pyramid(
        &mut self,
        config: &crate::nn::NetworkConfig,
        image: ArrayView3<f32>,
        max_level: usize,
    ) -> Result<Vec<Tensor>> {
        self.record("image pyramid".into(), 0.0, |e| e.pyramid(config, image, max_level))
    }
    fn conv(&mut self, x: &Tensor, l: &PreparedLayer, stride: usize, act: Activation) -> Result<Tensor> {
        let g = conv_geometry(x.dim(), l.params(), stride)?;
        let kind = format!("conv s{stride} {}->{}", g.c_in(), g.c_out());
        self.record(kind, g.flops(), |e| e.conv(x, l, stride, act))
    }
    fn concat_conv(
        &mut self,
        a: &Tensor,
        b: &Tensor,
        l: &PreparedLayer,
        stride: usize,
        act: Activation,
    ) -> Result<Tensor> {
        let g = concat_conv_geometry(a.dim(), b.dim(), l.params(), stride)?;
        let kind = format!("concat + conv s{stride} {}->{}", g.c_in(), g.c_out());
        self.record(kind, g.flops(), |e| e.concat_conv(a, b, l, stride, act))
    }
    fn deconv(&mut self, x: &Tensor, l: &PreparedLayer) -> Result<Tensor> {
        // Each input pixel's 4 outputs sum 9, 6, 6 and 4 taps: 25 products per input pixel and pair
        // of channels.
        let g = deconv_geometry(x.dim(), l.params())?;
        let flops = 2.0 * 25.0 * (g.c_in() * g.c_out() * g.h() * g.w()) as f64;
        self.record("deconv 5x5 s2".into(), flops, |e| e.deconv(x, l))
    }
    fn deconv_add(&mut self, x: &Tensor, l: &PreparedLayer, skip: &Tensor) -> Result<Tensor> {
        let g = deconv_geometry(x.dim(), l.params())?;
        let flops = 2.0 * 25.0 * (g.c_in() * g.c_out() * g.h() * g.w()) as f64;
        self.record("deconv 5x5 s2 + add".into(), flops, |e| e.deconv_add(x, l, skip))
    }
    fn concat(&mut self, a: &Tensor, b: &Tensor) -> Result<Tensor> {
        self.record("concat".into(), 0.0, |e| e.concat(a, b))
    }
    fn add(&mut self, a: &Tensor, b: &Tensor) -> Result<Tensor> {
        self.record("add".into(), 0.0, |e| e.add(a, b))
    }
    fn crop(&mut self, x: Tensor, h: usize, w: usize) -> Tensor {
        self.record("crop".into(), 0.0, |e| e.crop(x, h, w))
    }
    fn release(&mut self, map: Tensor) {
        self.inner.release(map);
    }
}

/// Run `runs` forward passes under the profiler; returns the per-kind totals divided by `runs`
/// and the mean total wall time per pass (the difference to the sum of the kinds is the input
/// padding, mean subtraction and image pyramid).
///
/// # Errors
/// As [`FeatureNet::forward`].
pub fn profile_forward(
    net: &FeatureNet,
    backend: &dyn Backend,
    image: ArrayView3<f32>,
    runs: usize,
) -> Result<(Vec<(String, OpTotals)>, f64)> {
    let prepared = net.prepared(backend)?;
    let mut exec = ProfileExecutor::new(backend);
    let runs = runs.max(1);
    let start = Instant::now();
    for _ in 0..runs {
        std::hint::black_box(run_features(&mut exec, &prepared, image)?);
        // The arena carries over from pass to pass, as in `FeatureNet::features`.
    }
    let total = start.elapsed().as_secs_f64() * 1e3 / runs as f64;
    let n = runs as f64;
    let rows = exec
        .totals
        .into_iter()
        .map(|(k, t)| (k, OpTotals { calls: t.calls / runs, ms: t.ms / n, flops: t.flops / n }))
        .collect();
    Ok((rows, total))
}
