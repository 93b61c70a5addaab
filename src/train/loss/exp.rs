//! The loss's exponential (SPEC.md §13.1, "The exponential"): `exp(x)` for the shifted softmax's
//! arguments `x = E_min − E_l <= 0`, written in plain IEEE operations (no fused multiply-add, no
//! table, no libm), so it gives the same bits on every platform and vectorises: the softmax of
//! 256 bins was one libm call per bin, the largest single cost of the per-pixel terms.
//!
//! `k = round(x log₂e)` (by adding and subtracting `1.5·2⁵²`), `r = (x − k ln2_hi) − k ln2_lo`
//! (`|r| <= ln2/2`, Cody-Waite with fdlibm's split of ln 2), `e^r` by its Taylor polynomial to
//! degree 13 in Horner form (truncation below 5e-18 relative), times `2^k` built from its bits.
//! Within 2 ulp of the correctly rounded `e^x` on `[-708, 0]`; exactly 0 below −708 (where
//! `e^x < 3.4e-308`), NaN for NaN.

/// `round(x log₂e)` lands in the low bits of `x log₂e + SHIFT`.
const SHIFT: f64 = 6_755_399_441_055_744.0;
const LOG2E: f64 = std::f64::consts::LOG2_E;
/// fdlibm's `ln2_hi` (its low 32 bits are zero, so `k ln2_hi` is exact for `|k| < 2²⁰`).
const LN2_HI: f64 = 6.931_471_803_691_238e-1;
const LN2_LO: f64 = 1.908_214_929_270_587_7e-10;
/// Below this the result is flushed to 0 (above it `2^k` is a normal number).
pub const FLUSH_BELOW: f64 = -708.0;

/// `1/n!` for `n = 13, 12, ..., 0` (Horner order).
const INV_FACT: [f64; 14] = {
    let mut c = [0.0f64; 14];
    let mut n = 0;
    let mut f = 1.0f64;
    while n < 14 {
        if n > 0 {
            f *= n as f64;
        }
        c[13 - n] = 1.0 / f;
        n += 1;
    }
    c
};

/// `e^x` for `x <= 0` (module docs); for `x > 0` the result is unspecified (not used).
#[inline(always)]
pub fn exp_nonpositive(x: f64) -> f64 {
    let t = x * LOG2E + SHIFT;
    let k = t - SHIFT;
    let r = (x - k * LN2_HI) - k * LN2_LO;
    let mut p = INV_FACT[0];
    for &c in &INV_FACT[1..] {
        p = p * r + c;
    }
    // The low 12 bits of t's bits plus 1023 are k + 1023 (k in [-1022, 0] where it is used).
    let scale = f64::from_bits(t.to_bits().wrapping_add(1023) << 52);
    let y = p * scale;
    if x >= FLUSH_BELOW {
        y
    } else if x.is_nan() {
        x
    } else {
        0.0
    }
}

/// `out[l] = exp_nonpositive(shift − values[l])`, elementwise (compiled for AVX-512 or AVX2 where
/// `level` and the CPU have it; the same bits either way).
pub fn exp_shifted(values: &[f64], shift: f64, out: &mut [f64], level: crate::runtime::CpuFeatureLevel) {
    #[cfg(target_arch = "x86_64")]
    if level.avx512f() {
        // SAFETY: the CPU has AVX-512F.
        unsafe { exp_shifted_avx512(values, shift, out) };
        return;
    }
    #[cfg(target_arch = "x86_64")]
    if level.avx2_fma() {
        // SAFETY: the CPU has AVX2 and FMA.
        unsafe { exp_shifted_avx2(values, shift, out) };
        return;
    }
    exp_shifted_body(values, shift, out);
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn exp_shifted_avx2(values: &[f64], shift: f64, out: &mut [f64]) {
    exp_shifted_body(values, shift, out);
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
unsafe fn exp_shifted_avx512(values: &[f64], shift: f64, out: &mut [f64]) {
    exp_shifted_body(values, shift, out);
}

#[inline(always)]
fn exp_shifted_body(values: &[f64], shift: f64, out: &mut [f64]) {
    for (o, &v) in out.iter_mut().zip(values) {
        *o = exp_nonpositive(shift - v);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn matches_std_exp_within_two_ulp() {
        let mut worst = 0u64;
        let mut x = 0.0f64;
        // 2e6 points over [-708, 0], including every k boundary region.
        for i in 0..2_000_000u64 {
            x = -(i as f64) * (708.0 / 2_000_000.0) - (i % 7) as f64 * 1e-9;
            if x < FLUSH_BELOW {
                continue;
            }
            let (a, b) = (exp_nonpositive(x), x.exp());
            let d = (a.to_bits() as i64 - b.to_bits() as i64).unsigned_abs();
            worst = worst.max(d);
        }
        assert!(worst <= 2, "worst ulp distance {worst} (last x {x})");
        assert_eq!(exp_nonpositive(0.0), 1.0);
        assert_eq!(exp_nonpositive(-0.0), 1.0);
        assert_eq!(exp_nonpositive(-708.5), 0.0);
        assert_eq!(exp_nonpositive(f64::NEG_INFINITY), 0.0);
        assert!(exp_nonpositive(f64::NAN).is_nan());
    }

    #[test]
    fn dispatched_and_portable_give_the_same_bits() {
        let values: Vec<f64> = (0..1000).map(|i| (i as f64 * 0.731).sin() * 300.0 + 300.0).collect();
        let shift = values.iter().copied().fold(f64::INFINITY, f64::min);
        let mut a = vec![0.0; values.len()];
        let mut b = vec![0.0; values.len()];
        exp_shifted_body(&values, shift, &mut b);
        for level in crate::runtime::CpuFeatureLevel::ALL {
            exp_shifted(&values, shift, &mut a, level);
            assert!(a.iter().zip(&b).all(|(x, y)| x.to_bits() == y.to_bits()), "{level:?}");
        }
        assert!(a
            .iter()
            .zip(&values)
            .all(|(&e, &v)| (e - (shift - v).exp()).abs() <= 4e-16 * (shift - v).exp()));
    }
}
