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
//! q ← Π_{|q|<=1} ( (q + σ g ∇d̄) · s_q ),   Π(n) = n · 1/max(|n|, 1)
//! d' ← (d - τ ∇ᵀ(g q) + τ a / θ) · s_d
//! d̄ ← 2 d' - d,   d ← d'
//! ```
//!
//! with `s_q = 1/(1 + σ ε)` and `s_d = 1/(1 + τ / θ)` rounded once (SPEC.md §10: multiplications
//! where the textbook form divides, the same up to an ulp and 1.4x faster).
//!
//! `∇` is the forward difference with a zero difference across the last column/row (Neumann), and
//! `∇ᵀ = -div` its exact adjoint. The dual objective is
//! `D(q) = ⟨Kᵀq, a⟩ - θ/2 ‖Kᵀq‖² - ε/2 ‖q‖²`, and `P(d) - D(q) >= 0` is the primal-dual gap.
//! Every update is a per-pixel function of the previous arrays, computed row-parallel: the same
//! bits for any thread count.

use ndarray::{Array2, ArrayView2, Zip};
use rayon::prelude::*;

use super::normal_prior::{step_size, SlopeField};
use crate::runtime::CpuFeatureLevel;

#[path = "normal_steps.rs"]
mod normal_steps;
#[path = "tgv_steps.rs"]
mod tgv_steps;

pub(crate) use normal_steps::slope_regulariser_row;
use normal_steps::Slope;
use tgv_steps::SecondOrder;

/// Primal and dual step size `σ = τ = 1/√8`.
pub const STEP: f64 = 0.353_553_390_593_273_8;

/// The Huber norm of a 2-vector: `|z|²/(2ε)` if `|z| <= ε`, else `|z| - ε/2`.
#[inline(always)]
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

/// `Σ_x ‖g ∇d‖_ε` over one row: the row term of [`HuberTv::regulariser_energy`], with the same
/// per-pixel expression and the same `f64` summation (`Iterator::sum`, `x` ascending); the terms
/// are computed first, by a loop that vectorises. `below` is the next row of `d` (`None` on the
/// last row).
#[inline(always)]
pub(crate) fn regulariser_row(d: &[f32], below: Option<&[f32]>, g: &[f32], eps: f64) -> f64 {
    let mut terms = vec![0.0; d.len()];
    match below {
        Some(b) => huber_terms::<true>(&mut terms, d, b, g, eps),
        None => huber_terms::<false>(&mut terms, d, d, g, eps),
    }
    terms.iter().copied().sum::<f64>()
}

/// `‖g ∇d‖_ε` per pixel of a row; `BELOW`: whether `below` is the next row (else `∂y d = 0`).
#[inline(always)]
fn huber_terms<const BELOW: bool>(terms: &mut [f64], d: &[f32], below: &[f32], g: &[f32], eps: f64) {
    let w = terms.len();
    if w == 0 {
        return;
    }
    let (d, below, g) = (&d[..w], &below[..w], &g[..w]);
    let term = |x: usize, gx: f64| {
        let c = d[x] as f64;
        let gy = if BELOW { below[x] as f64 - c } else { 0.0 };
        let gw = g[x] as f64;
        huber(gw * gx, gw * gy, eps)
    };
    for x in 0..w - 1 {
        terms[x] = term(x, d[x + 1] as f64 - d[x] as f64);
    }
    terms[w - 1] = term(w - 1, 0.0);
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
    /// Scratch for [`HuberTv::steps_with`]: `(τ a) / θ` per pixel.
    a_term: Vec<f64>,
    /// The normal prior's slope field (SPEC.md §10.2): `Some` replaces `∇` by `K_n = ∇ − q`.
    slope: Option<Slope>,
    /// TGV²'s slope field and dual (SPEC.md §10.4): `Some` replaces `‖g∇d‖_ε` by
    /// `‖g(∇d − v/β)‖_ε + ‖∇v‖`.
    second: Option<SecondOrder>,
}

impl HuberTv {
    /// Start from `d0` with zero dual, edge weights `g` (same shape) and Huber threshold `eps`.
    ///
    /// # Panics
    /// If `g` and `d0` differ in shape (callers validate shapes).
    pub fn new(d0: Array2<f32>, g: Array2<f32>, eps: f64) -> Self {
        assert_eq!(d0.dim(), g.dim(), "edge weights must match the depth map");
        let zeros = Array2::zeros(d0.dim());
        Self {
            d_bar: d0.clone(),
            d: d0,
            qx: zeros.clone(),
            qy: zeros,
            g,
            eps,
            a_term: Vec::new(),
            slope: None,
            second: None,
        }
    }

