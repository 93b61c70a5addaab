//! The portable Winograd kernel: the three stages in plain Rust, any channel counts, every target,
//! with the SIMD kernels' bits (the same [`fold`] rule, FMAs by `f32::mul_add`).

use super::tiles::{fmac_f32 as fma, fold, mulc_f32 as mul, Tile, MAX_POINTS, MAX_R};
use super::{Group, PackedWinograd, Rows, Scratch};
use crate::ops::Activation;

/// One group of tiles of variant `T` into `out` (the tile row's output rows, in its layout).
pub(super) fn group<T: Tile>(
    packed: &PackedWinograd,
    input: &[f32],
    g: Group,
    activation: Activation,
    scratch: &mut Scratch,
    out: Rows<'_>,
) {
    let geom = packed.geometry();
    let (h, w, c_in, c_out) = (geom.h(), geom.w(), geom.c_in(), geom.c_out());
    let (v, m, _) = scratch.parts();
    // Input transform, per tile and channel.
    for t in 0..g.n {
        let tx = g.tx0 + t;
        for c in 0..c_in {
            let d = |r: usize, j: usize| {
                let (iy, ix) = ((T::M * g.ty + r).wrapping_sub(1), (T::M * tx + j).wrapping_sub(1));
                if iy < h && ix < w {
                    input[(iy * w + ix) * c_in + c]
                } else {
                    0.0
                }
            };
            let tile = input_transform::<T>(d);
            for (xi, val) in tile.iter().take(T::P).enumerate() {
                v[(xi * g.n + t) * c_in + c] = *val;
            }
        }
    }
    // Dot products over channels (FMA chains from zero).
    let u = packed.transformed();
    for xi in 0..T::P {
        for t in 0..g.n {
            for o in 0..c_out {
                let mut acc = 0.0f32;
                for c in 0..c_in {
                    acc = v[(xi * g.n + t) * c_in + c].mul_add(u[(xi * c_in + c) * c_out + o], acc);
                }
                m[(xi * g.n + t) * c_out + o] = acc;
            }
        }
    }
    // Output transform, bias, activation, skip value.
    let bias = packed.bias();
    for t in 0..g.n {
        let tx = g.tx0 + t;
        for o in 0..c_out {
            let y = output_transform::<T>(|a, b| m[((T::R * a + b) * g.n + t) * c_out + o]);
            for (r, yr) in y.iter().enumerate().take(T::M) {
                for (j, yrj) in yr.iter().enumerate().take(T::M) {
                    let (oy, ox) = (T::M * g.ty + r, T::M * tx + j);
                    if oy < h && ox < w {
                        let at = out.layout.offset(w, c_out, r, ox, o);
                        let val = relu_like_maxps(activation, yrj + bias[o]);
                        out.rows[at] = out.skip.map_or(val, |s| val + s[at]);
                    }
                }
            }
        }
    }
}

/// `Bᵀ d B` of one window `d(r, j)`, row-major over `ξ = R i + j`, rows first.
fn input_transform<T: Tile>(d: impl Fn(usize, usize) -> f32) -> [f32; MAX_POINTS] {
    let mut e = [[0.0f32; MAX_R]; MAX_R];
    for (r, er) in e.iter_mut().enumerate().take(T::R) {
        for (i, v) in er.iter_mut().enumerate().take(T::R) {
            *v = fold(&T::BT[i], T::R, |k| d(r, k), mul, fma, 0.0);
        }
    }
    let mut v = [0.0f32; MAX_POINTS];
    for i in 0..T::R {
        for j in 0..T::R {
            v[T::R * i + j] = fold(&T::BT[i], T::R, |r| e[r][j], mul, fma, 0.0);
        }
    }
    v
}

/// `Aᵀ M A` of one tile's dot products `m(a, b)`, rows first.
fn output_transform<T: Tile>(m: impl Fn(usize, usize) -> f32) -> [[f32; MAX_R]; MAX_R] {
    let mut s = [[0.0f32; MAX_R]; MAX_R];
    for (a, sa) in s.iter_mut().enumerate().take(T::R) {
        for (j, v) in sa.iter_mut().enumerate().take(T::M) {
            *v = fold(&T::AT[j], T::R, |b| m(a, b), mul, fma, 0.0);
        }
    }
    let mut y = [[0.0f32; MAX_R]; MAX_R];
    for (i, yi) in y.iter_mut().enumerate().take(T::M) {
        for (j, v) in yi.iter_mut().enumerate().take(T::M) {
            *v = fold(&T::AT[i], T::R, |a| s[a][j], mul, fma, 0.0);
        }
    }
    y
}

/// The activation as AVX's `max(v, +0)` computes it: `v` if `v > 0`, else `+0` (so also for `-0`
/// and NaN), which the SIMD kernels' bits follow.
fn relu_like_maxps(activation: Activation, v: f32) -> f32 {
    match activation {
        Activation::Relu if v > 0.0 => v,
        Activation::Relu => 0.0,
        Activation::None => v,
    }
}
