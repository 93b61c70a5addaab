//! Inverse-depth hypotheses: `K` bins uniformly spaced from `ρ_min` to `ρ_max` inclusive.

use crate::error::{Error, Result};

/// `K >= 2` inverse-depth hypotheses `ρ_k = ρ_min + k (ρ_max - ρ_min) / (K - 1)`, `k = 0..K-1`.
///
/// `ρ = 0` (a point at infinity) is a valid hypothesis: the warp is written in homogeneous form and
/// is exact there. The paper trains with `K = 256` over `[0, 4]` 1/m.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct InverseDepthBins {
    /// Smallest inverse depth (1/m), `>= 0`.
    pub rho_min: f64,
    /// Largest inverse depth (1/m), `> rho_min`.
    pub rho_max: f64,
    /// Number of hypotheses, `>= 2`.
    pub count: usize,
}

impl InverseDepthBins {
    /// Validated constructor.
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] if `count < 2`, a bound is negative or not finite, or
    /// `rho_min >= rho_max`.
    pub fn new(rho_min: f64, rho_max: f64, count: usize) -> Result<Self> {
        if count < 2 {
            return Err(Error::invalid_argument("bins", format!("{count} bins: need at least 2")));
        }
        if !(rho_min.is_finite() && rho_max.is_finite()) || rho_min < 0.0 {
            return Err(Error::invalid_argument(
                "inverse-depth range",
                format!("[{rho_min}, {rho_max}] 1/m: bounds must be finite and >= 0"),
            ));
        }
        if rho_min >= rho_max {
            return Err(Error::invalid_argument(
                "inverse-depth range",
                format!("rho_min = {rho_min} >= rho_max = {rho_max}"),
            ));
        }
        Ok(Self { rho_min, rho_max, count })
    }

    /// Bins from a depth range in metres: `ρ_max = 1/near`, `ρ_min = 1/far` (`far = ∞` gives 0).
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] unless `0 < near < far`.
    pub fn from_depth_range(near: f64, far: f64, count: usize) -> Result<Self> {
        if !(near > 0.0 && near.is_finite()) || far.is_nan() || near >= far {
            return Err(Error::invalid_argument(
                "depth range",
                format!("near = {near} m, far = {far} m: need 0 < near < far"),
            ));
        }
        Self::new(1.0 / far, 1.0 / near, count)
    }

    /// The paper's training bins: 256 over `[0, 4]` 1/m.
    pub fn paper() -> Self {
        Self { rho_min: 0.0, rho_max: 4.0, count: 256 }
    }

    /// Spacing between consecutive hypotheses.
    pub fn step(&self) -> f64 {
        (self.rho_max - self.rho_min) / (self.count - 1) as f64
    }

    /// Inverse depth of bin `k` (`k < count`); the last bin is exactly `rho_max`.
    pub fn rho(&self, k: usize) -> f64 {
        if k + 1 == self.count {
            self.rho_max
        } else {
            self.rho_min + k as f64 * self.step()
        }
    }

    /// The continuous bin coordinate of `rho`: `(rho - rho_min) / step` (not clamped).
    pub fn bin_of(&self, rho: f64) -> f64 {
        (rho - self.rho_min) / self.step()
    }

    /// All hypotheses, ascending.
    pub fn values(&self) -> Vec<f64> {
        (0..self.count).map(|k| self.rho(k)).collect()
    }
}