    /// [`HuberTv::new`] with the normal prior (SPEC.md §10.2): the regulariser becomes
    /// `Σ ‖g (∇d − d q)‖_ε` for the slope field `q`, stepped with `σ = τ = 1/(√8 + Q)`; `g` is
    /// multiplied by the field's normal edge weights if it has them ([`SlopeField::solver_weights`]).
    ///
    /// # Panics
    /// If `g` or the field differ in shape from `d0` (callers validate shapes).
    pub fn with_slope(d0: Array2<f32>, g: Array2<f32>, eps: f64, q: &SlopeField) -> Self {
        assert_eq!(q.dim(), d0.dim(), "the slope field must match the depth map");
        let mut tv = Self::new(d0, q.solver_weights(g), eps);
        tv.slope = Some(Slope { sx: q.qx.clone(), sy: q.qy.clone(), step: step_size(q.max_norm) });
        tv
    }

    /// [`HuberTv::new`] with TGV² (SPEC.md §10.4): the regulariser becomes
    /// `Σ ‖g (∇d − v/β)‖_ε + ‖∇v‖` over `d` and a slope field `v` (starting at 0), stepped with
    /// `σ = τ = tgv::step_size(β)`.
    ///
    /// # Panics
    /// If `g` differs in shape from `d0` (callers validate shapes).
    pub fn with_second_order(d0: Array2<f32>, g: Array2<f32>, eps: f64, beta: f64) -> Self {
        let mut tv = Self::new(d0, g, eps);
        tv.second = Some(SecondOrder::new(tv.d.dim(), beta));
        tv
    }

    /// TGV²'s slope field `w = v/β` (inverse depth per pixel, `x` and `y`), if it is on.
    pub fn tgv_slope(&self) -> Option<(Array2<f32>, Array2<f32>)> {
        self.second.as_ref().map(|s| {
            let b = s.beta as f32;
            (s.vx.mapv(|v| v / b), s.vy.mapv(|v| v / b))
        })
    }

    /// The slope field's rows `y` (`q_x`, `q_y`), if the normal prior is on.
    pub(crate) fn slope_rows(&self, y: usize) -> Option<(&[f32], &[f32])> {
        let w = self.d.ncols();
        self.slope.as_ref().map(|s| {
            let (sx, sy) = (s.sx.as_slice().expect("contiguous"), s.sy.as_slice().expect("contiguous"));
            (&sx[y * w..][..w], &sy[y * w..][..w])
        })
    }

