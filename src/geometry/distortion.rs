//! Radial-tangential ("plumb bob", OpenCV / TUM) lens distortion on normalised image coordinates.
//!
//! With `r² = x² + y²`:
//! `x_d = x (1 + k1 r² + k2 r⁴ + k3 r⁶) + 2 p1 x y + p2 (r² + 2 x²)`,
//! `y_d = y (1 + k1 r² + k2 r⁴ + k3 r⁶) + p1 (r² + 2 y²) + 2 p2 x y`.
//! Undistortion inverts this with Newton's method (SPEC.md §2.7 states the tolerance).

use nalgebra::{Matrix2, Vector2};

/// Radial-tangential distortion coefficients `(k1, k2, p1, p2, k3)`.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct RadTan {
    /// Radial r² coefficient.
    pub k1: f64,
    /// Radial r⁴ coefficient.
    pub k2: f64,
    /// Tangential coefficient 1.
    pub p1: f64,
    /// Tangential coefficient 2.
    pub p2: f64,
    /// Radial r⁶ coefficient.
    pub k3: f64,
}

/// Newton iterations allowed when undistorting.
const UNDISTORT_MAX_ITERS: usize = 30;
/// Convergence threshold on the residual `|distort(x) - x_d|` in normalised units.
const UNDISTORT_TOL: f64 = 1e-14;

impl RadTan {
    /// Whether every coefficient is zero.
    pub fn is_identity(&self) -> bool {
        self.k1 == 0.0 && self.k2 == 0.0 && self.p1 == 0.0 && self.p2 == 0.0 && self.k3 == 0.0
    }

    /// Distort normalised coordinates `(x, y)`.
    #[inline]
    pub fn distort(&self, x: f64, y: f64) -> (f64, f64) {
        let r2 = x * x + y * y;
        let radial = 1.0 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3));
        let xd = x * radial + 2.0 * self.p1 * x * y + self.p2 * (r2 + 2.0 * x * x);
        let yd = y * radial + self.p1 * (r2 + 2.0 * y * y) + 2.0 * self.p2 * x * y;
        (xd, yd)
    }

    /// Jacobian of [`RadTan::distort`] at `(x, y)`.
    fn jacobian(&self, x: f64, y: f64) -> Matrix2<f64> {
        let r2 = x * x + y * y;
        let radial = 1.0 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3));
        // d radial / d r2
        let dradial = self.k1 + r2 * (2.0 * self.k2 + 3.0 * r2 * self.k3);
        let dxdx = radial + x * dradial * 2.0 * x + 2.0 * self.p1 * y + self.p2 * 6.0 * x;
        let dxdy = x * dradial * 2.0 * y + 2.0 * self.p1 * x + self.p2 * 2.0 * y;
        let dydx = y * dradial * 2.0 * x + self.p1 * 2.0 * x + 2.0 * self.p2 * y;
        let dydy = radial + y * dradial * 2.0 * y + self.p1 * 6.0 * y + 2.0 * self.p2 * x;
        Matrix2::new(dxdx, dxdy, dydx, dydy)
    }

    /// Invert [`RadTan::distort`]: the `(x, y)` whose distortion is `(xd, yd)`, by Newton's method
    /// started at `(xd, yd)`. `None` if it does not converge (far outside the calibrated field).
    pub fn undistort(&self, xd: f64, yd: f64) -> Option<(f64, f64)> {
        let target = Vector2::new(xd, yd);
        let mut p = target;
        for _ in 0..UNDISTORT_MAX_ITERS {
            let (dx, dy) = self.distort(p.x, p.y);
            let residual = Vector2::new(dx, dy) - target;
            if residual.norm() <= UNDISTORT_TOL * (1.0 + target.norm()) {
                return Some((p.x, p.y));
            }
            let step = self.jacobian(p.x, p.y).lu().solve(&residual)?;
            p -= step;
            if !p.x.is_finite() || !p.y.is_finite() {
                return None;
            }
        }
        let (dx, dy) = self.distort(p.x, p.y);
        ((Vector2::new(dx, dy) - target).norm() <= 1e-10).then_some((p.x, p.y))
    }
}
