//! Scene primitives and their analytic ray intersections, in `f64`.
//!
//! A ray is `p(t) = o + t d`. The renderer uses `d = R K⁻¹ (u, v, 1)ᵀ`, whose camera-frame z is 1,
//! so the `t` of a hit *is* the depth along the optical axis (no division by `|d|`).
//!
//! - [`Quad`]: a rectangle `origin + s·axis_u + r·axis_v`, `s ∈ [0, size_u]`, `r ∈ [0, size_v]`;
//!   `t = n·(origin - o) / n·d` (ray-plane).
//! - [`Cuboid`]: an oriented box, intersected with the slab method in its own frame.
//!
//! Both are two-sided for intersection; the hit normal is returned facing the ray, so shading is
//! the same from wherever a surface is seen.

use nalgebra::{Matrix3, Vector3};

use super::texture::Texture;

/// Hits closer than this (metres along a unit-z ray) are ignored.
pub const T_MIN: f64 = 1e-6;

/// Denominators `|n·d|` below this count as a ray parallel to a plane.
const PARALLEL_EPS: f64 = 1e-12;

/// Texture-coordinate offset between faces of a cuboid, metres, so that faces sharing one texture
/// do not show the same pattern.
const FACE_UV_OFFSET: f64 = 7.31;

/// A ray-surface intersection.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hit {
    /// Ray parameter (the depth, for unit-z camera rays).
    pub t: f64,
    /// Unit normal at the hit, facing the ray origin.
    pub normal: Vector3<f64>,
    /// Texture coordinates, metres.
    pub uv: [f64; 2],
}

/// A planar rectangle.
#[derive(Clone, Debug, PartialEq)]
pub struct Quad {
    /// One corner.
    pub origin: Vector3<f64>,
    /// Unit vector along the first side.
    pub axis_u: Vector3<f64>,
    /// Unit vector along the second side, orthogonal to `axis_u`.
    pub axis_v: Vector3<f64>,
    /// `axis_u × axis_v`.
    pub normal: Vector3<f64>,
    /// Side lengths along `axis_u` and `axis_v`, metres.
    pub size: [f64; 2],
}

impl Quad {
    /// The rectangle with a corner at `origin` spanned by `size[0]·axis_u` and `size[1]·axis_v`.
    /// The axes are used as given: callers pass orthonormal vectors.
    pub fn new(origin: Vector3<f64>, axis_u: Vector3<f64>, axis_v: Vector3<f64>, size: [f64; 2]) -> Self {
        Self { origin, axis_u, axis_v, normal: axis_u.cross(&axis_v), size }
    }

    /// Nearest hit with `T_MIN < t < t_max`.
    #[inline]
    pub fn intersect(&self, o: &Vector3<f64>, d: &Vector3<f64>, t_max: f64) -> Option<Hit> {
        let denom = self.normal.dot(d);
        if denom.abs() < PARALLEL_EPS {
            return None;
        }
        let t = self.normal.dot(&(self.origin - o)) / denom;
        if !(t > T_MIN && t < t_max) {
            return None;
        }
        let rel = o + d * t - self.origin;
        let (s, r) = (self.axis_u.dot(&rel), self.axis_v.dot(&rel));
        if !(s >= 0.0 && s <= self.size[0] && r >= 0.0 && r <= self.size[1]) {
            return None;
        }
        let normal = if denom < 0.0 { self.normal } else { -self.normal };
        Some(Hit { t, normal, uv: [s, r] })
    }
}

/// An oriented box.
#[derive(Clone, Debug, PartialEq)]
pub struct Cuboid {
    /// Centre, world frame.
    pub centre: Vector3<f64>,
    /// Rotation whose columns are the box's axes in the world frame.
    pub axes: Matrix3<f64>,
    /// Half side lengths along the box's axes, metres.
    pub half: Vector3<f64>,
}