    /// The current primal `d`.
    pub fn primal(&self) -> ArrayView2<'_, f32> {
        self.d.view()
    }

    /// One primal-dual step towards `argmin_d P(d)` for the given `a` and `θ`, with the AVX-512
    /// build of the row kernels where the CPU has it ([`CpuFeatureLevel::get()`]).
    ///
    /// # Panics
    /// If `a` differs in shape from `d`.
    pub fn step(&mut self, a: ArrayView2<f32>, theta: f64) {
        self.step_with(a, theta, CpuFeatureLevel::get());
    }

    /// [`HuberTv::step`] with an explicit choice of kernel build; every build gives the same bits
    /// as [`HuberTv::step_reference`].
    ///
    /// # Panics
    /// If `a` differs in shape from `d`.
    pub fn step_with(&mut self, a: ArrayView2<f32>, theta: f64, level: CpuFeatureLevel) {
        self.steps_with(a, theta, 1, level);
    }

    /// `n` primal-dual steps for the same `a` and `θ` (what one DTAM iteration runs between two
    /// a-searches): the bits of `n` calls of [`HuberTv::step_reference`].
    ///
    /// The primal update's term `(τ a) / θ` depends on neither `d` nor `q`, so it is formed once
    /// per pixel (the same f64 expression, so the same value) and read by every step. Each step is
    /// two row-parallel passes over contiguous rows: the dual update of every row (reading `d̄` rows
    /// `y, y+1`), then the primal update fused with the extrapolation `d̄ = 2d' - d` (reading `q`
    /// and `g` rows `y-1, y`, forming `g q` in `f32` on the fly). The per-pixel arithmetic is
    /// exactly the reference's, term by term and in the same order.
    ///
    /// # Panics
    /// If `a` differs in shape from `d`.
    pub fn steps_with(&mut self, a: ArrayView2<f32>, theta: f64, n: usize, level: CpuFeatureLevel) {
        assert_eq!(a.dim(), self.d.dim(), "a must match d");
        let (h, w) = self.d.dim();
        if h == 0 || w == 0 || n == 0 {
            return;
        }
        let a = a.as_standard_layout();
        let a = a.as_slice().expect("standard layout is contiguous");
        if self.slope.is_some() {
            // The normal prior has one build (portable, row-parallel): `level` changes nothing.
            self.slope_steps(a, theta, n);
            return;
        }
        if self.second.is_some() {
            // So has TGV².
            self.tgv_steps(a, theta, n);
            return;
        }
        let k = Coefficients::new(self.eps, theta);
        let mut a_term = std::mem::take(&mut self.a_term);
        a_term.resize(h * w, 0.0);
        a_term.par_chunks_mut(w).zip(a.par_chunks(w)).for_each(|(t, a)| {
            for (t, &a) in t.iter_mut().zip(a) {
                *t = STEP * a as f64 / theta;
            }
        });
        for _ in 0..n {
            self.one_step(&a_term, &k, level);
        }
        self.a_term = a_term;
    }

    /// One step of [`HuberTv::steps_with`] (`a_term` = `(τ a) / θ`, row-major).
    fn one_step(&mut self, a_term: &[f64], k: &Coefficients, level: CpuFeatureLevel) {
        let (h, w) = self.d.dim();
        let (d_bar, g) = (self.d_bar.as_slice().expect("contiguous"), self.g.as_slice().expect("contiguous"));
        let qx = self.qx.as_slice_mut().expect("owned arrays are contiguous");
        let qy = self.qy.as_slice_mut().expect("owned arrays are contiguous");
        qx.par_chunks_mut(w).zip(qy.par_chunks_mut(w)).enumerate().for_each(|(y, (rx, ry))| {
            let below = (y + 1 < h).then(|| &d_bar[(y + 1) * w..][..w]);
            let rows = DualRows { qx: rx, qy: ry, d_bar: &d_bar[y * w..][..w], below, g: &g[y * w..][..w] };
            kernels::dual_row(rows, k, level);
        });
        let (qx, qy) = (self.qx.as_slice().expect("contiguous"), self.qy.as_slice().expect("contiguous"));
        let d = self.d.as_slice_mut().expect("owned arrays are contiguous");
        let d_bar = self.d_bar.as_slice_mut().expect("owned arrays are contiguous");
        d.par_chunks_mut(w).zip(d_bar.par_chunks_mut(w)).enumerate().for_each(|(y, (rd, rb))| {
            fn row<T>(v: &[T], y: usize, w: usize) -> &[T] {
                &v[y * w..][..w]
            }
            let above = (y > 0).then(|| (row(qy, y - 1, w), row(g, y - 1, w)));
            let rows = PrimalRows {
                d: rd,
                d_bar: rb,
                qx: row(qx, y, w),
                qy: row(qy, y, w),
                g: row(g, y, w),
                above,
                has_below: y + 1 < h,
                a_term: row(a_term, y, w),
            };
            kernels::primal_row(rows, k, level);
        });
    }

    /// The original, unfused step (ndarray indexing, `g q` and the old `d` as temporary arrays):
    /// the definition [`HuberTv::step`] is tested against bit for bit
    /// (`fused_solve_equals_the_reference_bit_for_bit` in tests/dtam.rs).
    ///
    /// # Panics
    /// If `a` differs in shape from `d`.
    ///
    /// With the normal prior this is the prior's one step (its oracle is the f64
    /// `normal_prior::Reference`, within a stated budget, not bit for bit).
    pub fn step_reference(&mut self, a: ArrayView2<f32>, theta: f64) {
        assert_eq!(a.dim(), self.d.dim(), "a must match d");
        if self.slope.is_some() || self.second.is_some() {
            let a = a.as_standard_layout();
            let a = a.as_slice().expect("standard layout is contiguous");
            if self.slope.is_some() {
                self.slope_steps(a, theta, 1);
            } else {
                self.tgv_steps(a, theta, 1);
            }
            return;
        }
        let (s, eps) = (STEP, self.eps);
        let (dual_scale, primal_scale) = (1.0 / (1.0 + s * eps), 1.0 / (1.0 + s / theta));
        let (d_bar, g) = (self.d_bar.view(), self.g.view());
        let w = self.d.ncols();
        // Dual ascent, projected onto the unit ball.
        let qx = self.qx.as_slice_mut().expect("owned arrays are contiguous");
        let qy = self.qy.as_slice_mut().expect("owned arrays are contiguous");
        qx.par_chunks_mut(w).zip(qy.par_chunks_mut(w)).enumerate().for_each(|(y, (rx, ry))| {
            for (x, (qx, qy)) in rx.iter_mut().zip(ry.iter_mut()).enumerate() {
                let (gx, gy) = grad(&d_bar, y, x);
                let gw = g[[y, x]] as f64;
                let nx = (*qx as f64 + s * gw * gx) * dual_scale;
                let ny = (*qy as f64 + s * gw * gy) * dual_scale;
                let shrink = 1.0 / (nx * nx + ny * ny).sqrt().max(1.0);
                *qx = (nx * shrink) as f32;
                *qy = (ny * shrink) as f32;
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
                *d = ((*d as f64 - s * kt + s * a[[y, x]] as f64 / theta) * primal_scale) as f32;
            }
        });
        Zip::from(&mut self.d_bar).and(&self.d).and(&old).for_each(|b, &d, &o| *b = 2.0 * d - o);
    }

    /// The edge weights `g`.
    pub fn weights(&self) -> ArrayView2<'_, f32> {
        self.g.view()
    }

    /// The Huber threshold `ε`.
    pub fn epsilon(&self) -> f64 {
        self.eps
    }

    /// Largest `|q(u)|` (at most 1: the dual stays in its constraint set).
    pub fn dual_max_norm(&self) -> f32 {
        self.qx.iter().zip(self.qy.iter()).map(|(x, y)| (x * x + y * y).sqrt()).fold(0.0, f32::max)
    }

    /// `Σ ‖g ∇d‖_ε` (with the normal prior `Σ ‖g (∇d − d q)‖_ε`, with TGV²
    /// `Σ ‖g (∇d − v/β)‖_ε + ‖∇v‖`), summed per row in f64, rows in order.
    pub fn regulariser_energy(&self) -> f64 {
        let d = self.d.view();
        let (h, w) = d.dim();
        if self.second.is_some() {
            let rows: Vec<f64> = (0..h)
                .into_par_iter()
                .map(|y| {
                    let (rows, beta) = self.tgv_rows(y).expect("second order is on");
                    super::tgv::regulariser_row(rows, beta, self.eps)
                })
                .collect();
            return rows.iter().sum();
        }
        if self.slope.is_some() {
            let (ds, g) = (self.d.as_slice().expect("contiguous"), self.g.as_slice().expect("contiguous"));
            let rows: Vec<f64> = (0..h)
                .into_par_iter()
                .map(|y| {
                    let (sx, sy) = self.slope_rows(y).expect("slope is on");
                    let below = (y + 1 < h).then(|| &ds[(y + 1) * w..][..w]);
                    slope_regulariser_row(&ds[y * w..][..w], below, &g[y * w..][..w], sx, sy, self.eps)
                })
                .collect();
            return rows.iter().sum();
        }
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

    /// Primal and dual objectives for the sub-problem with this `a` and `θ`. Defined for Huber-TV
    /// and the normal prior; with TGV² the dual objective is not formed and is NaN (the primal is
    /// TGV²'s).
    pub fn gap(&self, a: ArrayView2<f32>, theta: f64) -> HuberTvReport {
        let (h, w) = self.d.dim();
        let gqx = &self.qx * &self.g;
        let gqy = &self.qy * &self.g;
        let (mut coupling, mut lin, mut kt2, mut q2) = (0.0, 0.0, 0.0, 0.0);
        for y in 0..h {
            for x in 0..w {
                let diff = self.d[[y, x]] as f64 - a[[y, x]] as f64;
                coupling += diff * diff / (2.0 * theta);
                let mut kt = grad_adjoint(&gqx.view(), &gqy.view(), y, x);
                if let Some(s) = &self.slope {
                    kt -= s.sx[[y, x]] as f64 * gqx[[y, x]] as f64 + s.sy[[y, x]] as f64 * gqy[[y, x]] as f64;
                }
                lin += kt * a[[y, x]] as f64;
                kt2 += kt * kt;
                let (qx, qy) = (self.qx[[y, x]] as f64, self.qy[[y, x]] as f64);
                q2 += qx * qx + qy * qy;
            }
        }
        let dual =
            if self.second.is_some() { f64::NAN } else { lin - theta / 2.0 * kt2 - self.eps / 2.0 * q2 };
        HuberTvReport { primal: self.regulariser_energy() + coupling, dual }
    }
}

