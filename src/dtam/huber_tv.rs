//! Huber-TV denoising of an inverse-depth map by Chambolle-Pock primal-dual steps.
//!
//! For fixed `a` and `θ` this minimises the convex
//!
//! ```text
//! P(d) = Σ_u ‖g(u) ∇d(u)‖_ε + 1/(2θ) (d(u) - a(u))²
//! ```
//!
//! through its saddle form `min_d max_{|q(u)|<=1} ⟨K d, q⟩ - ε/2 ‖q‖² + 1/(2θ) ‖d - a‖²` with
//! `K = diag(g) ∇`. One step (σ = τ = 1/√8, since `‖K‖² <= 8 max g² <= 8`):
//!
//! ```text
//! q ← Π_{|q|<=1} ( (q + σ g ∇d̄) / (1 + σ ε) )
//! d' ← (d - τ ∇ᵀ(g q) + τ a / θ) / (1 + τ / θ)
//! d̄ ← 2 d' - d,   d ← d'
//! ```
//!
//! `∇` is the forward difference with a zero difference across the last column/row (Neumann), and
//! `∇ᵀ = -div` its exact adjoint. The dual objective is
//! `D(q) = ⟨Kᵀq, a⟩ - θ/2 ‖Kᵀq‖² - ε/2 ‖q‖²`, and `P(d) - D(q) >= 0` is the primal-dual gap.
//! Every update is a per-pixel function of the previous arrays, computed row-parallel: the same
//! bits for any thread count.

use ndarray::{Array2, ArrayView2, Zip};
use rayon::prelude::*;

/// Primal and dual step size `σ = τ = 1/√8`.
pub const STEP: f64 = 0.353_553_390_593_273_8;

/// The Huber norm of a 2-vector: `|z|²/(2ε)` if `|z| <= ε`, else `|z| - ε/2`.
#[inline]
pub fn huber(zx: f64, zy: f64, eps: f64) -> f64 {
    let n = (zx * zx + zy * zy).sqrt();
    if n <= eps {
        n * n / (2.0 * eps)
    } else {
        n - eps / 2.0
    }
}

/// Forward differences `(∂x d, ∂y d)` at `(y, x)`, zero across the last column / row.
#[inline]
fn grad(d: &ArrayView2<f32>, y: usize, x: usize) -> (f64, f64) {
    let (h, w) = d.dim();
    let c = d[[y, x]] as f64;
    let gx = if x + 1 < w { d[[y, x + 1]] as f64 - c } else { 0.0 };
    let gy = if y + 1 < h { d[[y + 1, x]] as f64 - c } else { 0.0 };
    (gx, gy)
}

/// `(∇ᵀ p)(y, x) = -div p`, the exact adjoint of [`grad`] for a vector field `p = (px, py)`.
#[inline]
fn grad_adjoint(px: &ArrayView2<f32>, py: &ArrayView2<f32>, y: usize, x: usize) -> f64 {
    let (h, w) = px.dim();
    let mut div = 0.0;
    if x + 1 < w {
        div += px[[y, x]] as f64;
    }
    if x > 0 {
        div -= px[[y, x - 1]] as f64;
    }
    if y + 1 < h {
        div += py[[y, x]] as f64;
    }
    if y > 0 {
        div -= py[[y - 1, x]] as f64;
    }
    -div
}

/// Result of [`HuberTv::gap`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HuberTvReport {
    /// Primal objective `P(d)`.
    pub primal: f64,
    /// Dual objective `D(q)`.
    pub dual: f64,
}

impl HuberTvReport {
    /// `P(d) - D(q)`, non-negative up to rounding; zero at the optimum.
    pub fn gap(&self) -> f64 {
        self.primal - self.dual
    }
}

/// Primal-dual state: `d`, the extrapolation `d̄`, the dual field `q = (qx, qy)` and the weights.
#[derive(Clone, Debug)]
pub struct HuberTv {
    d: Array2<f32>,
    d_bar: Array2<f32>,
    qx: Array2<f32>,
    qy: Array2<f32>,
    g: Array2<f32>,
    eps: f64,
}

impl HuberTv {
    /// Start from `d0` with zero dual, edge weights `g` (same shape) and Huber threshold `eps`.
    ///
    /// # Panics
    /// If `g` and `d0` differ in shape (callers validate shapes).
    pub fn new(d0: Array2<f32>, g: Array2<f32>, eps: f64) -> Self {
        assert_eq!(d0.dim(), g.dim(), "edge weights must match the depth map");
        let zeros = Array2::zeros(d0.dim());
        Self { d_bar: d0.clone(), d: d0, qx: zeros.clone(), qy: zeros, g, eps }
    }

