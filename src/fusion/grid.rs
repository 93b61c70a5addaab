//! The voxel grid of a TSDF volume (SPEC.md §16.1).
//!
//! Grid point `(i, j, k)` sits at `origin + (i, j, k) · voxel` (world frame, metres). Storage is
//! x fastest: index `(k · ny + j) · nx + i`, so a z slab is one contiguous run of `nx · ny` voxels.

use nalgebra::Vector3;
use serde::Serialize;

use crate::error::{Error, Result};
use crate::geometry::{PinholeCamera, Pose};

/// Bytes per voxel of one volume: f32 TSDF, f32 weight, three f32 colour sums.
pub const BYTES_PER_VOXEL: u64 = 20;

/// An axis-aligned box, metres.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Aabb {
    /// Smallest corner.
    pub min: [f64; 3],
    /// Largest corner.
    pub max: [f64; 3],
}

impl Aabb {
    /// The empty box (min = +inf, max = -inf); [`Aabb::add`] grows it.
    pub fn empty() -> Self {
        Self { min: [f64::INFINITY; 3], max: [f64::NEG_INFINITY; 3] }
    }

    /// Grow to contain `p`.
    pub fn add(&mut self, p: [f64; 3]) {
        for ((lo, hi), v) in self.min.iter_mut().zip(&mut self.max).zip(p) {
            *lo = lo.min(v);
            *hi = hi.max(v);
        }
    }

    /// Whether no point was added.
    pub fn is_empty(&self) -> bool {
        (0..3).any(|a| self.min[a].is_nan() || self.max[a].is_nan() || self.min[a] > self.max[a])
    }

    /// The intersection (possibly empty).
    pub fn intersect(&self, o: &Aabb) -> Aabb {
        let mut r = *self;
        for a in 0..3 {
            r.min[a] = r.min[a].max(o.min[a]);
            r.max[a] = r.max[a].min(o.max[a]);
        }
        r
    }

    /// Grown by `m` on every side.
    pub fn padded(&self, m: f64) -> Aabb {
        let mut r = *self;
        for a in 0..3 {
            r.min[a] -= m;
            r.max[a] += m;
        }
        r
    }

    /// The box around the viewing frusta of `poses` (camera centres and the image corners at
    /// depth `max_depth`): every point a depth map of these cameras can put within `max_depth`.
    pub fn of_frusta(camera: &PinholeCamera, poses: &[Pose], max_depth: f64) -> Aabb {
        let mut b = Aabb::empty();
        let (w, h) = ((camera.width - 1) as f64, (camera.height - 1) as f64);
        for pose in poses {
            let c = pose.translation.vector;
            b.add([c.x, c.y, c.z]);
            for (u, v) in [(0.0, 0.0), (w, 0.0), (0.0, h), (w, h)] {
                let p = pose * nalgebra::Point3::from(camera.ray(u, v) * max_depth);
                b.add([p.x, p.y, p.z]);
            }
        }
        b
    }
}

/// A regular grid of voxels.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct VoxelGrid {
    /// World position of grid point `(0, 0, 0)`, metres.
    pub origin: [f64; 3],
    /// Edge length of a voxel, metres.
    pub voxel: f64,
    /// Number of grid points along x, y, z.
    pub dims: [usize; 3],
}

impl VoxelGrid {
    /// The grid of voxel size `voxel` covering `bounds`: origin at `bounds.min`, `ceil(extent /
    /// voxel) + 1` points per axis.
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] (`--voxel-size`) for a non-positive voxel, an empty box or more
    /// than `2^31` voxels.
    pub fn covering(bounds: &Aabb, voxel: f64) -> Result<Self> {
        if !(voxel.is_finite() && voxel > 0.0) {
            return Err(Error::invalid_argument("--voxel-size", format!("{voxel}: must be > 0")));
        }
        if bounds.is_empty() || bounds.min.iter().chain(&bounds.max).any(|v| !v.is_finite()) {
            return Err(Error::invalid_argument("fusion bounds", "no depth to fuse: the volume is empty"));
        }
        let mut dims = [0usize; 3];
        for (a, d) in dims.iter_mut().enumerate() {
            let n = ((bounds.max[a] - bounds.min[a]) / voxel).ceil() + 1.0;
            if n > (1u64 << 31) as f64 {
                return Err(Error::invalid_argument("--voxel-size", format!("{voxel} m: too many voxels")));
            }
            *d = (n as usize).max(2);
        }
        let g = Self { origin: bounds.min, voxel, dims };
        if g.len() as u64 > 1u64 << 31 {
            return Err(Error::invalid_argument("--voxel-size", format!("{voxel} m: too many voxels")));
        }
        Ok(g)
    }

    /// Number of voxels (saturating).
    pub fn len(&self) -> usize {
        self.dims[0].saturating_mul(self.dims[1]).saturating_mul(self.dims[2])
    }

    /// Whether the grid has no voxel.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Bytes of one volume on this grid ([`BYTES_PER_VOXEL`] per voxel).
    pub fn bytes(&self) -> u64 {
        (self.len() as u64).saturating_mul(BYTES_PER_VOXEL)
    }

    /// Index of grid point `(i, j, k)`.
    #[inline]
    pub fn index(&self, i: usize, j: usize, k: usize) -> usize {
        (k * self.dims[1] + j) * self.dims[0] + i
    }

    /// World position of grid point `(i, j, k)`.
    #[inline]
    pub fn point(&self, i: usize, j: usize, k: usize) -> Vector3<f64> {
        Vector3::new(
            self.origin[0] + i as f64 * self.voxel,
            self.origin[1] + j as f64 * self.voxel,
            self.origin[2] + k as f64 * self.voxel,
        )
    }
}

/// Voxels of a grid of voxel size `voxel` over `bounds`, without building it (saturating; an empty
/// box has none).
pub fn voxel_count(bounds: &Aabb, voxel: f64) -> u64 {
    if bounds.is_empty() || voxel.is_nan() || voxel <= 0.0 {
        return 0;
    }
    (0..3).fold(1u64, |acc, a| {
        let n = ((bounds.max[a] - bounds.min[a]) / voxel).ceil() + 1.0;
        acc.saturating_mul(if n.is_finite() && n < 1e18 { n as u64 } else { u64::MAX })
    })
}