/// Per-step constants of the row kernels, each the reference's subexpression evaluated once.
struct Coefficients {
    /// `1 / (1 + σ ε)`.
    dual_scale: f64,
    /// `1 / (1 + τ / θ)`.
    primal_scale: f64,
}

impl Coefficients {
    fn new(eps: f64, theta: f64) -> Self {
        Self { dual_scale: 1.0 / (1.0 + STEP * eps), primal_scale: 1.0 / (1.0 + STEP / theta) }
    }
}

/// One row of the dual update: `q` (updated in place), `d̄` of this row and of the next (`None` on
/// the last row) and `g` of this row.
struct DualRows<'a> {
    qx: &'a mut [f32],
    qy: &'a mut [f32],
    d_bar: &'a [f32],
    below: Option<&'a [f32]>,
    g: &'a [f32],
}

/// One row of the primal update: `d` (updated in place) and `d̄` (written), `q` and `g` of this row
/// and of the previous one (`None` on the first row), whether a next row exists, and `a`.
struct PrimalRows<'a> {
    d: &'a mut [f32],
    d_bar: &'a mut [f32],
    qx: &'a [f32],
    qy: &'a [f32],
    g: &'a [f32],
    above: Option<(&'a [f32], &'a [f32])>,
    has_below: bool,
    /// `(τ a) / θ`.
    a_term: &'a [f64],
}

