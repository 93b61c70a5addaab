//! Lattice value noise and its fractal sum, evaluated analytically at any `(u, v)` in metres.
//!
//! A lattice value is [`hash_unit`] of the integer corner (so the noise is a pure function of its
//! inputs), corners are blended with the quintic fade `6t⁵ - 15t⁴ + 10t³` (C² continuous).

use crate::util::rng::hash_unit;

/// Octave-to-octave frequency factor of [`fbm`].
const LACUNARITY: f64 = 2.0;
/// Octave-to-octave amplitude factor of [`fbm`].
const PERSISTENCE: f64 = 0.5;

/// Quintic fade.
#[inline]
fn fade(t: f64) -> f64 {
    t * t * t * (t * (t * 6.0 - 15.0) + 10.0)
}

/// Hermite smoothstep of `x` between `e0` and `e1` (0 below, 1 above).
#[inline]
pub fn smoothstep(e0: f64, e1: f64, x: f64) -> f64 {
    let t = ((x - e0) / (e1 - e0)).clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

/// Value noise in `[0, 1)` with unit lattice spacing.
#[inline]
pub fn value_noise(key: u64, x: f64, y: f64) -> f64 {
    let (fx, fy) = (x.floor(), y.floor());
    let (i, j) = (fx as i64, fy as i64);
    let (tx, ty) = (fade(x - fx), fade(y - fy));
    let c = |di: i64, dj: i64| hash_unit(key, (i + di) as u64, (j + dj) as u64, 0);
    let top = c(0, 0) + (c(1, 0) - c(0, 0)) * tx;
    let bottom = c(0, 1) + (c(1, 1) - c(0, 1)) * tx;
    top + (bottom - top) * ty
}

/// Fractal sum of `octaves` value-noise octaves, normalised to `[0, 1)`. `x`, `y` are in units of
/// the coarsest octave's lattice spacing.
pub fn fbm(key: u64, x: f64, y: f64, octaves: u32) -> f64 {
    let (mut sum, mut norm, mut amp, mut freq) = (0.0, 0.0, 1.0, 1.0);
    for o in 0..octaves {
        // A per-octave offset keeps lattice points of different octaves from lining up.
        let shift = 17.31 * o as f64;
        sum += amp * value_noise(key.wrapping_add(o as u64), x * freq + shift, y * freq - shift);
        norm += amp;
        amp *= PERSISTENCE;
        freq *= LACUNARITY;
    }
    if norm > 0.0 {
        sum / norm
    } else {
        0.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn value_noise_interpolates_lattice_values_continuously() {
        let key = 11;
        for (x, y) in [(0.0, 0.0), (3.0, -2.0), (-5.0, 7.0)] {
            assert_eq!(value_noise(key, x, y), hash_unit(key, x as i64 as u64, y as i64 as u64, 0));
            let eps = 1e-9;
            assert!((value_noise(key, x - eps, y) - value_noise(key, x, y)).abs() < 1e-6);
        }
        for i in 0..100 {
            let v = fbm(key, i as f64 * 0.37, i as f64 * -0.11, 4);
            assert!((0.0..1.0).contains(&v));
        }
    }
}
