//! The simulated camera response: per-frame exposure (gain) and bias drift, vignetting and sensor
//! noise, then 8-bit quantisation.
//!
//! `I = q(g_i · V(x, y) · L + b_i + σ n)` where `L` is the rendered radiance in grey levels, `g_i`
//! and `b_i` the frame's gain and bias, `V = 1 - s (1 - cos⁴θ)` the vignetting with
//! `cos⁴θ = 1 / (1 + r²)²` and `r² = ((x-cx)/fx)² + ((y-cy)/fy)²`, `n` approximately standard normal
//! noise from a counter-based hash of (key, frame, pixel, channel), and `q` rounding and clamping to
//! `0..=255`. Quantising makes the in-memory frame identical to what is written to disk.

use super::detmath::sin;
use crate::util::rng::{hash64, SplitMix64};

/// The strength of each photometric effect.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PhotometricConfig {
    /// Amplitude of the relative gain drift (`g_i ∈ [1 - a, 1 + a]`).
    pub gain_amplitude: f64,
    /// Amplitude of the bias drift, grey levels.
    pub bias_amplitude: f64,
    /// Vignetting strength `s ∈ [0, 1]`: the fraction of the `cos⁴` fall-off applied.
    pub vignetting: f64,
    /// Standard deviation of the sensor noise, grey levels.
    pub noise_sigma: f64,
}

impl Default for PhotometricConfig {
    fn default() -> Self {
        Self { gain_amplitude: 0.12, bias_amplitude: 5.0, vignetting: 0.35, noise_sigma: 1.0 }
    }
}

impl PhotometricConfig {
    /// No photometric variation: unit gain, zero bias, no vignetting, no noise (frames then differ
    /// only by viewpoint and 8-bit rounding).
    pub fn none() -> Self {
        Self { gain_amplitude: 0.0, bias_amplitude: 0.0, vignetting: 0.0, noise_sigma: 0.0 }
    }
}

/// Periods (frames) of the two gain sinusoids and of the bias sinusoid.
const GAIN_PERIODS: [f64; 2] = [97.0, 23.0];
const BIAS_PERIOD: f64 = 61.0;
/// Share of the gain amplitude carried by the slow sinusoid (the fast one gets the rest).
const SLOW_GAIN_SHARE: f64 = 0.75;

/// `sqrt(3)`: scales the Irwin-Hall sum of four uniforms (variance 1/3) to unit variance.
const IRWIN_HALL_4_SCALE: f64 = 1.732_050_807_568_877_2;

/// The photometric model of one sequence: the config plus seeded phases.
#[derive(Clone, Debug, PartialEq)]
pub struct Photometric {
    /// Effect strengths.
    pub config: PhotometricConfig,
    phases: [f64; 3],
    key: u64,
}

/// One frame's exposure.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Exposure {
    /// Multiplicative gain.
    pub gain: f64,
    /// Additive bias, grey levels.
    pub bias: f64,
}

impl Photometric {
    /// Draw the drift phases and noise key from `rng`.
    pub fn new(config: PhotometricConfig, rng: &mut SplitMix64) -> Self {
        let tau = std::f64::consts::TAU;
        let phases = [rng.range(0.0, tau), rng.range(0.0, tau), rng.range(0.0, tau)];
        Self { config, phases, key: rng.next_u64() }
    }

    /// Frame `i`'s gain and bias.
    pub fn exposure(&self, i: usize) -> Exposure {
        let (c, tau, t) = (&self.config, std::f64::consts::TAU, i as f64);
        let slow = sin(tau * t / GAIN_PERIODS[0] + self.phases[0]);
        let fast = sin(tau * t / GAIN_PERIODS[1] + self.phases[1]);
        let gain = 1.0 + c.gain_amplitude * (SLOW_GAIN_SHARE * slow + (1.0 - SLOW_GAIN_SHARE) * fast);
        let bias = c.bias_amplitude * sin(tau * t / BIAS_PERIOD + self.phases[2]);
        Exposure { gain, bias }
    }

    /// Vignetting factor at normalised image coordinates `(nx, ny) = ((x-cx)/fx, (y-cy)/fy)`.
    #[inline]
    pub fn vignetting(&self, nx: f64, ny: f64) -> f64 {
        let c = 1.0 + nx * nx + ny * ny;
        1.0 - self.config.vignetting * (1.0 - 1.0 / (c * c))
    }

    /// Approximately standard normal noise for (frame, pixel, channel): the Irwin-Hall sum of four
    /// 16-bit uniforms taken from one hash, centred and scaled to unit variance.
    #[inline]
    pub fn noise(&self, frame: usize, pixel: usize, channel: usize) -> f64 {
        let h = hash64(self.key, frame as u64, pixel as u64, channel as u64);
        let mut s = 0.0;
        for k in 0..4 {
            s += (((h >> (16 * k)) & 0xFFFF) as f64 + 0.5) / 65_536.0;
        }
        (s - 2.0) * IRWIN_HALL_4_SCALE
    }

    /// The recorded 8-bit value (as `f32`) of radiance `l` (grey levels) at a pixel whose vignetting
    /// factor is `vig`.
    #[inline]
    pub fn record(&self, l: f64, exposure: &Exposure, vig: f64, noise: f64) -> f32 {
        let v = exposure.gain * vig * l + exposure.bias + self.config.noise_sigma * noise;
        v.round().clamp(0.0, 255.0) as f32
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn noise_has_unit_variance_and_none_is_identity() {
        let p = Photometric::new(PhotometricConfig::default(), &mut SplitMix64::new(1));
        let n = 20_000;
        let (mut s, mut s2) = (0.0, 0.0);
        for i in 0..n {
            let x = p.noise(3, i, 1);
            s += x;
            s2 += x * x;
        }
        let (mean, var) = (s / n as f64, s2 / n as f64 - (s / n as f64).powi(2));
        assert!(mean.abs() < 0.03 && (var - 1.0).abs() < 0.05, "mean {mean}, var {var}");

        let none = Photometric::new(PhotometricConfig::none(), &mut SplitMix64::new(1));
        let e = none.exposure(17);
        assert_eq!((e.gain, e.bias), (1.0, 0.0));
        assert_eq!(none.vignetting(0.7, -0.4), 1.0);
        assert_eq!(none.record(123.4, &e, 1.0, 2.0), 123.0);
    }
}
