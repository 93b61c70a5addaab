//! The primal-dual steps of TGV² (SPEC.md §10.4) on [`HuberTv`]'s f32 state plus the slope field
//! `v` and its dual `r`: two row-parallel passes per step, as the Huber-TV step. Every pixel's value
//! is a fixed sequence of f64 operations on f32 inputs (no reductions across pixels), so the bits
//! do not depend on the thread count; the naive f64 oracle is `super::tgv::Reference`
//! (tests/dtam_tgv.rs states the budget).

use ndarray::Array2;
use rayon::prelude::*;

use super::HuberTv;
use crate::dtam::tgv::{self, Rows};

/// The second-order state: `v`, its extrapolation `v̄`, the dual `r` and the constants.
#[derive(Clone, Debug)]
pub(crate) struct SecondOrder {
    pub(crate) vx: Array2<f32>,
    pub(crate) vy: Array2<f32>,
    pub(crate) vx_bar: Array2<f32>,
    pub(crate) vy_bar: Array2<f32>,
    /// Pairs with `∂x v_x`, `∂y v_x`, `∂x v_y`, `∂y v_y`.
    pub(crate) r: [Array2<f32>; 4],
    pub(crate) beta: f64,
    pub(crate) step: f64,
}

impl SecondOrder {
    pub(crate) fn new(dim: (usize, usize), beta: f64) -> Self {
        let z = Array2::<f32>::zeros(dim);
        Self {
            vx: z.clone(),
            vy: z.clone(),
            vx_bar: z.clone(),
            vy_bar: z.clone(),
            r: std::array::from_fn(|_| z.clone()),
            beta,
            step: tgv::step_size(beta),
        }
    }
}

fn row<T>(v: &[T], y: usize, w: usize) -> &[T] {
    &v[y * w..][..w]
}

fn slice(a: &Array2<f32>) -> &[f32] {
    a.as_slice().expect("owned arrays are contiguous")
}

/// `−div (a, b)` at column `x` of row `y`: `a` the row's `x` component, `b` the row's `y` component,
/// `b_up` the previous row's (`None` on the first row); `last_row` drops `b` (zero difference).
#[inline(always)]
fn neg_div(a: &[f32], b: &[f32], b_up: Option<&[f32]>, last_row: bool, x: usize) -> f64 {
    let w = a.len();
    let mut div = 0.0;
    if x + 1 < w {
        div += a[x] as f64;
    }
    if x > 0 {
        div -= a[x - 1] as f64;
    }
    if !last_row {
        div += b[x] as f64;
    }
    if let Some(up) = b_up {
        div -= up[x] as f64;
    }
    -div
}

