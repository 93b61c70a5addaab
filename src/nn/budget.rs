//! The network-level error budget (SPEC.md §8.7).
//!
//! 1. **Per layer, in place** ([`LayerCheck`]): while a network runs with the chosen
//!    kernels, every convolution and transposed convolution is also run by its f64 reference on the
//!    *same* input, and the fast output must be within the budget of the kernel that ran: §7.5's
//!    `2 K ε M`, or §7.11's `2 (n + 2) ε M_W` for a Winograd layer. So the fast network is
//!    exactly a composition of layers that each meet their budget.
//! 2. **End to end** ([`relative_budget`]): `max |fast - ref| <= D · 2 K_max ε · max |ref|` for
//!    every output map, `D` the number of layers on the longest path and `K_max` the largest
//!    product count. This is a first-order model (each layer adds at most its own relative error,
//!    and Xavier-initialised layers roughly preserve the max norm), not a proof: the rigorous
//!    worst case, which propagates errors through `|W|`, grows like `(sqrt(3K)/2)^D` and is
//!    vacuous beyond two blocks.

use ndarray::{Array1, Array3, Array4};

use crate::backend::{Backend, CpuBackend, NetworkOp, Observer, PreparedLayer, Tensor};
use crate::error::Result;
use crate::ops::config::NetworkConfig;
use crate::ops::conv2d::{conv2d_reference, winograd_budget, winograd_magnitude_reference};
use crate::ops::deconv2d::{deconv2d_reference, deconv2d_winograd_magnitude_reference};
use crate::ops::Activation;
use crate::ops::LayerParams;
use crate::ops::NetworkImpl;
use crate::testing::within_budget;

/// Relative budget of one layer with `k` products per output (SPEC.md §7.5).
fn layer_budget(k: usize) -> f32 {
    2.0 * k as f32 * f32::EPSILON
}

/// Checks every layer of a forward pass against its reference on the same input: an
/// [`Observer`] of the pass run on [`LayerCheck::backend`] (wrapped in
/// [`crate::backend::Observed`]). Failures are collected, not raised, so a test can report them all.
#[derive(Clone, Debug)]
pub struct LayerCheck {
    /// The fast kernels under test.
    pub imp: NetworkImpl,
    /// One line per layer over its budget.
    pub failures: Vec<String>,
    /// Largest `|fast - ref| / budget` seen (<= 1 when every layer passes).
    pub worst_fraction: f64,
    /// Layers checked.
    pub layers: usize,
}

/// A host tensor's array (the CPU backend's tensors are host maps).
fn host(t: &Tensor) -> Result<&Array3<f32>> {
    t.as_host().ok_or_else(|| crate::error::Error::Unsupported {
        backend: t.location().into(),
        what: "the layer check runs on the CPU backend's host maps".into(),
    })
}

impl LayerCheck {
    /// A check of the kernels `imp`.
    pub fn new(imp: NetworkImpl) -> Self {
        LayerCheck { imp, failures: Vec::new(), worst_fraction: 0.0, layers: 0 }
    }

    /// The backend to run the checked pass on: the CPU backend with the kernels `imp`.
    pub fn backend(&self) -> CpuBackend {
        CpuBackend::with_network(self.imp)
    }

    fn check(
        &mut self,
        what: &str,
        got: &Array3<f32>,
        want: &Array3<f64>,
        magnitude: &Array3<f64>,
        rel: f32,
    ) {
        let want32 = want.mapv(|v| v as f32);
        let mag32 = magnitude.mapv(|v| v as f32);
        self.layers += 1;
        for ((g, w), m) in got.iter().zip(want32.iter()).zip(mag32.iter()) {
            let budget = f64::from(rel) * f64::from(*m);
            let diff = f64::from((g - w).abs());
            if budget > 0.0 {
                self.worst_fraction = self.worst_fraction.max(diff / budget);
            }
        }
        if let Err(e) = within_budget(got.view(), want32.view(), mag32.view(), rel) {
            self.failures.push(format!("layer {} ({what}, relative budget {rel:e}): {e}", self.layers));
        }
    }

    fn conv(
        &mut self,
        x: &Array3<f32>,
        l: &PreparedLayer,
        stride: usize,
        act: Activation,
        got: &Array3<f32>,
    ) -> Result<()> {
        let g = crate::ops::conv_geometry(x.dim(), l.params(), stride)?;
        let (xf, xa) = f64_and_abs(x);
        let (aw, ab) = abs_params(l.params());
        let (wf, bf) = (l.params().weight.mapv(f64::from), l.params().bias.mapv(f64::from));
        let want = conv2d_reference(&g, xf.view(), wf.view(), bf.view(), act)?;
        let imp = self.backend().conv_impl_for(&g);
        let (magnitude, rel) = if let Some(tile) = imp.winograd_tile() {
            let m = winograd_magnitude_reference(tile, &g, xa.view(), aw.view(), ab.view())?;
            (m, winograd_budget(tile, g.c_in()))
        } else {
            (conv2d_reference(&g, xa.view(), aw.view(), ab.view(), Activation::None)?, layer_budget(g.k()))
        };
        self.check(&format!("conv {:?} stride {stride}, {imp:?}", x.shape()), got, &want, &magnitude, rel);
        Ok(())
    }

