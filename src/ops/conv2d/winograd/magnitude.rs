//! The magnitude that bounds the Winograd kernels' error, and the budget (SPEC.md §7.11).

use ndarray::{Array3, ArrayView1, ArrayView3, ArrayView4};

use super::tiles::{depth, Tile, F2, F4, MAX_R};
use super::{check_geometry, WinogradTile};
use crate::error::Result;
use crate::ops::expect_shape;
use crate::ops::geometry::Conv2dGeometry;

/// `M_W`: the algorithm of `tile` with every transform entry, weight, bias and input replaced by its
/// absolute value, in f64, plain loops:
/// `M_W[y, x, o] = |b_o| + Σ_c Σ_ξ (|Aᵀ|⊗|Aᵀ|)[(y, x), ξ] (|G| |g_oc| |Gᵀ|)[ξ] (|Bᵀ| |d_c| |B|)[ξ]`.
/// It is at least §7.5's `M = Σ |x| |w| + |b|` (each product of the convolution appears in it with
/// a coefficient of at least one).
///
/// # Errors
/// [`crate::Error::InvalidArgument`] if a shape disagrees with `geom` or the stride is not 1.
pub fn winograd_magnitude_reference(
    tile: WinogradTile,
    geom: &Conv2dGeometry,
    input: ArrayView3<f64>,
    weight: ArrayView4<f64>,
    bias: ArrayView1<f64>,
) -> Result<Array3<f64>> {
    check_geometry(geom)?;
    expect_shape("conv2d input", input.shape(), &geom.input_shape())?;
    expect_shape("conv2d weight", weight.shape(), &geom.weight_shape())?;
    expect_shape("conv2d bias", bias.shape(), &[geom.c_out()])?;
    Ok(match tile {
        WinogradTile::F2x2 => magnitude::<F2>(geom, input, weight, bias),
        WinogradTile::F4x4 => magnitude::<F4>(geom, input, weight, bias),
    })
}

fn magnitude<T: Tile>(
    geom: &Conv2dGeometry,
    input: ArrayView3<f64>,
    weight: ArrayView4<f64>,
    bias: ArrayView1<f64>,
) -> Array3<f64> {
    let (h, w, c_in, c_out) = (geom.h(), geom.w(), geom.c_in(), geom.c_out());
    let (r_n, m_n) = (T::R, T::M);
    let abs_g = |i: usize, k: usize| T::G[i][k].abs();
    let abs_bt = |i: usize, k: usize| f64::from(T::BT[i][k].abs());
    let abs_at = |i: usize, k: usize| f64::from(T::AT[i][k].abs());
    let mut out = Array3::<f64>::zeros(geom.output_shape());
    for ty in 0..h.div_ceil(m_n) {
        for tx in 0..w.div_ceil(m_n) {
            for o in 0..c_out {
                let mut m = [[0.0f64; MAX_R]; MAX_R];
                for c in 0..c_in {
                    let d = |r: usize, j: usize| {
                        let (iy, ix) = ((m_n * ty + r).wrapping_sub(1), (m_n * tx + j).wrapping_sub(1));
                        if iy < h && ix < w {
                            input[[iy, ix, c]].abs()
                        } else {
                            0.0
                        }
                    };
                    for (i, mi) in m.iter_mut().enumerate().take(r_n) {
                        for (j, mij) in mi.iter_mut().enumerate().take(r_n) {
                            let mut vv = 0.0;
                            let mut uu = 0.0;
                            for a in 0..r_n {
                                for b in 0..r_n {
                                    vv += abs_bt(i, a) * d(a, b) * abs_bt(j, b);
                                }
                            }
                            for ky in 0..3 {
                                for kx in 0..3 {
                                    uu += abs_g(i, ky) * weight[[o, c, ky, kx]].abs() * abs_g(j, kx);
                                }
                            }
                            *mij += uu * vv;
                        }
                    }
                }
                for r in 0..m_n {
                    for j in 0..m_n {
                        let (oy, ox) = (m_n * ty + r, m_n * tx + j);
                        if oy < h && ox < w {
                            let mut y = bias[o].abs();
                            for (a, ma) in m.iter().enumerate().take(r_n) {
                                for (b, mab) in ma.iter().enumerate().take(r_n) {
                                    y += abs_at(r, a) * mab * abs_at(j, b);
                                }
                            }
                            out[[oy, ox, o]] = y;
                        }
                    }
                }
            }
        }
    }
    out
}

/// Relative budget of the Winograd kernels against [`winograd_magnitude_reference`] (SPEC.md
/// §7.11): `|fast - ref| <= 2 (n + 2) ε_f32 · M_W`, `n = 2 d_B + 1 + c_in + 2 d_A + 1` the most
/// roundings on a path through the algorithm (`d_B`, `d_A` those of one transform row, `tiles::depth`):
/// `c_in + 10` for F(2x2, 3x3), `c_in + 18` for F(4x4, 3x3).
pub fn winograd_budget(tile: WinogradTile, c_in: usize) -> f32 {
    let (d_b, d_a) = match tile {
        WinogradTile::F2x2 => (depth(&F2::BT, F2::R, F2::R), depth(&F2::AT, F2::M, F2::R)),
        WinogradTile::F4x4 => (depth(&F4::BT, F4::R, F4::R), depth(&F4::AT, F4::M, F4::R)),
    };
    let n = 2 * d_b + 1 + c_in + 2 * d_a + 1;
    2.0 * (n + 2) as f32 * f32::EPSILON
}
