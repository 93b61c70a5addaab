//! The optimiser (SPEC.md §13.4): Adam with decoupled weight decay (AdamW) on convolution and
//! transposed-convolution weights (not biases), global gradient-norm clipping, and a learning-rate
//! schedule of linear warm-up then cosine decay.

use crate::error::{Error, Result};
use crate::nn::NetworkWeights;
use crate::ops::LayerParams;

/// Optimiser hyper-parameters.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct OptimConfig {
    /// Peak learning rate.
    pub lr: f64,
    /// Final learning rate as a fraction of `lr` (cosine decay reaches it at the last step).
    pub lr_final_fraction: f64,
    /// Linear warm-up steps.
    pub warmup: usize,
    /// Adam's `β1`.
    pub beta1: f64,
    /// Adam's `β2`.
    pub beta2: f64,
    /// Adam's `ε`.
    pub eps: f64,
    /// Decoupled weight decay (per step, times the learning rate), weights only.
    pub weight_decay: f64,
    /// Clip the global gradient norm to this (0 = no clipping).
    pub clip_norm: f64,
}

impl Default for OptimConfig {
    fn default() -> Self {
        OptimConfig {
            lr: 1e-3,
            lr_final_fraction: 0.05,
            warmup: 100,
            beta1: 0.9,
            beta2: 0.999,
            eps: 1e-8,
            weight_decay: 1e-4,
            clip_norm: 10.0,
        }
    }
}

impl OptimConfig {
    /// Learning rate at step `t` (1-based) of `total`.
    pub fn lr_at(&self, t: usize, total: usize) -> f64 {
        if t <= self.warmup {
            return self.lr * t as f64 / self.warmup.max(1) as f64;
        }
        let span = total.saturating_sub(self.warmup).max(1) as f64;
        let progress = ((t - self.warmup) as f64 / span).min(1.0);
        let cos = 0.5 * (1.0 + (std::f64::consts::PI * progress).cos());
        self.lr * (self.lr_final_fraction + (1.0 - self.lr_final_fraction) * cos)
    }

    /// Checks ranges.
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] naming the field.
    pub fn validate(&self) -> Result<()> {
        let check = |name: &str, ok: bool, v: f64| {
            if ok {
                Ok(())
            } else {
                Err(Error::invalid_argument(name, format!("{v} is out of range")))
            }
        };
        check("lr", self.lr.is_finite() && self.lr > 0.0, self.lr)?;
        check("lr_final_fraction", (0.0..=1.0).contains(&self.lr_final_fraction), self.lr_final_fraction)?;
        check("beta1", (0.0..1.0).contains(&self.beta1), self.beta1)?;
        check("beta2", (0.0..1.0).contains(&self.beta2), self.beta2)?;
        check("eps", self.eps > 0.0, self.eps)?;
        check("weight_decay", self.weight_decay >= 0.0 && self.weight_decay.is_finite(), self.weight_decay)?;
        check("clip_norm", self.clip_norm >= 0.0 && self.clip_norm.is_finite(), self.clip_norm)
    }
}

/// Adam's moments, shaped like the weights.
#[derive(Clone, Debug, PartialEq)]
pub struct AdamState {
    /// Steps taken.
    pub step: usize,
    /// First moments.
    pub m: NetworkWeights,
    /// Second moments.
    pub v: NetworkWeights,
}

impl AdamState {
    /// Zero moments for `weights`.
    pub fn new(weights: &NetworkWeights) -> Self {
        AdamState { step: 0, m: weights.zeros_like(), v: weights.zeros_like() }
    }
}

/// The global L2 norm of a gradient, summed in f64 in layer order.
pub fn grad_norm(g: &NetworkWeights) -> f64 {
    grad_norm_layers(&g.layers())
}

/// [`grad_norm`] of any list of layers (weights then bias of each, in list order).
pub fn grad_norm_layers(layers: &[&LayerParams]) -> f64 {
    let mut s = 0.0f64;
    for l in layers {
        for &v in l.weight.iter().chain(l.bias.iter()) {
            s += f64::from(v) * f64::from(v);
        }
    }
    s.sqrt()
}

/// One AdamW update of `weights` with gradient `grads` at learning rate `lr` (serial, elementwise
/// in layer order: deterministic). Returns the gradient norm before clipping.
pub fn adam_step(
    cfg: &OptimConfig,
    state: &mut AdamState,
    weights: &mut NetworkWeights,
    grads: &NetworkWeights,
    lr: f64,
) -> f64 {
    let layers = AdamLayers {
        weights: weights.layers_mut(),
        grads: grads.layers(),
        m: state.m.layers_mut(),
        v: state.v.layers_mut(),
    };
    adam_step_layers(cfg, &mut state.step, layers, lr)
}

/// The parameters, gradients and moments [`adam_step_layers`] updates, as parallel lists of layers
/// (the same shapes at each index).
pub struct AdamLayers<'a> {
    /// Parameters, updated in place.
    pub weights: Vec<&'a mut LayerParams>,
    /// Their gradients.
    pub grads: Vec<&'a LayerParams>,
    /// First moments.
    pub m: Vec<&'a mut LayerParams>,
    /// Second moments.
    pub v: Vec<&'a mut LayerParams>,
}

/// [`adam_step`] on any list of layers (a network with a head, SPEC.md §13.11): `step` is Adam's
/// step count, incremented here. The same operations in the same order as [`adam_step`] on a
/// network's layers. Returns the gradient norm before clipping.
///
/// # Panics
/// If a weight, gradient or moment tensor is not contiguous, or the lists differ in length.
pub fn adam_step_layers(cfg: &OptimConfig, step: &mut usize, layers: AdamLayers<'_>, lr: f64) -> f64 {
    let AdamLayers { weights, grads, m, v } = layers;
    assert!(
        weights.len() == grads.len() && grads.len() == m.len() && m.len() == v.len(),
        "adam_step_layers: lists of different lengths"
    );
    let norm = grad_norm_layers(&grads);
    let clip = if cfg.clip_norm > 0.0 && norm > cfg.clip_norm { (cfg.clip_norm / norm) as f32 } else { 1.0 };
    *step += 1;
    let t = *step as i32;
    let bc1 = (1.0 - cfg.beta1.powi(t)) as f32;
    let bc2 = (1.0 - cfg.beta2.powi(t)) as f32;
    let (b1, b2, eps, lr32) = (cfg.beta1 as f32, cfg.beta2 as f32, cfg.eps as f32, lr as f32);
    let decay = (lr * cfg.weight_decay) as f32;
    let layers = weights.into_iter().zip(grads).zip(m).zip(v);
    for (((w, g), m), v) in layers {
        let tensors = [
            (
                w.weight.as_slice_mut(),
                g.weight.as_slice(),
                m.weight.as_slice_mut(),
                v.weight.as_slice_mut(),
                decay,
            ),
            (w.bias.as_slice_mut(), g.bias.as_slice(), m.bias.as_slice_mut(), v.bias.as_slice_mut(), 0.0),
        ];
        for (w, g, m, v, decay) in tensors {
            let (Some(w), Some(g), Some(m), Some(v)) = (w, g, m, v) else {
                unreachable!("parameters are contiguous")
            };
            for i in 0..w.len() {
                let gi = g[i] * clip;
                m[i] = b1 * m[i] + (1.0 - b1) * gi;
                v[i] = b2 * v[i] + (1.0 - b2) * gi * gi;
                let m_hat = m[i] / bc1;
                let v_hat = v[i] / bc2;
                w[i] -= lr32 * m_hat / (v_hat.sqrt() + eps) + decay * w[i];
            }
        }
    }
    norm
}
