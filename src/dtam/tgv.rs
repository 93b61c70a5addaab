//! Second-order total generalised variation (TGV², Bredies, Kunisch and Pock 2010; in stereo
//! Ranftl, Gehrig, Pock and Bischof 2012) in place of DTAM's Huber-TV (SPEC.md §10.4,
//! `--regularizer tgv`):
//!
//! ```text
//! R(d, v) = Σ_u ‖g(u) (∇d(u) − v(u)/β)‖_ε + Σ_u ‖∇v(u)‖
//! ```
//!
//! `v = (v_x, v_y)` is an auxiliary slope field (inverse depth per pixel, scaled by `β`), `∇v` its
//! 2x2 Jacobian of forward differences with the Frobenius norm. With `w = v/β` this is the textbook
//! `‖∇d − w‖ + β ‖∇w‖`: the first term lets the depth follow any slope `w`, the second makes the
//! slope piecewise constant. On a plane inverse depth is affine in the pixel (SPEC.md §10.2), so a
//! plane costs nothing at any orientation, where TV charges every slanted plane its gradient. `β`
//! is the length, in pixels, over which a change of slope costs what a jump of the same size does;
//! `β → ∞` is TV. The scaling `v = βw` keeps the operator's norm near TV's for every `β`, so the
//! step size stays near TV's (below).
//!
//! **Operator.** `K(d, v) = (∇d − M v/β, ∇v)`, `∇` DTAM's forward differences (zero across the
//! last column / row), `M` zeroing `v_x` in the last column and `v_y` in the last row (there the
//! difference is zero, so a plane stays in the null space up to the border). The solver's operator
//! is `diag(g)` on the first part. Adjoint (`−div` the adjoint of `∇`):
//! `K_dᵀ(p, r) = −div p`, `K_vᵀ(p, r) = −M p/β − (div(r_xx, r_xy), div(r_yx, r_yy))`.
//! With `g ≤ 1`, `‖K(d, v)‖² ≤ (√8‖d‖ + ‖v‖/β)² + 8‖v‖²`, so `L² = λ_max [[8, √8/β], [√8/β, 8 + 1/β²]]`
//! bounds `‖K‖²` and the solver steps with `σ = τ = 1/L` ([`step_size`]; `1/√8` as `β → ∞`).
//!
//! This file holds the definition: `K` and `Kᵀ` in f64, the regulariser's row term, and
//! [`Reference`], a naive f64 primal-dual solver the row-parallel f32 steps (`tgv_steps.rs`) are
//! tested against.

use ndarray::{Array2, ArrayView2};

use super::huber_tv::huber;
use crate::error::{Error, Result};

/// `β` when `--tgv-beta` is not given, in pixels at [`super::REFERENCE_WIDTH`] (SPEC.md §10.4):
/// of 4 and 16, 16 was the better on the validation scenes for depth (both feature kinds) and meshes.
pub const DEFAULT_BETA: f64 = 16.0;

/// `β` at the solver's grid for `beta` stated at [`super::REFERENCE_WIDTH`]: `β r` with
/// `r = width / REFERENCE_WIDTH` (a slope per pixel scales as `1/r`, its change per pixel as
/// `1/r²`, so the two terms keep their continuous ratio; SPEC.md §10.4).
pub fn normalised_beta(beta: f64, width: usize) -> f64 {
    beta * width as f64 / super::REFERENCE_WIDTH
}

/// Check `β`: positive and finite.
///
/// # Errors
/// [`Error::InvalidArgument`] naming `--tgv-beta`.
pub fn check_beta(beta: f64) -> Result<()> {
    if beta > 0.0 && beta.is_finite() {
        Ok(())
    } else {
        Err(Error::invalid_argument("--tgv-beta", format!("{beta}: must be positive and finite")))
    }
}

/// `σ = τ = 1/L`, `L² = λ_max [[8, √8/β], [√8/β, 8 + 1/β²]]` (module docs).
pub fn step_size(beta: f64) -> f64 {
    let (a, b, c) = (8.0, 8f64.sqrt() / beta, 8.0 + 1.0 / (beta * beta));
    let l2 = 0.5 * (a + c + ((a - c) * (a - c) + 4.0 * b * b).sqrt());
    1.0 / l2.sqrt()
}

/// The primal state `(d, v_x, v_y)` or its image under `Kᵀ`, in f64.
#[derive(Clone, Debug, PartialEq)]
pub struct Primal {
    /// Inverse depth.
    pub d: Array2<f64>,
    /// Slope field, `x` component (scaled by `β`).
    pub vx: Array2<f64>,
    /// Slope field, `y` component.
    pub vy: Array2<f64>,
}