    /// The current primal `d`.
    pub fn primal(&self) -> ArrayView2<'_, f32> {
        self.d.view()
    }

    /// One primal-dual step towards `argmin_d P(d)` for the given `a` and `θ`.
    ///
    /// # Panics
    /// If `a` differs in shape from `d`.
    pub fn step(&mut self, a: ArrayView2<f32>, theta: f64) {
        assert_eq!(a.dim(), self.d.dim(), "a must match d");
        let (s, eps) = (STEP, self.eps);
        let (d_bar, g) = (self.d_bar.view(), self.g.view());
        let w = self.d.ncols();
        // Dual ascent, projected onto the unit ball.
        let qx = self.qx.as_slice_mut().expect("owned arrays are contiguous");
        let qy = self.qy.as_slice_mut().expect("owned arrays are contiguous");
        qx.par_chunks_mut(w).zip(qy.par_chunks_mut(w)).enumerate().for_each(|(y, (rx, ry))| {
            for (x, (qx, qy)) in rx.iter_mut().zip(ry.iter_mut()).enumerate() {
                let (gx, gy) = grad(&d_bar, y, x);
                let gw = g[[y, x]] as f64;
                let nx = (*qx as f64 + s * gw * gx) / (1.0 + s * eps);
                let ny = (*qy as f64 + s * gw * gy) / (1.0 + s * eps);
                let scale = (nx * nx + ny * ny).sqrt().max(1.0);
                *qx = (nx / scale) as f32;
                *qy = (ny / scale) as f32;
            }
        });
        // Weighted dual field g q, then the primal proximal step.
        let gqx = &self.qx * &self.g;
        let gqy = &self.qy * &self.g;
        let (gqx, gqy) = (gqx.view(), gqy.view());
        let old = self.d.clone();
        let d = self.d.as_slice_mut().expect("owned arrays are contiguous");
        d.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
            for (x, d) in row.iter_mut().enumerate() {
                let kt = grad_adjoint(&gqx, &gqy, y, x);
                *d = ((*d as f64 - s * kt + s * a[[y, x]] as f64 / theta) / (1.0 + s / theta)) as f32;
            }
        });
        Zip::from(&mut self.d_bar).and(&self.d).and(&old).for_each(|b, &d, &o| *b = 2.0 * d - o);
    }

    /// Largest `|q(u)|` (at most 1: the dual stays in its constraint set).
    pub fn dual_max_norm(&self) -> f32 {
        self.qx.iter().zip(self.qy.iter()).map(|(x, y)| (x * x + y * y).sqrt()).fold(0.0, f32::max)
    }

    /// `Σ ‖g ∇d‖_ε`, summed per row in f64, rows in order.
    pub fn regulariser_energy(&self) -> f64 {
        let d = self.d.view();
        let (h, w) = d.dim();
        let rows: Vec<f64> = (0..h)
            .into_par_iter()
            .map(|y| {
                (0..w)
                    .map(|x| {
                        let (gx, gy) = grad(&d, y, x);
                        let gw = self.g[[y, x]] as f64;
                        huber(gw * gx, gw * gy, self.eps)
                    })
                    .sum::<f64>()
            })
            .collect();
        rows.iter().sum()
    }

    /// Primal and dual objectives for the sub-problem with this `a` and `θ`.
    pub fn gap(&self, a: ArrayView2<f32>, theta: f64) -> HuberTvReport {
        let (h, w) = self.d.dim();
        let gqx = &self.qx * &self.g;
        let gqy = &self.qy * &self.g;
        let (mut coupling, mut lin, mut kt2, mut q2) = (0.0, 0.0, 0.0, 0.0);
        for y in 0..h {
            for x in 0..w {
                let diff = self.d[[y, x]] as f64 - a[[y, x]] as f64;
                coupling += diff * diff / (2.0 * theta);
                let kt = grad_adjoint(&gqx.view(), &gqy.view(), y, x);
                lin += kt * a[[y, x]] as f64;
                kt2 += kt * kt;
                let (qx, qy) = (self.qx[[y, x]] as f64, self.qy[[y, x]] as f64);
                q2 += qx * qx + qy * qy;
            }
        }
        HuberTvReport {
            primal: self.regulariser_energy() + coupling,
            dual: lin - theta / 2.0 * kt2 - self.eps / 2.0 * q2,
        }
    }
}