impl Cuboid {
    /// Nearest entry hit with `T_MIN < t < t_max`; `None` from inside the box.
    #[inline]
    pub fn intersect(&self, o: &Vector3<f64>, d: &Vector3<f64>, t_max: f64) -> Option<Hit> {
        // Early out: a ray that misses the box's circumscribed sphere (radius padded by a relative
        // 1e-6, far above the rounding of this test) misses the box. Hits are computed below
        // exactly as without the test.
        let oc = self.centre - o;
        let r2 = self.half.norm_squared() * (1.0 + 2e-6);
        let b = oc.dot(d);
        if b * b - d.norm_squared() * (oc.norm_squared() - r2) < 0.0 {
            return None;
        }
        let p = self.axes.tr_mul(&(o - self.centre));
        let q = self.axes.tr_mul(d);
        let (mut t_near, mut t_far, mut axis) = (f64::NEG_INFINITY, f64::INFINITY, 0usize);
        for k in 0..3 {
            if q[k].abs() < PARALLEL_EPS {
                if p[k].abs() > self.half[k] {
                    return None;
                }
                continue;
            }
            let (a, b) = ((-self.half[k] - p[k]) / q[k], (self.half[k] - p[k]) / q[k]);
            let (lo, hi) = if a < b { (a, b) } else { (b, a) };
            if lo > t_near {
                t_near = lo;
                axis = k;
            }
            t_far = t_far.min(hi);
        }
        if !(t_near <= t_far && t_near > T_MIN && t_near < t_max) {
            return None;
        }
        // The entry face is perpendicular to `axis`, on the side the ray comes from.
        let sign = if q[axis] > 0.0 { -1.0 } else { 1.0 };
        let local = p + q * t_near;
        let (i, j) = ((axis + 1) % 3, (axis + 2) % 3);
        let face = (2 * axis) as f64 + if sign > 0.0 { 1.0 } else { 0.0 };
        let uv = [local[i] + self.half[i] + face * FACE_UV_OFFSET, local[j] + self.half[j]];
        let normal = self.axes.column(axis) * sign;
        Some(Hit { t: t_near, normal, uv })
    }
}

/// A primitive's geometry.
#[derive(Clone, Debug, PartialEq)]
pub enum Shape {
    /// A rectangle.
    Quad(Quad),
    /// An oriented box.
    Cuboid(Cuboid),
}

/// A textured primitive.
#[derive(Clone, Debug, PartialEq)]
pub struct Surface {
    /// Geometry.
    pub shape: Shape,
    /// Albedo.
    pub texture: Texture,
}

impl Surface {
    /// Nearest hit with `T_MIN < t < t_max`.
    #[inline]
    pub fn intersect(&self, o: &Vector3<f64>, d: &Vector3<f64>, t_max: f64) -> Option<Hit> {
        match &self.shape {
            Shape::Quad(q) => q.intersect(o, d, t_max),
            Shape::Cuboid(c) => c.intersect(o, d, t_max),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cuboid_entry_face_and_depth_are_analytic() {
        let c = Cuboid {
            centre: Vector3::new(0.0, 0.0, 3.0),
            axes: Matrix3::identity(),
            half: Vector3::repeat(0.5),
        };
        let hit = c.intersect(&Vector3::zeros(), &Vector3::new(0.1, -0.05, 1.0), f64::INFINITY);
        let hit = hit.map(|h| (h.t, h.normal));
        assert_eq!(hit, Some((2.5, Vector3::new(0.0, 0.0, -1.0))));
        // A ray passing beside the box misses it; a ray from inside does not report a hit.
        assert!(c.intersect(&Vector3::zeros(), &Vector3::new(0.3, 0.0, 1.0), f64::INFINITY).is_none());
        assert!(c.intersect(&Vector3::new(0.0, 0.0, 3.0), &Vector3::z(), f64::INFINITY).is_none());
    }

    #[test]
    fn quad_hit_respects_bounds_and_faces_the_ray() {
        let q = Quad::new(Vector3::new(-1.0, -1.0, 2.0), Vector3::x(), Vector3::y(), [2.0, 2.0]);
        let h = q.intersect(&Vector3::zeros(), &Vector3::new(0.25, 0.0, 1.0), f64::INFINITY);
        assert_eq!(h.map(|h| (h.t, h.uv, h.normal)), Some((2.0, [1.5, 1.0], Vector3::new(0.0, 0.0, -1.0))));
        assert!(q.intersect(&Vector3::zeros(), &Vector3::new(0.6, 0.0, 1.0), f64::INFINITY).is_none());
        assert!(q.intersect(&Vector3::zeros(), &Vector3::new(0.0, 0.0, 1.0), 1.5).is_none());
    }
}