/// The dual state `(p, r)` or the image of a primal under `K`, in f64.
#[derive(Clone, Debug, PartialEq)]
pub struct Dual {
    /// First-order part, `x`.
    pub px: Array2<f64>,
    /// First-order part, `y`.
    pub py: Array2<f64>,
    /// Second-order part: pairs with `∂x v_x`, `∂y v_x`, `∂x v_y`, `∂y v_y`.
    pub r: [Array2<f64>; 4],
}

fn dx(a: &ArrayView2<f64>, y: usize, x: usize) -> f64 {
    if x + 1 < a.ncols() {
        a[[y, x + 1]] - a[[y, x]]
    } else {
        0.0
    }
}

fn dy(a: &ArrayView2<f64>, y: usize, x: usize) -> f64 {
    if y + 1 < a.nrows() {
        a[[y + 1, x]] - a[[y, x]]
    } else {
        0.0
    }
}

/// `−div (px, py)` at `(y, x)`: the adjoint of the forward differences (also the normal prior's).
pub(crate) fn neg_div(px: &ArrayView2<f64>, py: &ArrayView2<f64>, y: usize, x: usize) -> f64 {
    let (h, w) = px.dim();
    let mut div = 0.0;
    if x + 1 < w {
        div += px[[y, x]];
    }
    if x > 0 {
        div -= px[[y, x - 1]];
    }
    if y + 1 < h {
        div += py[[y, x]];
    }
    if y > 0 {
        div -= py[[y - 1, x]];
    }
    -div
}

/// `K(d, v)` in f64 (the definition, without the edge weights).
pub fn apply(x: &Primal, beta: f64) -> Dual {
    let (d, vx, vy) = (x.d.view(), x.vx.view(), x.vy.view());
    let (h, w) = d.dim();
    let px = Array2::from_shape_fn(
        (h, w),
        |(y, x)| if x + 1 < w { dx(&d, y, x) - vx[[y, x]] / beta } else { 0.0 },
    );
    let py = Array2::from_shape_fn(
        (h, w),
        |(y, x)| if y + 1 < h { dy(&d, y, x) - vy[[y, x]] / beta } else { 0.0 },
    );
    let r = [
        Array2::from_shape_fn((h, w), |(y, x)| dx(&vx, y, x)),
        Array2::from_shape_fn((h, w), |(y, x)| dy(&vx, y, x)),
        Array2::from_shape_fn((h, w), |(y, x)| dx(&vy, y, x)),
        Array2::from_shape_fn((h, w), |(y, x)| dy(&vy, y, x)),
    ];
    Dual { px, py, r }
}

/// `Kᵀ(p, r)` in f64 (the definition).
pub fn adjoint(p: &Dual, beta: f64) -> Primal {
    let (px, py) = (p.px.view(), p.py.view());
    let r: [ArrayView2<f64>; 4] = std::array::from_fn(|i| p.r[i].view());
    let (h, w) = px.dim();
    let d = Array2::from_shape_fn((h, w), |(y, x)| neg_div(&px, &py, y, x));
    let vx = Array2::from_shape_fn((h, w), |(y, x)| {
        let m = if x + 1 < w { px[[y, x]] / beta } else { 0.0 };
        -m + neg_div(&r[0], &r[1], y, x)
    });
    let vy = Array2::from_shape_fn((h, w), |(y, x)| {
        let m = if y + 1 < h { py[[y, x]] / beta } else { 0.0 };
        -m + neg_div(&r[2], &r[3], y, x)
    });
    Primal { d, vx, vy }
}

/// One row's arrays of the f32 state, for [`regulariser_row`].
#[derive(Clone, Copy, Debug)]
pub(crate) struct Rows<'a> {
    pub(crate) d: &'a [f32],
    pub(crate) vx: &'a [f32],
    pub(crate) vy: &'a [f32],
    /// The next row's `d`, `v_x`, `v_y` (`None` on the last row).
    pub(crate) below: Option<(&'a [f32], &'a [f32], &'a [f32])>,
    pub(crate) g: &'a [f32],
}

