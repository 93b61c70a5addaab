//! The two Winograd variants' transform matrices (Lavin and Gray, 2016) and the one rule every
//! kernel evaluates a transform row with ([`fold`], SPEC.md §7.11).
//!
//! F(2x2, 3x3): 2x2 output tile, 4x4 window, 16 points. F(4x4, 3x3): 4x4 output tile, 6x6 window,
//! 36 points. Matrices are padded to the largest size with zeros; only the first `R` (window)
//! columns and `R` / `M` rows are used.

/// Largest window (F(4x4, 3x3)).
pub(crate) const MAX_R: usize = 6;
/// Largest output tile.
pub(crate) const MAX_M: usize = 4;
/// Largest number of points per tile.
pub(crate) const MAX_POINTS: usize = MAX_R * MAX_R;

/// One variant's sizes and matrices, as compile-time constants for the kernels.
pub(crate) trait Tile {
    /// Output tile side.
    const M: usize;
    /// Window side, `M + 2`.
    const R: usize;
    /// Points per tile, `R²`.
    const P: usize;
    /// `Bᵀ` (`R x R`): `V = Bᵀ d B`.
    const BT: [[f32; MAX_R]; MAX_R];
    /// `Aᵀ` (`M x R`): `Y = Aᵀ M A`.
    const AT: [[f32; MAX_R]; MAX_M];
    /// `G` (`R x 3`): `U = G g Gᵀ`, in f64.
    const G: [[f64; 3]; MAX_R];
}

/// F(2x2, 3x3).
pub(crate) struct F2;

/// F(4x4, 3x3).
pub(crate) struct F4;

impl Tile for F2 {
    const M: usize = 2;
    const R: usize = 4;
    const P: usize = 16;
    const BT: [[f32; MAX_R]; MAX_R] = [
        [1.0, 0.0, -1.0, 0.0, 0.0, 0.0],
        [0.0, 1.0, 1.0, 0.0, 0.0, 0.0],
        [0.0, -1.0, 1.0, 0.0, 0.0, 0.0],
        [0.0, 1.0, 0.0, -1.0, 0.0, 0.0],
        [0.0; MAX_R],
        [0.0; MAX_R],
    ];
    const AT: [[f32; MAX_R]; MAX_M] =
        [[1.0, 1.0, 1.0, 0.0, 0.0, 0.0], [0.0, 1.0, -1.0, -1.0, 0.0, 0.0], [0.0; MAX_R], [0.0; MAX_R]];
    const G: [[f64; 3]; MAX_R] =
        [[1.0, 0.0, 0.0], [0.5, 0.5, 0.5], [0.5, -0.5, 0.5], [0.0, 0.0, 1.0], [0.0; 3], [0.0; 3]];
}

impl Tile for F4 {
    const M: usize = 4;
    const R: usize = 6;
    const P: usize = 36;
    const BT: [[f32; MAX_R]; MAX_R] = [
        [4.0, 0.0, -5.0, 0.0, 1.0, 0.0],
        [0.0, -4.0, -4.0, 1.0, 1.0, 0.0],
        [0.0, 4.0, -4.0, -1.0, 1.0, 0.0],
        [0.0, -2.0, -1.0, 2.0, 1.0, 0.0],
        [0.0, 2.0, -1.0, -2.0, 1.0, 0.0],
        [0.0, 4.0, 0.0, -5.0, 0.0, 1.0],
    ];
    const AT: [[f32; MAX_R]; MAX_M] = [
        [1.0, 1.0, 1.0, 1.0, 1.0, 0.0],
        [0.0, 1.0, -1.0, 2.0, -2.0, 0.0],
        [0.0, 1.0, 1.0, 4.0, 4.0, 0.0],
        [0.0, 1.0, -1.0, 8.0, -8.0, 1.0],
    ];
    const G: [[f64; 3]; MAX_R] = [
        [1.0 / 4.0, 0.0, 0.0],
        [-1.0 / 6.0, -1.0 / 6.0, -1.0 / 6.0],
        [-1.0 / 6.0, 1.0 / 6.0, -1.0 / 6.0],
        [1.0 / 24.0, 1.0 / 12.0, 1.0 / 6.0],
        [1.0 / 24.0, -1.0 / 12.0, 1.0 / 6.0],
        [0.0, 0.0, 1.0],
    ];
}

