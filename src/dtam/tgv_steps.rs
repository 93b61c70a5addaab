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

/// The rows of an owned array, for a row-parallel pass.
fn rows_mut(a: &mut Array2<f32>) -> rayon::slice::ChunksMut<'_, f32> {
    let w = a.ncols().max(1);
    a.as_slice_mut().expect("owned arrays are contiguous").par_chunks_mut(w)
}

/// One row of the dual update: `p ← Π((p + σ g (∇d̄ − M v̄/β)) s_p)`, `r ← Π(r + σ ∇v̄)`.
/// `BELOW`: whether the next row exists (else the `y` differences are 0).
#[inline(always)]
fn dual_row<const BELOW: bool>(
    (px, py): (&mut [f32], &mut [f32]),
    r: [&mut [f32]; 4],
    (c, vx, vy): (&[f32], &[f32], &[f32]),
    (bd, bx, by): (&[f32], &[f32], &[f32]),
    g: &[f32],
    k: &Constants,
) {
    let w = c.len();
    let [r0, r1, r2, r3] = r;
    let pixel = |x: usize, right: bool, px: &mut f32, py: &mut f32, q: [&mut f32; 4]| {
        let cv = c[x] as f64;
        let (vxv, vyv) = (vx[x] as f64, vy[x] as f64);
        let (kx, jxx, jyx) = if right {
            (c[x + 1] as f64 - cv - vxv * k.inv_beta, vx[x + 1] as f64 - vxv, vy[x + 1] as f64 - vyv)
        } else {
            (0.0, 0.0, 0.0)
        };
        let (ky, jxy, jyy) = if BELOW {
            (bd[x] as f64 - cv - vyv * k.inv_beta, bx[x] as f64 - vxv, by[x] as f64 - vyv)
        } else {
            (0.0, 0.0, 0.0)
        };
        let gv = g[x] as f64;
        let nx = (*px as f64 + k.s * gv * kx) * k.dual_scale;
        let ny = (*py as f64 + k.s * gv * ky) * k.dual_scale;
        let shrink = 1.0 / (nx * nx + ny * ny).sqrt().max(1.0);
        *px = (nx * shrink) as f32;
        *py = (ny * shrink) as f32;
        let [q0, q1, q2, q3] = q;
        let m =
            [*q0 as f64 + k.s * jxx, *q1 as f64 + k.s * jxy, *q2 as f64 + k.s * jyx, *q3 as f64 + k.s * jyy];
        let shrink = 1.0 / (m[0] * m[0] + m[1] * m[1] + m[2] * m[2] + m[3] * m[3]).sqrt().max(1.0);
        *q0 = (m[0] * shrink) as f32;
        *q1 = (m[1] * shrink) as f32;
        *q2 = (m[2] * shrink) as f32;
        *q3 = (m[3] * shrink) as f32;
    };
    if w == 0 {
        return;
    }
    for x in 0..w - 1 {
        pixel(x, true, &mut px[x], &mut py[x], [&mut r0[x], &mut r1[x], &mut r2[x], &mut r3[x]]);
    }
    let x = w - 1;
    pixel(x, false, &mut px[x], &mut py[x], [&mut r0[x], &mut r1[x], &mut r2[x], &mut r3[x]]);
}

/// The rows the primal update of row `y` reads.
struct PrimalIn<'a> {
    px: &'a [f32],
    py: &'a [f32],
    g: &'a [f32],
    /// Row `y − 1`'s `p_y` and `g` (`None` on the first row).
    up: Option<(&'a [f32], &'a [f32])>,
    /// `r` of row `y`, and `r_xy`, `r_yy` of row `y − 1`.
    r: [&'a [f32]; 4],
    r_up: Option<(&'a [f32], &'a [f32])>,
    a_term: &'a [f64],
}

