//! Where a forward pass spends its time: an [`Observer`] of the product's forward pass that times each
//! operation, grouped by kind (`densefeat bench forward --profile`).

use std::collections::BTreeMap;
use std::time::Instant;

use ndarray::ArrayView3;

use super::network::{run_features, Arena};
use super::FeatureNet;
use crate::backend::{Backend, NetworkOp, Observed, Observer, PreparedLayer, Tensor};
use crate::error::Result;
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

/// The profiler: an [`Observer`] that sums each op kind's calls, time and work.
#[derive(Debug, Default)]
struct Profile {
    totals: BTreeMap<String, OpTotals>,
}

impl Profile {
    fn add(&mut self, kind: String, flops: f64, seconds: f64) {
        let e = self.totals.entry(kind).or_default();
        e.calls += 1;
        e.ms += seconds * 1e3;
        e.flops += flops;
    }
}

/// Work of a 5x5 stride-2 transposed convolution of `input`: each input pixel's 4 outputs sum 9, 6,
/// 6 and 4 taps, 25 products per input pixel and pair of channels.
fn deconv_flops(input: &Tensor, layer: &PreparedLayer) -> f64 {
    deconv_geometry(input.dim(), layer.params())
        .map(|g| 2.0 * 25.0 * (g.c_in() * g.c_out() * g.h() * g.w()) as f64)
        .unwrap_or(0.0)
}

impl Observer for Profile {
    fn observe(&mut self, op: NetworkOp<'_>, seconds: f64) {
        let (kind, flops) = match op {
            NetworkOp::Pyramid(_) => ("image pyramid".to_string(), 0.0),
            NetworkOp::Conv { input, layer, stride, .. } => {
                match conv_geometry(input.dim(), layer.params(), stride) {
                    Ok(g) => (format!("conv s{stride} {}->{}", g.c_in(), g.c_out()), g.flops()),
                    Err(_) => (format!("conv s{stride}"), 0.0),
                }
            }
            NetworkOp::ConcatConv { a, b, layer, stride, .. } => {
                match concat_conv_geometry(a.dim(), b.dim(), layer.params(), stride) {
                    Ok(g) => (format!("concat + conv s{stride} {}->{}", g.c_in(), g.c_out()), g.flops()),
                    Err(_) => (format!("concat + conv s{stride}"), 0.0),
                }
            }
            NetworkOp::Deconv { input, layer, .. } => {
                ("deconv 5x5 s2".to_string(), deconv_flops(input, layer))
            }
            NetworkOp::DeconvAdd { input, layer, .. } => {
                ("deconv 5x5 s2 + add".to_string(), deconv_flops(input, layer))
            }
            NetworkOp::Downsample { .. } => ("downsample".to_string(), 0.0),
            NetworkOp::Concat { .. } => ("concat".to_string(), 0.0),
            NetworkOp::Add { .. } => ("add".to_string(), 0.0),
            NetworkOp::Crop { .. } => ("crop".to_string(), 0.0),
        };
        self.add(kind, flops, seconds);
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
    let observed = Observed::new(backend, Profile::default());
    let mut arena = Arena::new();
    let runs = runs.max(1);
    let start = Instant::now();
    for _ in 0..runs {
        // The arena carries over from pass to pass, as in `FeatureNet::features`.
        std::hint::black_box(run_features(&observed, &mut arena, &prepared, image)?);
    }
    let total = start.elapsed().as_secs_f64() * 1e3 / runs as f64;
    let n = runs as f64;
    let rows = observed
        .into_observer()
        .totals
        .into_iter()
        .map(|(k, t)| (k, OpTotals { calls: t.calls / runs, ms: t.ms / n, flops: t.flops / n }))
        .collect();
    Ok((rows, total))
}