/// One transform row applied to `x`, SPEC.md §7.11's rule: over the row's nonzero coefficients
/// `c_k` in index order, the first gives `c_k · x_k` (rounded), each next one
/// `fma(c_k, x_k, acc)`; a row of zeros gives `+0`. Generic over the lane type so that the
/// portable (f32) and SIMD kernels share the rule.
#[inline(always)]
pub(crate) fn fold<V: Copy>(
    row: &[f32; MAX_R],
    n: usize,
    x: impl Fn(usize) -> V,
    mul: impl Fn(f32, V) -> V,
    fma: impl Fn(f32, V, V) -> V,
    zero: V,
) -> V {
    let mut acc: Option<V> = None;
    for (k, &c) in row.iter().enumerate().take(n) {
        if c == 0.0 {
            continue;
        }
        acc = Some(match acc {
            None => mul(c, x(k)),
            Some(a) => fma(c, x(k), a),
        });
    }
    acc.unwrap_or(zero)
}

/// The fold's product on f32: `c · x`, rounded.
pub(crate) fn mulc_f32(c: f32, x: f32) -> f32 {
    c * x
}

/// The fold's fused multiply-add on f32: `fma(c, x, a)`, one rounding.
pub(crate) fn fmac_f32(c: f32, x: f32, a: f32) -> f32 {
    c.mul_add(x, a)
}

/// `G g Gᵀ` of one 3x3 kernel `g(ky, kx)` for variant `T`, row-major over `ξ = R i + j`, in f64
/// (rows of the kernel first: `h[ky][j] = Σ_kx g[ky][kx] G[j][kx]`, then `Σ_ky G[i][ky] h[ky][j]`,
/// terms in index order, folds from `0.0`).
pub(crate) fn transform_weights<T: Tile>(g: impl Fn(usize, usize) -> f64) -> [f64; MAX_POINTS] {
    let mut h = [[0.0f64; MAX_R]; 3];
    for (ky, row) in h.iter_mut().enumerate() {
        for (j, v) in row.iter_mut().enumerate().take(T::R) {
            *v = (0..3).fold(0.0, |s, kx| s + g(ky, kx) * T::G[j][kx]);
        }
    }
    let mut u = [0.0f64; MAX_POINTS];
    for i in 0..T::R {
        for j in 0..T::R {
            u[T::R * i + j] = (0..3).fold(0.0, |s, ky| s + T::G[i][ky] * h[ky][j]);
        }
    }
    u
}

/// The largest number of roundings one [`fold`] of a row of `mat` (its first `rows` rows, `n`
/// columns) performs: one per nonzero coefficient, less one when the first is `±2^k` (that product
/// is exact). SPEC.md §7.11 counts these for the error budget.
pub(crate) fn depth(mat: &[[f32; MAX_R]], rows: usize, n: usize) -> usize {
    let roundings = |r: &[f32; MAX_R]| {
        let nz: Vec<f32> = r.iter().take(n).copied().filter(|c| *c != 0.0).collect();
        let exact_first = nz.first().is_some_and(|c| c.abs().log2().fract() == 0.0);
        nz.len() - usize::from(exact_first)
    };
    mat.iter().take(rows).map(roundings).max().unwrap_or(0)
}

