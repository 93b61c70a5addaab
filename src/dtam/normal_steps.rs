//! The primal-dual steps of the normal prior (SPEC.md §10.2) on [`HuberTv`]'s f32 state: two
//! row-parallel passes per step, as the Huber-TV step, with `K_n = ∇ − q` in place of `∇` and the
//! step size `1/(√8 + Q)`. Every pixel's value is a fixed sequence of f64 operations on the f32
//! inputs (no reductions across pixels), so the bits do not depend on the thread count; the naive
//! f64 oracle is `super::normal_prior::Reference` (tests/dtam_normals.rs states the budget).

use ndarray::Array2;
use rayon::prelude::*;

use super::HuberTv;

/// The slope field `q` of the prior on the solver's grid and its step size.
#[derive(Clone, Debug)]
pub(crate) struct Slope {
    pub(crate) sx: Array2<f32>,
    pub(crate) sy: Array2<f32>,
    pub(crate) step: f64,
}

impl HuberTv {
    /// `n` steps of the normal-prior solve for fixed `a`, `θ` (`HuberTv::steps_with` with a slope).
    pub(super) fn slope_steps(&mut self, a: &[f32], theta: f64, n: usize) {
        let slope = self.slope.as_ref().expect("slope steps need a slope field");
        let (h, w) = self.d.dim();
        let s = slope.step;
        let dual_scale = 1.0 / (1.0 + s * self.eps);
        let primal_scale = 1.0 / (1.0 + s / theta);
        let a_term: Vec<f64> = a.iter().map(|&a| s * a as f64 / theta).collect();
        let (sx, sy) = (slope.sx.as_slice().expect("contiguous"), slope.sy.as_slice().expect("contiguous"));
        let g = self.g.as_slice().expect("contiguous");
        for _ in 0..n {
            let d_bar = self.d_bar.as_slice().expect("contiguous");
            let px = self.qx.as_slice_mut().expect("owned arrays are contiguous");
            let py = self.qy.as_slice_mut().expect("owned arrays are contiguous");
            px.par_chunks_mut(w).zip(py.par_chunks_mut(w)).enumerate().for_each(|(y, (rx, ry))| {
                fn row(v: &[f32], r: usize, w: usize) -> &[f32] {
                    &v[r * w..][..w]
                }
                let (c, gw, qx, qy) = (row(d_bar, y, w), row(g, y, w), row(sx, y, w), row(sy, y, w));
                let below = (y + 1 < h).then(|| row(d_bar, y + 1, w));
                for x in 0..w {
                    let cv = c[x] as f64;
                    let dx = if x + 1 < w { c[x + 1] as f64 - cv } else { 0.0 };
                    let dy = below.map_or(0.0, |b| b[x] as f64 - cv);
                    let kx = dx - cv * qx[x] as f64;
                    let ky = dy - cv * qy[x] as f64;
                    let gv = gw[x] as f64;
                    let nx = (rx[x] as f64 + s * gv * kx) * dual_scale;
                    let ny = (ry[x] as f64 + s * gv * ky) * dual_scale;
                    let shrink = 1.0 / (nx * nx + ny * ny).sqrt().max(1.0);
                    rx[x] = (nx * shrink) as f32;
                    ry[x] = (ny * shrink) as f32;
                }
            });
            let (px, py) = (self.qx.as_slice().expect("contiguous"), self.qy.as_slice().expect("contiguous"));
            let d = self.d.as_slice_mut().expect("owned arrays are contiguous");
            let d_bar = self.d_bar.as_slice_mut().expect("owned arrays are contiguous");
            d.par_chunks_mut(w).zip(d_bar.par_chunks_mut(w)).enumerate().for_each(|(y, (rd, rb))| {
                let at = |v: &[f32], x: usize| v[y * w + x];
                // `g p` in f32, as the Huber-TV step's `q * g`.
                let gpx = |x: usize| at(px, x) * at(g, x);
                let gpy = |x: usize| at(py, x) * at(g, x);
                for x in 0..w {
                    let mut div = 0.0;
                    if x + 1 < w {
                        div += gpx(x) as f64;
                    }
                    if x > 0 {
                        div -= gpx(x - 1) as f64;
                    }
                    if y + 1 < h {
                        div += gpy(x) as f64;
                    }
                    if y > 0 {
                        div -= (py[(y - 1) * w + x] * g[(y - 1) * w + x]) as f64;
                    }
                    let kt = -div - (at(sx, x) as f64 * gpx(x) as f64 + at(sy, x) as f64 * gpy(x) as f64);
                    let old = rd[x];
                    let new = ((old as f64 - s * kt + a_term[y * w + x]) * primal_scale) as f32;
                    rd[x] = new;
                    rb[x] = 2.0 * new - old;
                }
            });
        }
    }
}

/// `Σ_x ‖g K_n d‖_ε` over one row (`below`: the next row of `d`, `None` on the last row; `sx`,
/// `sy`: the row's slope field), summed in f64 with `x` ascending: the row term of
/// [`HuberTv::regulariser_energy`] with a slope field.
pub(crate) fn slope_regulariser_row(
    d: &[f32],
    below: Option<&[f32]>,
    g: &[f32],
    sx: &[f32],
    sy: &[f32],
    eps: f64,
) -> f64 {
    let w = d.len();
    (0..w)
        .map(|x| {
            let c = d[x] as f64;
            let dx = if x + 1 < w { d[x + 1] as f64 - c } else { 0.0 };
            let dy = below.map_or(0.0, |b| b[x] as f64 - c);
            let gw = g[x] as f64;
            super::huber(gw * (dx - c * sx[x] as f64), gw * (dy - c * sy[x] as f64), eps)
        })
        .sum()
}