/// One row of the primal update: `d' = (d − τ(−div(g p)) + τa/θ) s_d`,
/// `v' = v − τ(−M g p/β − div r)`, and the extrapolations. `BELOW`: whether the next row exists.
#[inline(always)]
fn primal_row<const BELOW: bool>(
    (d, d_bar): (&mut [f32], &mut [f32]),
    (vx, vxb, vy, vyb): (&mut [f32], &mut [f32], &mut [f32], &mut [f32]),
    i: &PrimalIn,
    k: &Constants,
) {
    let w = d.len();
    // `g p` in f32, as the Huber-TV step's `q * g`.
    let gpx = |x: usize| i.px[x] * i.g[x];
    let gpy = |x: usize| i.py[x] * i.g[x];
    for x in 0..w {
        let (left, right) = (x > 0, x + 1 < w);
        let mut div_d = 0.0;
        let (mut div_x, mut div_y) = (0.0, 0.0);
        if right {
            div_d += gpx(x) as f64;
            div_x += i.r[0][x] as f64;
            div_y += i.r[2][x] as f64;
        }
        if left {
            div_d -= gpx(x - 1) as f64;
            div_x -= i.r[0][x - 1] as f64;
            div_y -= i.r[2][x - 1] as f64;
        }
        if BELOW {
            div_d += gpy(x) as f64;
            div_x += i.r[1][x] as f64;
            div_y += i.r[3][x] as f64;
        }
        if let Some((py_up, g_up)) = i.up {
            div_d -= (py_up[x] * g_up[x]) as f64;
        }
        if let Some((r1_up, r3_up)) = i.r_up {
            div_x -= r1_up[x] as f64;
            div_y -= r3_up[x] as f64;
        }
        let old = d[x];
        let new = ((old as f64 + k.s * div_d + i.a_term[x]) * k.primal_scale) as f32;
        d[x] = new;
        d_bar[x] = 2.0 * new - old;
        let mx = if right { gpx(x) as f64 * k.inv_beta } else { 0.0 };
        let my = if BELOW { gpy(x) as f64 * k.inv_beta } else { 0.0 };
        let (ox, oy) = (vx[x], vy[x]);
        let (nx, ny) = ((ox as f64 + k.s * (mx + div_x)) as f32, (oy as f64 + k.s * (my + div_y)) as f32);
        vx[x] = nx;
        vy[x] = ny;
        vxb[x] = 2.0 * nx - ox;
        vyb[x] = 2.0 * ny - oy;
    }
}

/// Per-step constants, each evaluated once.
struct Constants {
    s: f64,
    inv_beta: f64,
    dual_scale: f64,
    primal_scale: f64,
}

impl HuberTv {
    /// `n` steps of the TGV² solve for fixed `a`, `θ` (`HuberTv::steps_with` with the second order).
    pub(super) fn tgv_steps(&mut self, a: &[f32], theta: f64, n: usize) {
        let so = self.second.as_mut().expect("TGV steps need the second-order state");
        let (h, w) = self.d.dim();
        let s = so.step;
        let k = Constants {
            s,
            inv_beta: 1.0 / so.beta,
            dual_scale: 1.0 / (1.0 + s * self.eps),
            primal_scale: 1.0 / (1.0 + s / theta),
        };
        // `(τ a) / θ` in the Huber-TV step's scratch, formed once per call.
        self.a_term.clear();
        self.a_term.extend(a.iter().map(|&a| s * a as f64 / theta));
        let a_term = &self.a_term;
        for _ in 0..n {
            // Dual: p from g (∇d̄ − M v̄/β), r from ∇v̄.
            let (d_bar, g) = (slice(&self.d_bar), slice(&self.g));
            let (vxb, vyb) = (slice(&so.vx_bar), slice(&so.vy_bar));
            let [r0, r1, r2, r3] = &mut so.r;
            let rs = rows_mut(r0).zip(rows_mut(r1)).zip(rows_mut(r2)).zip(rows_mut(r3));
            rows_mut(&mut self.qx).zip(rows_mut(&mut self.qy)).zip(rs).enumerate().for_each(
                |(y, ((rx, ry), (((q0, q1), q2), q3)))| {
                    let here = (row(d_bar, y, w), row(vxb, y, w), row(vyb, y, w));
                    let (p, r, g) = ((rx, ry), [q0, q1, q2, q3], row(g, y, w));
                    if y + 1 < h {
                        let below = (row(d_bar, y + 1, w), row(vxb, y + 1, w), row(vyb, y + 1, w));
                        dual_row::<true>(p, r, here, below, g, &k);
                    } else {
                        dual_row::<false>(p, r, here, here, g, &k);
                    }
                },
            );
            // Primal: d from −div(g p) and the coupling, v from −M g p/β − div r; then the
            // extrapolations.
            let (px, py, g) = (slice(&self.qx), slice(&self.qy), slice(&self.g));
            let [r0, r1, r2, r3] = &so.r;
            let (r0, r1, r2, r3) = (slice(r0), slice(r1), slice(r2), slice(r3));
            let vs = rows_mut(&mut so.vx)
                .zip(rows_mut(&mut so.vx_bar))
                .zip(rows_mut(&mut so.vy))
                .zip(rows_mut(&mut so.vy_bar));
            rows_mut(&mut self.d).zip(rows_mut(&mut self.d_bar)).zip(vs).enumerate().for_each(
                |(y, ((rd, rb), (((vx, vxb), vy), vyb)))| {
                    let i = PrimalIn {
                        px: row(px, y, w),
                        py: row(py, y, w),
                        g: row(g, y, w),
                        up: (y > 0).then(|| (row(py, y - 1, w), row(g, y - 1, w))),
                        r: [row(r0, y, w), row(r1, y, w), row(r2, y, w), row(r3, y, w)],
                        r_up: (y > 0).then(|| (row(r1, y - 1, w), row(r3, y - 1, w))),
                        a_term: row(a_term, y, w),
                    };
                    if y + 1 < h {
                        primal_row::<true>((rd, rb), (vx, vxb, vy, vyb), &i, &k);
                    } else {
                        primal_row::<false>((rd, rb), (vx, vxb, vy, vyb), &i, &k);
                    }
                },
            );
        }
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
