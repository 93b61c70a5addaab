//! Pinhole intrinsics and a camera (intrinsics + optional lens distortion).

use nalgebra::{Matrix3, Point2, Vector3};

use super::distortion::RadTan;
use crate::error::{Error, Result};

/// Pinhole intrinsics for an image of `width x height` pixels.
///
/// A pixel `(u, v)` has its centre at integer coordinates: `u = 0` is the centre of the first column
/// (SPEC.md §2.1). `fy` may be negative (ICL-NUIM stores `fy = -480`): the maths never assumes a sign.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PinholeCamera {
    /// Focal length along x, pixels.
    pub fx: f64,
    /// Focal length along y, pixels (may be negative).
    pub fy: f64,
    /// Principal point x, pixels.
    pub cx: f64,
    /// Principal point y, pixels.
    pub cy: f64,
    /// Image width, pixels.
    pub width: usize,
    /// Image height, pixels.
    pub height: usize,
}

impl PinholeCamera {
    /// Validated constructor: every value finite, `fx > 0`, `fy` non-zero (negative for an upward y
    /// axis, ICL-NUIM), size non-zero.
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] naming the first bad value.
    pub fn new(fx: f64, fy: f64, cx: f64, cy: f64, width: usize, height: usize) -> Result<Self> {
        for (name, v) in [("fx", fx), ("fy", fy), ("cx", cx), ("cy", cy)] {
            if !v.is_finite() {
                return Err(Error::invalid_argument(name, format!("intrinsic is {v}, must be finite")));
            }
        }
        if fx == 0.0 || fy == 0.0 {
            return Err(Error::invalid_argument(
                "focal length",
                format!("fx = {fx}, fy = {fy}: must be non-zero"),
            ));
        }
        if fx < 0.0 {
            return Err(Error::invalid_argument(
                "focal length",
                format!("fx = {fx}: must be positive (only fy may be negative, for an upward y axis: SPEC.md §2.6)"),
            ));
        }
        if width == 0 || height == 0 {
            return Err(Error::invalid_argument(
                "image size",
                format!("{width}x{height}: must be non-empty"),
            ));
        }
        Ok(Self { fx, fy, cx, cy, width, height })
    }

    /// The 3x3 intrinsics matrix `K`.
    pub fn k(&self) -> Matrix3<f64> {
        Matrix3::new(self.fx, 0.0, self.cx, 0.0, self.fy, self.cy, 0.0, 0.0, 1.0)
    }

    /// `K⁻¹ (u, v, 1)ᵀ`: the ray through pixel `(u, v)` with unit z.
    #[inline]
    pub fn ray(&self, u: f64, v: f64) -> Vector3<f64> {
        Vector3::new((u - self.cx) / self.fx, (v - self.cy) / self.fy, 1.0)
    }

    /// Projection `π(p) = (fx x/z + cx, fy y/z + cy)`; `None` unless `z > 0`.
    #[inline]
    pub fn project(&self, p: &Vector3<f64>) -> Option<Point2<f64>> {
        if p.z > 0.0 && p.z.is_finite() {
            Some(Point2::new(self.fx * p.x / p.z + self.cx, self.fy * p.y / p.z + self.cy))
        } else {
            None
        }
    }

    /// Back-projection `π⁻¹(u, ρ) = K⁻¹ u̇ / ρ` for `ρ > 0` (a point at depth `z = 1/ρ`).
    /// For `ρ = 0` use the homogeneous form of [`super::Warp`].
    #[inline]
    pub fn backproject(&self, u: f64, v: f64, rho: f64) -> Vector3<f64> {
        self.ray(u, v) / rho
    }

    /// Whether `(u, v)` lies inside the image under the integer-centre convention,
    /// i.e. `0 <= u <= width - 1` and `0 <= v <= height - 1` (where bilinear sampling is defined).
    #[inline]
    pub fn contains(&self, u: f64, v: f64) -> bool {
        u >= 0.0 && v >= 0.0 && u <= (self.width - 1) as f64 && v <= (self.height - 1) as f64
    }

    /// Intrinsics of pyramid level `level`, the grid of a stride-`2^level` feature map
    /// (SPEC.md §2.6): `f_l = f / 2^l`, `c_l = c / 2^l`, size `ceil(size / 2^l)`.
    ///
    /// With pixel centres at integers, a stride-2 3x3 convolution with padding 1 centres output
    /// pixel `j` on input pixel `2j`, so level-`l` pixel `j` sits at level-0 coordinate `2^l j`:
    /// a pure scaling of the image plane, no half-pixel offset.
    pub fn at_level(&self, level: u32) -> Self {
        let s = 0.5f64.powi(level as i32);
        let div = 1usize << level;
        Self {
            fx: self.fx * s,
            fy: self.fy * s,
            cx: self.cx * s,
            cy: self.cy * s,
            width: self.width.div_ceil(div),
            height: self.height.div_ceil(div),
        }
    }
}

/// A camera: pinhole intrinsics plus optional radial-tangential distortion of the raw images.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Camera {
    /// Intrinsics.
    pub pinhole: PinholeCamera,
    /// Lens distortion of the raw images (`None`: images are already pinhole).
    pub distortion: Option<RadTan>,
}

impl Camera {
    /// A distortion-free camera.
    pub fn pinhole(pinhole: PinholeCamera) -> Self {
        Self { pinhole, distortion: None }
    }
}