/// The transform rows of both variants written out as [`fold`] evaluates them, for a lane type:
/// `bt_rows::<T>(x)` is `Bᵀ x` and `at_rows::<T>(x)` is `Aᵀ x` for one vector `x` of `R` values.
/// Coefficients `±1` are additions and subtractions (`fma(±1, x, a)` rounds exactly as `a ± x`),
/// the others the `mulc` / `fmac` the caller provides (`c · x` rounded, `fma(c, x, a)`). Each SIMD
/// kernel instantiates it with its own intrinsics and target feature; `fold_rows_equal_the_fold`
/// checks the f32 instance against [`fold`].
macro_rules! winograd_rows {
    ($(#[$attr:meta])* $v:ty, $add:path, $sub:path, $mulc:path, $fmac:path, $zero:expr) => {
        $(#[$attr])*
        fn bt_rows<T: $crate::ops::conv2d::winograd::tiles::Tile>(
            x: &[$v; $crate::ops::conv2d::winograd::tiles::MAX_R],
        ) -> [$v; $crate::ops::conv2d::winograd::tiles::MAX_R] {
            let z = $zero;
            if T::R == 4 {
                [$sub(x[0], x[2]), $add(x[1], x[2]), $sub(x[2], x[1]), $sub(x[1], x[3]), z, z]
            } else {
                [
                    $add($fmac(-5.0, x[2], $mulc(4.0, x[0])), x[4]),
                    $add($add($fmac(-4.0, x[2], $mulc(-4.0, x[1])), x[3]), x[4]),
                    $add($sub($fmac(-4.0, x[2], $mulc(4.0, x[1])), x[3]), x[4]),
                    $add($fmac(2.0, x[3], $sub($mulc(-2.0, x[1]), x[2])), x[4]),
                    $add($fmac(-2.0, x[3], $sub($mulc(2.0, x[1]), x[2])), x[4]),
                    $add($fmac(-5.0, x[3], $mulc(4.0, x[1])), x[5]),
                ]
            }
        }

        $(#[$attr])*
        fn at_rows<T: $crate::ops::conv2d::winograd::tiles::Tile>(
            x: &[$v; $crate::ops::conv2d::winograd::tiles::MAX_R],
        ) -> [$v; $crate::ops::conv2d::winograd::tiles::MAX_M] {
            let z = $zero;
            if T::R == 4 {
                [$add($add(x[0], x[1]), x[2]), $sub($sub(x[1], x[2]), x[3]), z, z]
            } else {
                [
                    $add($add($add($add(x[0], x[1]), x[2]), x[3]), x[4]),
                    $fmac(-2.0, x[4], $fmac(2.0, x[3], $sub(x[1], x[2]))),
                    $fmac(4.0, x[4], $fmac(4.0, x[3], $add(x[1], x[2]))),
                    $add($fmac(-8.0, x[4], $fmac(8.0, x[3], $sub(x[1], x[2]))), x[5]),
                ]
            }
        }
    };
}
pub(crate) use winograd_rows;

#[cfg(test)]
mod tests {
    use super::*;

    use fmac_f32 as fmac;
    use mulc_f32 as mulc;

    fn add(a: f32, b: f32) -> f32 {
        a + b
    }
    fn sub(a: f32, b: f32) -> f32 {
        a - b
    }
    winograd_rows!(f32, add, sub, mulc, fmac, 0.0f32);

    fn check<T: Tile>(x: &[f32; MAX_R]) {
        let b = bt_rows::<T>(x);
        let a = at_rows::<T>(x);
        for (i, bi) in b.iter().enumerate().take(T::R) {
            let want = fold(&T::BT[i], T::R, |k| x[k], mulc, fmac, 0.0);
            assert_eq!(bi.to_bits(), want.to_bits(), "Bᵀ row {i} of {x:?}");
        }
        for (i, ai) in a.iter().enumerate().take(T::M) {
            let want = fold(&T::AT[i], T::R, |k| x[k], mulc, fmac, 0.0);
            assert_eq!(ai.to_bits(), want.to_bits(), "Aᵀ row {i} of {x:?}");
        }
    }

    /// The written-out rows are the [`fold`] of the matrices, bit for bit, on values whose sums
    /// round (ratios of primes), signed zeros, infinities and values near overflow.
    #[test]
    fn fold_rows_equal_the_fold() {
        let mut s = 0x9E37_79B9_7F4A_7C15u64;
        let mut next = || {
            s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            let m = ((s >> 40) as f32 / (1u64 << 24) as f32) - 0.5;
            m * [1.0, 3.0e-3, 7.0e5, 1.0e-30, 3.0e37][(s >> 20) as usize % 5]
        };
        for _ in 0..2000 {
            let x: [f32; MAX_R] = std::array::from_fn(|_| next());
            check::<F2>(&x);
            check::<F4>(&x);
        }
        for special in [0.0, -0.0, f32::INFINITY, f32::MAX, -f32::MAX, f32::MIN_POSITIVE] {
            let x = [special, 1.0, -0.0, special, 2.5, -special];
            check::<F2>(&x);
            check::<F4>(&x);
        }
        // The matrices match the written-out tables in the test above through `check`; the
        // depths counted for the budget are those of SPEC.md §7.11.
        assert_eq!((depth(&F2::BT, 4, 4), depth(&F2::AT, 2, 4)), (1, 2));
        assert_eq!((depth(&F4::BT, 6, 6), depth(&F4::AT, 4, 6)), (3, 4));
    }
}