/// `Σ_x ‖g (∇d − M v/β)‖_ε + ‖∇v‖` over one row, in f64 with `x` ascending: the row term of the
/// regulariser energy (the solver's energy and [`Reference::regulariser_energy`] agree to rounding).
pub(crate) fn regulariser_row(rows: Rows, beta: f64, eps: f64) -> f64 {
    let Rows { d, vx, vy, below, g } = rows;
    let w = d.len();
    (0..w)
        .map(|x| {
            let f = |v: &[f32]| v[x] as f64;
            let right = |v: &[f32]| if x + 1 < w { v[x + 1] as f64 - v[x] as f64 } else { 0.0 };
            let down = |v: &[f32], b: &[f32]| b[x] as f64 - v[x] as f64;
            let kx = if x + 1 < w { right(d) - f(vx) / beta } else { 0.0 };
            let (ky, jxy, jyy) = match below {
                Some((bd, bx, by)) => (down(d, bd) - f(vy) / beta, down(vx, bx), down(vy, by)),
                None => (0.0, 0.0, 0.0),
            };
            let (jxx, jyx) = (right(vx), right(vy));
            let gw = g[x] as f64;
            huber(gw * kx, gw * ky, eps) + (jxx * jxx + jxy * jxy + jyx * jyx + jyy * jyy).sqrt()
        })
        .sum()
}

/// The naive f64 Chambolle-Pock solver of `min_{d,v} R(d, v) + 1/(2θ) ‖d − a‖²`: whole-array
/// passes through [`apply`] and [`adjoint`], every value in f64. The oracle of the row-parallel f32
/// steps.
#[derive(Clone, Debug)]
pub struct Reference {
    /// Primal `(d, v)`.
    pub x: Primal,
    x_bar: Primal,
    /// Dual `(p, r)`.
    pub p: Dual,
    g: Array2<f64>,
    beta: f64,
    eps: f64,
    step: f64,
}

impl Reference {
    /// Start from `d0`, `v = 0`, zero dual.
    pub fn new(d0: ArrayView2<f32>, g: ArrayView2<f32>, eps: f64, beta: f64) -> Self {
        let d = d0.mapv(f64::from);
        let z = Array2::<f64>::zeros(d.dim());
        let x = Primal { d, vx: z.clone(), vy: z.clone() };
        let p = Dual { px: z.clone(), py: z.clone(), r: std::array::from_fn(|_| z.clone()) };
        Self { x_bar: x.clone(), x, p, g: g.mapv(f64::from), beta, eps, step: step_size(beta) }
    }

    /// One step: `p ← Π((p + σ g K₁x̄)/(1 + σε))`, `r ← Π(r + σ K₂x̄)`,
    /// `x' = prox(x − τ Kᵀ(g p, r))` (`d` coupled to `a`, `v` free), `x̄ ← 2x' − x`.
    pub fn step(&mut self, a: ArrayView2<f32>, theta: f64) {
        let s = self.step;
        let k = apply(&self.x_bar, self.beta);
        for ((y, x), px) in self.p.px.indexed_iter_mut() {
            let g = self.g[[y, x]];
            let nx = (*px + s * g * k.px[[y, x]]) / (1.0 + s * self.eps);
            let ny = (self.p.py[[y, x]] + s * g * k.py[[y, x]]) / (1.0 + s * self.eps);
            let m = (nx * nx + ny * ny).sqrt().max(1.0);
            *px = nx / m;
            self.p.py[[y, x]] = ny / m;
        }
        let (h, w) = self.g.dim();
        for y in 0..h {
            for x in 0..w {
                let n: [f64; 4] = std::array::from_fn(|i| self.p.r[i][[y, x]] + s * k.r[i][[y, x]]);
                let m = n.iter().map(|v| v * v).sum::<f64>().sqrt().max(1.0);
                for (i, v) in n.iter().enumerate() {
                    self.p.r[i][[y, x]] = v / m;
                }
            }
        }
        let weighted = Dual { px: &self.p.px * &self.g, py: &self.p.py * &self.g, r: self.p.r.clone() };
        let kt = adjoint(&weighted, self.beta);
        let old = self.x.clone();
        for ((y, x), d) in self.x.d.indexed_iter_mut() {
            *d = (*d - s * kt.d[[y, x]] + s * a[[y, x]] as f64 / theta) / (1.0 + s / theta);
        }
        self.x.vx = &self.x.vx - &(&kt.vx * s);
        self.x.vy = &self.x.vy - &(&kt.vy * s);
        self.x_bar = Primal {
            d: &self.x.d * 2.0 - &old.d,
            vx: &self.x.vx * 2.0 - &old.vx,
            vy: &self.x.vy * 2.0 - &old.vy,
        };
    }

    /// `R(d, v)` in f64.
    pub fn regulariser_energy(&self) -> f64 {
        let k = apply(&self.x, self.beta);
        let mut e = 0.0;
        for ((y, x), g) in self.g.indexed_iter() {
            let j = k.r.iter().map(|r| r[[y, x]] * r[[y, x]]).sum::<f64>().sqrt();
            e += huber(g * k.px[[y, x]], g * k.py[[y, x]], self.eps) + j;
        }
        e
    }
}