/// The row kernels of [`HuberTv::step_with`]: generic bodies (`#[inline(always)]`) instantiated
/// for the baseline target, inside an `avx512f` function and inside an `avx2,fma` one, so the
/// compiler may vectorise the latter two 8 and 4 lanes wide. Each pixel's result is a fixed sequence of IEEE operations (no
/// reductions across pixels, no fused multiply-adds), hence the same bits in both builds.
mod kernels {
    use super::{Coefficients, DualRows, PrimalRows, STEP};
    use crate::runtime::CpuFeatureLevel;

    pub(super) fn dual_row(rows: DualRows, k: &Coefficients, level: CpuFeatureLevel) {
        #[cfg(target_arch = "x86_64")]
        if level.avx512f() {
            // SAFETY: `avx512` is only set when the CPU reported AVX-512F (`CpuFeatureLevel::avx512f`).
            unsafe { dual_row_avx512(rows, k) };
            return;
        }
        #[cfg(target_arch = "x86_64")]
        if level.avx2_fma() {
            // SAFETY: `avx2_fma()` reported AVX2 and FMA on this CPU.
            unsafe { dual_row_avx2(rows, k) };
            return;
        }
        let _ = level;
        dual_row_any(rows, k);
    }

    pub(super) fn primal_row(rows: PrimalRows, k: &Coefficients, level: CpuFeatureLevel) {
        #[cfg(target_arch = "x86_64")]
        if level.avx512f() {
            // SAFETY: as in `dual_row`.
            unsafe { primal_row_avx512(rows, k) };
            return;
        }
        #[cfg(target_arch = "x86_64")]
        if level.avx2_fma() {
            // SAFETY: `avx2_fma()` reported AVX2 and FMA on this CPU.
            unsafe { primal_row_avx2(rows, k) };
            return;
        }
        let _ = level;
        primal_row_any(rows, k);
    }

