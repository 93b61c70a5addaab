//! The network-level error budget (SPEC.md §8.7): the reference network's output together with an
//! elementwise bound on how far any implementation whose layers meet the §7.5 budget can be from
//! it.
//!
//! Each map carries the reference value `r` (f32, as the reference network computes it) and a bound
//! `e >= |x - r|` valid for any such implementation's value `x`. Through a layer with weights `W`,
//! bias `b` and `K` products per output:
//!
//! ```text
//! e' = |W| ⊛ e + 2 K ε M,   M = |W| ⊛ (|r| + e) + |b|
//! ```
//!
//! (`⊛` is the layer's own linear map, evaluated by the f64 reference kernel on non-negative
//! operands.) The first term carries the input's error through the exact layer; the second is the
//! §7.5 budget of the layer itself, whose magnitude `|W| |x| + |b|` is at most `M` because
//! `|x| <= |r| + e`; it also covers the reference's own rounding to f32. ReLU is 1-Lipschitz, so
//! it does not change `e`. A sum in f32 gives `e' = (1 + u)(e_a + e_b) + 2u (|r_a| + |r_b|)`,
//! `u = ε/2`; concatenation and cropping carry `e` along; the image pyramid is shared by all
//! implementations (one downsampling kernel), so its `e` is 0.

use ndarray::{s, Array1, Array3, Array4};

use crate::error::Result;
use crate::nn::conv2d::conv2d_reference;
use crate::nn::deconv2d::deconv2d_reference;
use crate::nn::network::{run_network, Executor, ForwardOutput, KernelExecutor, NetworkImpl};
use crate::nn::weights::{LayerParams, NetworkWeights};
use crate::nn::{Activation, Conv2dGeometry, Deconv2dGeometry};

/// A reference activation with its error bound.
#[derive(Clone, Debug)]
pub struct Bounded {
    /// The reference network's value.
    pub value: Array3<f32>,
    /// Elementwise bound on `|x - value|` for an implementation within the §7.5 budget.
    pub bound: Array3<f64>,
}

/// [`Executor`] of the reference network that propagates [`Bounded::bound`].
#[derive(Clone, Copy, Debug, Default)]
pub struct BoundExecutor;

/// `|W|`, `|b|` in f64.
fn abs_params(l: &LayerParams) -> (Array4<f64>, Array1<f64>) {
    (l.weight.mapv(|v| f64::from(v.abs())), l.bias.mapv(|v| f64::from(v.abs())))
}

/// `|r| + e`, the largest magnitude any admissible input can have.
fn magnitude(x: &Bounded) -> Array3<f64> {
    let mut m = x.value.mapv(|v| f64::from(v.abs()));
    m += &x.bound;
    m
}

/// `e' = prop + 2 K ε M`.
fn combine(prop: Array3<f64>, m: &Array3<f64>, k: usize) -> Array3<f64> {
    let rel = 2.0 * k as f64 * f64::from(f32::EPSILON);
    let mut e = prop;
    e.zip_mut_with(m, |e, &m| *e += rel * m);
    e
}

impl Executor for BoundExecutor {
    type Map = Bounded;
    fn image(&mut self, image: &Array3<f32>) -> Result<Bounded> {
        Ok(Bounded { value: image.clone(), bound: Array3::zeros(image.dim()) })
    }
    fn conv(&mut self, x: &Bounded, l: &LayerParams, stride: usize, act: Activation) -> Result<Bounded> {
        let value = KernelExecutor(NetworkImpl::REFERENCE).conv(&x.value, l, stride, act)?;
        let (h, w, c_in) = x.value.dim();
        let g = Conv2dGeometry::new(h, w, c_in, l.weight.shape()[0], stride)?;
        let (aw, ab) = abs_params(l);
        let zero = Array1::zeros(ab.len());
        let m = conv2d_reference(&g, magnitude(x).view(), aw.view(), ab.view(), Activation::None)?;
        let prop = conv2d_reference(&g, x.bound.view(), aw.view(), zero.view(), Activation::None)?;
        Ok(Bounded { value, bound: combine(prop, &m, g.k()) })
    }
    fn deconv(&mut self, x: &Bounded, l: &LayerParams) -> Result<Bounded> {
        let value = KernelExecutor(NetworkImpl::REFERENCE).deconv(&x.value, l)?;
        let (h, w, c_in) = x.value.dim();
        let g = Deconv2dGeometry::new(h, w, c_in, l.weight.shape()[1])?;
        let (aw, ab) = abs_params(l);
        let zero = Array1::zeros(ab.len());
        let m = deconv2d_reference(&g, magnitude(x).view(), aw.view(), ab.view())?;
        let prop = deconv2d_reference(&g, x.bound.view(), aw.view(), zero.view())?;
        Ok(Bounded { value, bound: combine(prop, &m, g.k()) })
    }
    fn concat(&mut self, a: &Bounded, b: &Bounded) -> Result<Bounded> {
        let value = KernelExecutor(NetworkImpl::REFERENCE).concat(&a.value, &b.value)?;
        let bound = ndarray::concatenate(ndarray::Axis(2), &[a.bound.view(), b.bound.view()])
            .map_err(|e| crate::Error::invalid_argument("concat bound", e.to_string()))?;
        Ok(Bounded { value, bound })
    }
    fn add(&mut self, a: &Bounded, b: &Bounded) -> Result<Bounded> {
        let value = KernelExecutor(NetworkImpl::REFERENCE).add(&a.value, &b.value)?;
        let u = f64::from(f32::EPSILON) / 2.0;
        let mut bound = &a.bound + &b.bound;
        bound.mapv_inplace(|e| (1.0 + u) * e);
        ndarray::Zip::from(&mut bound).and(&a.value).and(&b.value).for_each(|e, &ra, &rb| {
            *e += 2.0 * u * (f64::from(ra.abs()) + f64::from(rb.abs()));
        });
        Ok(Bounded { value, bound })
    }
    fn crop(&mut self, x: &Bounded, h: usize, w: usize) -> Bounded {
        Bounded {
            value: x.value.slice(s![..h, ..w, ..]).to_owned(),
            bound: x.bound.slice(s![..h, ..w, ..]).to_owned(),
        }
    }
}

/// The reference network's forward pass with the error bound of every output (SPEC.md §8.7).
/// Costs about three reference forward passes.
///
/// # Errors
/// As [`run_network`].
pub fn reference_with_bounds(
    weights: &NetworkWeights,
    image: ndarray::ArrayView3<f32>,
) -> Result<ForwardOutput<Bounded>> {
    run_network(&mut BoundExecutor, weights, image)
}