    fn deconv(&mut self, x: &Array3<f32>, l: &PreparedLayer, got: &Array3<f32>) -> Result<()> {
        let g = crate::ops::deconv_geometry(x.dim(), l.params())?;
        let (xf, xa) = f64_and_abs(x);
        let (aw, ab) = abs_params(l.params());
        let (wf, bf) = (l.params().weight.mapv(f64::from), l.params().bias.mapv(f64::from));
        let want = deconv2d_reference(&g, xf.view(), wf.view(), bf.view())?;
        let imp = self.backend().deconv_impl_for(&g);
        let (magnitude, rel) = if let Some(tile) = imp.winograd_tile() {
            let m = deconv2d_winograd_magnitude_reference(tile, &g, xa.view(), aw.view(), ab.view())?;
            (m, winograd_budget(tile, g.c_in()))
        } else {
            (deconv2d_reference(&g, xa.view(), aw.view(), ab.view())?, layer_budget(g.k()))
        };
        self.check(&format!("deconv {:?}, {imp:?}", x.shape()), got, &want, &magnitude, rel);
        Ok(())
    }

    /// The checks of one op (the fused ops: the concatenation's convolution against the reference
    /// on the concatenation; `skip + deconv` bit for bit against the backend's own deconvolution
    /// plus `skip`, and that deconvolution against its reference).
    fn op(&mut self, op: NetworkOp<'_>) -> Result<()> {
        match op {
            NetworkOp::Conv { input, layer, stride, act, output } => {
                self.conv(host(input)?, layer, stride, act, host(output)?)
            }
            NetworkOp::ConcatConv { a, b, layer, stride, act, output } => {
                let x = crate::ops::concat_channels(host(a)?.view(), host(b)?.view())?;
                self.conv(&x, layer, stride, act, host(output)?)
            }
            NetworkOp::Deconv { input, layer, output } => self.deconv(host(input)?, layer, host(output)?),
            NetworkOp::DeconvAdd { input, layer, skip, output } => {
                let d = self.backend().deconv5x5s2(input, layer)?;
                let d = host(&d)?;
                let sum = host(skip)? + d;
                if sum.iter().zip(host(output)?).any(|(s, o)| s.to_bits() != o.to_bits()) {
                    self.failures.push(format!(
                        "deconv + add {:?}: the fused kernel differs from deconv then add (budget: exact)",
                        input.dim()
                    ));
                }
                self.deconv(host(input)?, layer, d)
            }
            _ => Ok(()),
        }
    }
}

/// `|W|`, `|b|` in f64.
fn abs_params(l: &LayerParams) -> (Array4<f64>, Array1<f64>) {
    (l.weight.mapv(|v| f64::from(v.abs())), l.bias.mapv(|v| f64::from(v.abs())))
}

/// `x` and `|x|` in f64.
fn f64_and_abs(x: &Array3<f32>) -> (Array3<f64>, Array3<f64>) {
    (x.mapv(f64::from), x.mapv(|v| f64::from(v.abs())))
}

impl Observer for LayerCheck {
    fn observe(&mut self, op: NetworkOp<'_>, _seconds: f64) {
        if let Err(e) = self.op(op) {
            self.failures.push(format!("layer {}: the check failed: {e}", self.layers + 1));
        }
    }
}

/// Number of (transposed) convolutions on the longest path from the image to the features:
/// `3 · blocks` convolutions and `blocks - 1` transposed convolutions.
pub fn depth(config: &NetworkConfig) -> usize {
    3 * config.blocks + config.blocks - 1
}

/// Largest number of products in one output of any layer: `9 (channels + 3)` with more than one
/// block, else `9 channels` (`9 · 3` if that is larger).
pub fn max_products(config: &NetworkConfig) -> usize {
    let widest_in = (0..config.blocks).map(|k| config.block_in_channels(k)).max().unwrap_or(0);
    9 * widest_in.max(config.channels)
}

/// End-to-end relative budget `D · 2 K_max ε` ([`depth`], [`max_products`]): a bound on
/// `max |fast - ref| / max |ref|` for any output map (SPEC.md §8.7).
pub fn relative_budget(config: &NetworkConfig) -> f64 {
    depth(config) as f64 * 2.0 * max_products(config) as f64 * f64::from(f32::EPSILON)
}