impl HuberTv {
    /// `n` steps of the TGV² solve for fixed `a`, `θ` (`HuberTv::steps_with` with the second order).
    pub(super) fn tgv_steps(&mut self, a: &[f32], theta: f64, n: usize) {
        let mut so = self.second.take().expect("TGV steps need the second-order state");
        let (h, w) = self.d.dim();
        let (s, beta) = (so.step, so.beta);
        let dual_scale = 1.0 / (1.0 + s * self.eps);
        let primal_scale = 1.0 / (1.0 + s / theta);
        let a_term: Vec<f64> = a.iter().map(|&a| s * a as f64 / theta).collect();
        for _ in 0..n {
            // Dual: p from g (∇d̄ − M v̄/β), r from ∇v̄.
            {
                let (d_bar, g) = (slice(&self.d_bar), slice(&self.g));
                let (vxb, vyb) = (slice(&so.vx_bar), slice(&so.vy_bar));
                let px = self.qx.as_slice_mut().expect("owned arrays are contiguous");
                let py = self.qy.as_slice_mut().expect("owned arrays are contiguous");
                let [r0, r1, r2, r3] = &mut so.r;
                let rs = r0
                    .as_slice_mut()
                    .expect("contiguous")
                    .par_chunks_mut(w)
                    .zip(r1.as_slice_mut().expect("contiguous").par_chunks_mut(w))
                    .zip(r2.as_slice_mut().expect("contiguous").par_chunks_mut(w))
                    .zip(r3.as_slice_mut().expect("contiguous").par_chunks_mut(w));
                px.par_chunks_mut(w).zip(py.par_chunks_mut(w)).zip(rs).enumerate().for_each(
                    |(y, ((rx, ry), (((q0, q1), q2), q3)))| {
                        let (c, gw, vx, vy) =
                            (row(d_bar, y, w), row(g, y, w), row(vxb, y, w), row(vyb, y, w));
                        let below = (y + 1 < h)
                            .then(|| (row(d_bar, y + 1, w), row(vxb, y + 1, w), row(vyb, y + 1, w)));
                        for x in 0..w {
                            let cv = c[x] as f64;
                            let (vxv, vyv) = (vx[x] as f64, vy[x] as f64);
                            let kx = if x + 1 < w { c[x + 1] as f64 - cv - vxv / beta } else { 0.0 };
                            let (ky, jxy, jyy) = match below {
                                Some((bd, bx, by)) => {
                                    (bd[x] as f64 - cv - vyv / beta, bx[x] as f64 - vxv, by[x] as f64 - vyv)
                                }
                                None => (0.0, 0.0, 0.0),
                            };
                            let (jxx, jyx) = if x + 1 < w {
                                (vx[x + 1] as f64 - vxv, vy[x + 1] as f64 - vyv)
                            } else {
                                (0.0, 0.0)
                            };
                            let gv = gw[x] as f64;
                            let nx = (rx[x] as f64 + s * gv * kx) * dual_scale;
                            let ny = (ry[x] as f64 + s * gv * ky) * dual_scale;
                            let shrink = 1.0 / (nx * nx + ny * ny).sqrt().max(1.0);
                            rx[x] = (nx * shrink) as f32;
                            ry[x] = (ny * shrink) as f32;
                            let m = [
                                q0[x] as f64 + s * jxx,
                                q1[x] as f64 + s * jxy,
                                q2[x] as f64 + s * jyx,
                                q3[x] as f64 + s * jyy,
                            ];
                            let shrink =
                                1.0 / (m[0] * m[0] + m[1] * m[1] + m[2] * m[2] + m[3] * m[3]).sqrt().max(1.0);
                            q0[x] = (m[0] * shrink) as f32;
                            q1[x] = (m[1] * shrink) as f32;
                            q2[x] = (m[2] * shrink) as f32;
                            q3[x] = (m[3] * shrink) as f32;
                        }
                    },
                );
            }
            // Primal: d from −div(g p) and the coupling, v from −M g p/β − div r; then the
            // extrapolations.
            let (px, py, g) = (slice(&self.qx), slice(&self.qy), slice(&self.g));
            let [r0, r1, r2, r3] = &so.r;
            let (r0, r1, r2, r3) = (slice(r0), slice(r1), slice(r2), slice(r3));
            let d = self.d.as_slice_mut().expect("owned arrays are contiguous");
            let d_bar = self.d_bar.as_slice_mut().expect("owned arrays are contiguous");
            let vs = so
                .vx
                .as_slice_mut()
                .expect("contiguous")
                .par_chunks_mut(w)
                .zip(so.vx_bar.as_slice_mut().expect("contiguous").par_chunks_mut(w))
                .zip(so.vy.as_slice_mut().expect("contiguous").par_chunks_mut(w))
                .zip(so.vy_bar.as_slice_mut().expect("contiguous").par_chunks_mut(w));
            d.par_chunks_mut(w).zip(d_bar.par_chunks_mut(w)).zip(vs).enumerate().for_each(
                |(y, ((rd, rb), (((vx, vxb), vy), vyb)))| {
                    let last_row = y + 1 >= h;
                    // `g p` in f32, as the Huber-TV step's `q * g`.
                    let gpx: Vec<f32> = (0..w).map(|x| row(px, y, w)[x] * row(g, y, w)[x]).collect();
                    let gpy: Vec<f32> = (0..w).map(|x| row(py, y, w)[x] * row(g, y, w)[x]).collect();
                    let gpy_up: Option<Vec<f32>> =
                        (y > 0).then(|| (0..w).map(|x| row(py, y - 1, w)[x] * row(g, y - 1, w)[x]).collect());
                    let (r1_up, r3_up) =
                        ((y > 0).then(|| row(r1, y - 1, w)), (y > 0).then(|| row(r3, y - 1, w)));
                    let (q0, q1, q2, q3) = (row(r0, y, w), row(r1, y, w), row(r2, y, w), row(r3, y, w));
                    for x in 0..w {
                        let kt_d = neg_div(&gpx, &gpy, gpy_up.as_deref(), last_row, x);
                        let old = rd[x];
                        let new = ((old as f64 - s * kt_d + a_term[y * w + x]) * primal_scale) as f32;
                        rd[x] = new;
                        rb[x] = 2.0 * new - old;
                        let mx = if x + 1 < w { gpx[x] as f64 / beta } else { 0.0 };
                        let kt_x = -mx + neg_div(q0, q1, r1_up, last_row, x);
                        let my = if !last_row { gpy[x] as f64 / beta } else { 0.0 };
                        let kt_y = -my + neg_div(q2, q3, r3_up, last_row, x);
                        let (ox, oy) = (vx[x], vy[x]);
                        let (nx, ny) = ((ox as f64 - s * kt_x) as f32, (oy as f64 - s * kt_y) as f32);
                        vx[x] = nx;
                        vy[x] = ny;
                        vxb[x] = 2.0 * nx - ox;
                        vyb[x] = 2.0 * ny - oy;
                    }
                },
            );
        }
        self.second = Some(so);
    }

    /// Row `y` of the TGV² state for [`tgv::regulariser_row`], with `β` (`None` without the
    /// second order).
    pub(crate) fn tgv_rows(&self, y: usize) -> Option<(Rows<'_>, f64)> {
        let so = self.second.as_ref()?;
        let (h, w) = self.d.dim();
        let (d, vx, vy) = (slice(&self.d), slice(&so.vx), slice(&so.vy));
        let below = (y + 1 < h).then(|| (row(d, y + 1, w), row(vx, y + 1, w), row(vy, y + 1, w)));
        Some((
            Rows {
                d: row(d, y, w),
                vx: row(vx, y, w),
                vy: row(vy, y, w),
                below,
                g: row(slice(&self.g), y, w),
            },
            so.beta,
        ))
    }
}
