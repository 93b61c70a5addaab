//! The paper's warp `u' = π(T_nr π⁻¹(u, ρ))`, in the homogeneous form that is exact at `ρ = 0`.
//!
//! `π⁻¹(u, ρ) = K_r⁻¹ u̇ / ρ`; multiplying the homogeneous point `(K_r⁻¹ u̇ / ρ, 1)` by `ρ` gives
//! `(K_r⁻¹ u̇, ρ)`, the same projective point, finite for every `ρ >= 0`. Then
//! `p = R K_r⁻¹ u̇ + ρ t` and `u' = (fx p_x/p_z + cx, fy p_y/p_z + cy)`; the warped point lies in
//! front of camera `n` iff `p_z > 0`, and its inverse depth in camera `n` is `ρ' = ρ / p_z`.

use nalgebra::{Matrix3, Point2, Vector3};

use super::camera::PinholeCamera;
use super::pose::Pose;

/// A warped pixel: position in the target image and inverse depth in the target camera.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct WarpedPixel {
    /// Pixel position in the target camera (not necessarily inside the image).
    pub uv: Point2<f64>,
    /// Inverse depth of the point in the target camera.
    pub rho: f64,
}

/// The warp from a reference camera into a target camera, with `R`, `t` and `K` premultiplied.
#[derive(Clone, Copy, Debug)]
pub struct Warp {
    /// `R_nr K_r⁻¹`.
    rk: Matrix3<f64>,
    /// `t_nr`.
    t: Vector3<f64>,
    target: PinholeCamera,
    reference: PinholeCamera,
}

impl Warp {
    /// The warp for `T_nr` (reference camera to target camera).
    pub fn new(reference: &PinholeCamera, target: &PinholeCamera, t_nr: &Pose) -> Self {
        let r = t_nr.rotation.to_rotation_matrix().into_inner();
        let k_inv = Matrix3::new(
            1.0 / reference.fx,
            0.0,
            -reference.cx / reference.fx,
            0.0,
            1.0 / reference.fy,
            -reference.cy / reference.fy,
            0.0,
            0.0,
            1.0,
        );
        Self { rk: r * k_inv, t: t_nr.translation.vector, target: *target, reference: *reference }
    }

    /// The reference camera.
    pub fn reference(&self) -> &PinholeCamera {
        &self.reference
    }

    /// The target camera.
    pub fn target(&self) -> &PinholeCamera {
        &self.target
    }

    /// `R_nr K_r⁻¹`, so that `p = R K⁻¹ u̇ + ρ t` can be hoisted per pixel.
    pub fn rotation_k_inv(&self) -> &Matrix3<f64> {
        &self.rk
    }

    /// `t_nr`.
    pub fn translation(&self) -> &Vector3<f64> {
        &self.t
    }

    /// `p = R K⁻¹ u̇ + ρ t`, the target-camera point scaled by `ρ`.
    #[inline]
    pub fn point(&self, u: f64, v: f64, rho: f64) -> Vector3<f64> {
        self.rk * Vector3::new(u, v, 1.0) + self.t * rho
    }

    /// The cost volume's warp (SPEC.md §9.1): [`Warp::point`] projected with one division,
    /// `x' = (f_x p_x) · (1/p_z) + c_x`, `y' = (f_y p_y) · (1/p_z) + c_y`; `None` unless `p_z > 0`
    /// and finite. [`Warp::apply`] divides twice (`f_x p_x / p_z`); the two differ by an ulp.
    #[inline]
    pub fn apply_volume(&self, u: f64, v: f64, rho: f64) -> Option<Point2<f64>> {
        let p = self.point(u, v, rho);
        if !(p.z > 0.0 && p.z.is_finite()) {
            return None;
        }
        let inv = 1.0 / p.z;
        let cam = &self.target;
        Some(Point2::new(cam.fx * p.x * inv + cam.cx, cam.fy * p.y * inv + cam.cy))
    }

    /// Warp pixel `(u, v)` at inverse depth `rho >= 0`; `None` if the point is not in front of the
    /// target camera (`p_z <= 0`).
    #[inline]
    pub fn apply(&self, u: f64, v: f64, rho: f64) -> Option<WarpedPixel> {
        let p = self.point(u, v, rho);
        let uv = self.target.project(&p)?;
        Some(WarpedPixel { uv, rho: rho / p.z })
    }
}

/// One-off warp of a single pixel (builds a [`Warp`]; hoist it for many pixels).
pub fn warp_pixel(
    reference: &PinholeCamera,
    target: &PinholeCamera,
    t_nr: &Pose,
    u: f64,
    v: f64,
    rho: f64,
) -> Option<WarpedPixel> {
    Warp::new(reference, target, t_nr).apply(u, v, rho)
}