    /// [`dual_row_any`] compiled for AVX2 and FMA (no fused multiply-add is formed: the same bits).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    unsafe fn dual_row_avx2(rows: DualRows, k: &Coefficients) {
        dual_row_any(rows, k);
    }

    /// [`primal_row_any`] compiled for AVX2 and FMA.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2,fma")]
    unsafe fn primal_row_avx2(rows: PrimalRows, k: &Coefficients) {
        primal_row_any(rows, k);
    }

    /// The dual row on AVX-512 registers, 8 pixels at a time, the same operations as [`dual_px`]
    /// lane for lane; where all 8 have `|n|² <= 1` the projection's factor is exactly 1 (`sqrt`
    /// of at most 1 is at most 1, so `1/max(·, 1) = 1`) and its square roots and divisions are
    /// skipped: 91-100 % of the groups in a real solve (SPEC.md §10). NaN fails the test and takes
    /// the full path, whose `vmaxpd` returns the `1` operand for NaN as Rust's `max` does.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f")]
    unsafe fn dual_row_avx512(rows: DualRows, k: &Coefficients) {
        use std::arch::x86_64::*;
        let w = rows.qx.len();
        let (qx, qy, d_bar, g) = (rows.qx, &mut rows.qy[..w], &rows.d_bar[..w], &rows.g[..w]);
        let below = rows.below.map(|b| &b[..w]);
        let load = |v: &[f32], x: usize| _mm512_cvtps_pd(_mm256_loadu_ps(v[x..x + GROUP].as_ptr()));
        let (one, step, scale) = (_mm512_set1_pd(1.0), _mm512_set1_pd(STEP), _mm512_set1_pd(k.dual_scale));
        let mut x = 0;
        while x + GROUP < w {
            let c = load(d_bar, x);
            let gx = _mm512_sub_pd(load(d_bar, x + 1), c);
            let gy = match below {
                Some(b) => _mm512_sub_pd(load(b, x), c),
                None => _mm512_setzero_pd(),
            };
            let sg = _mm512_mul_pd(step, load(g, x));
            let nx = _mm512_mul_pd(_mm512_add_pd(load(qx, x), _mm512_mul_pd(sg, gx)), scale);
            let ny = _mm512_mul_pd(_mm512_add_pd(load(qy, x), _mm512_mul_pd(sg, gy)), scale);
            let n2 = _mm512_add_pd(_mm512_mul_pd(nx, nx), _mm512_mul_pd(ny, ny));
            let (nx, ny) = if _mm512_cmp_pd_mask::<_CMP_LE_OQ>(n2, one) == 0xff {
                (nx, ny)
            } else {
                let shrink = _mm512_div_pd(one, _mm512_max_pd(_mm512_sqrt_pd(n2), one));
                (_mm512_mul_pd(nx, shrink), _mm512_mul_pd(ny, shrink))
            };
            _mm256_storeu_ps(qx[x..x + GROUP].as_mut_ptr(), _mm512_cvtpd_ps(nx));
            _mm256_storeu_ps(qy[x..x + GROUP].as_mut_ptr(), _mm512_cvtpd_ps(ny));
            x += GROUP;
        }
        let rows = DualRows {
            qx: &mut qx[x..],
            qy: &mut qy[x..],
            d_bar: &d_bar[x..],
            below: below.map(|b| &b[x..]),
            g: &g[x..],
        };
        dual_row_any(rows, k);
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f")]
    unsafe fn primal_row_avx512(rows: PrimalRows, k: &Coefficients) {
        primal_row_any(rows, k);
    }

    /// Pixels per group of [`dual_row_avx512`].
    #[cfg(target_arch = "x86_64")]
    const GROUP: usize = 8;

    /// `q ← Π((q + σ g ∇d̄) · s_q)` at one pixel: the reference's expression.
    #[inline(always)]
    fn dual_px(qx: &mut f32, qy: &mut f32, gx: f64, gy: f64, gw: f64, k: &Coefficients) {
        let nx = (*qx as f64 + STEP * gw * gx) * k.dual_scale;
        let ny = (*qy as f64 + STEP * gw * gy) * k.dual_scale;
        let shrink = 1.0 / (nx * nx + ny * ny).sqrt().max(1.0);
        *qx = (nx * shrink) as f32;
        *qy = (ny * shrink) as f32;
    }

    #[inline(always)]
    fn dual_row_any(rows: DualRows, k: &Coefficients) {
        match rows.below {
            Some(b) => dual_body::<true>(rows.qx, rows.qy, rows.d_bar, b, rows.g, k),
            None => dual_body::<false>(rows.qx, rows.qy, rows.d_bar, rows.d_bar, rows.g, k),
        }
    }

    /// `BELOW`: whether `below` is the next row (else the vertical difference is zero).
    #[inline(always)]
    fn dual_body<const BELOW: bool>(
        qx: &mut [f32],
        qy: &mut [f32],
        d_bar: &[f32],
        below: &[f32],
        g: &[f32],
        k: &Coefficients,
    ) {
        let w = qx.len();
        let (qy, d_bar, below, g) = (&mut qy[..w], &d_bar[..w], &below[..w], &g[..w]);
        let vertical = |x: usize, c: f64| if BELOW { below[x] as f64 - c } else { 0.0 };
        for x in 0..w - 1 {
            let c = d_bar[x] as f64;
            dual_px(&mut qx[x], &mut qy[x], d_bar[x + 1] as f64 - c, vertical(x, c), g[x] as f64, k);
        }
        let x = w - 1;
        let c = d_bar[x] as f64;
        dual_px(&mut qx[x], &mut qy[x], 0.0, vertical(x, c), g[x] as f64, k);
    }

    /// `∇ᵀ(g q)` at one pixel from the terms that exist there (`RIGHT`: `x + 1 < w`, `LEFT`:
    /// `x > 0`, `DOWN`: `y + 1 < h`, `UP`: `y > 0`), added in the reference's order.
    #[inline(always)]
    fn adjoint<const RIGHT: bool, const LEFT: bool, const DOWN: bool, const UP: bool>(
        px: f32,
        px_left: f32,
        py: f32,
        py_up: f32,
    ) -> f64 {
        let mut div = 0.0;
        if RIGHT {
            div += px as f64;
        }
        if LEFT {
            div -= px_left as f64;
        }
        if DOWN {
            div += py as f64;
        }
        if UP {
            div -= py_up as f64;
        }
        -div
    }

    /// `d' ← (d - τ kt + τ a / θ) · s_d`, `d̄ ← 2 d' - d` at one pixel (`at` = `(τ a) / θ`).
    #[inline(always)]
    fn primal_px(d: &mut f32, d_bar: &mut f32, kt: f64, at: f64, k: &Coefficients) {
        let old = *d;
        let new = ((old as f64 - STEP * kt + at) * k.primal_scale) as f32;
        *d = new;
        *d_bar = 2.0 * new - old;
    }

    #[inline(always)]
    fn primal_row_any(rows: PrimalRows, k: &Coefficients) {
        let (qy_up, g_up) = rows.above.unwrap_or((rows.qy, rows.g));
        let r = (rows.d, rows.d_bar, rows.qx, rows.qy, rows.g, qy_up, g_up, rows.a_term);
        match (rows.has_below, rows.above.is_some()) {
            (true, true) => primal_body::<true, true>(r, k),
            (true, false) => primal_body::<true, false>(r, k),
            (false, true) => primal_body::<false, true>(r, k),
            (false, false) => primal_body::<false, false>(r, k),
        }
    }

    type PrimalSlices<'a> =
        (&'a mut [f32], &'a mut [f32], &'a [f32], &'a [f32], &'a [f32], &'a [f32], &'a [f32], &'a [f64]);

    /// One row of the primal update; `DOWN` / `UP`: whether the next / previous row exists.
    #[inline(always)]
    fn primal_body<const DOWN: bool, const UP: bool>(r: PrimalSlices, k: &Coefficients) {
        let (d, d_bar, qx, qy, g, qy_up, g_up, a) = r;
        let w = d.len();
        let (d_bar, qx, qy, g, qy_up, g_up, a) =
            (&mut d_bar[..w], &qx[..w], &qy[..w], &g[..w], &qy_up[..w], &g_up[..w], &a[..w]);
        // `g q` in f32, as the reference's `&q * &g`.
        let px = |x: usize| qx[x] * g[x];
        let py = |x: usize| qy[x] * g[x];
        let py_up = |x: usize| qy_up[x] * g_up[x];
        if w == 1 {
            let kt = adjoint::<false, false, DOWN, UP>(0.0, 0.0, py(0), py_up(0));
            primal_px(&mut d[0], &mut d_bar[0], kt, a[0], k);
            return;
        }
        let kt = adjoint::<true, false, DOWN, UP>(px(0), 0.0, py(0), py_up(0));
        primal_px(&mut d[0], &mut d_bar[0], kt, a[0], k);
        for x in 1..w - 1 {
            let kt = adjoint::<true, true, DOWN, UP>(px(x), px(x - 1), py(x), py_up(x));
            primal_px(&mut d[x], &mut d_bar[x], kt, a[x], k);
        }
        let x = w - 1;
        let kt = adjoint::<false, true, DOWN, UP>(0.0, px(x - 1), py(x), py_up(x));
        primal_px(&mut d[x], &mut d_bar[x], kt, a[x], k);
    }
}
