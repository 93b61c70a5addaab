//! TSDF integration (SPEC.md §16.2).
//!
//! For grid point `X` and a depth map with pose `T_wc`, camera `K`, truncation `μ`:
//! `X_c = R_cw X + t_cw` (`T_cw = T_wc⁻¹`), pixel `p = round(π(X_c))` (nearest, §2.1; `z_c > 0`,
//! inside the image), measured depth `d = D[p]` (valid: `> 0` and finite), weight `w = W_obs[p]`
//! (the confidence, or 1; `w > 0`), `η = d - z_c`. If `η >= -μ` the voxel is updated with
//! `t = min(1, η / μ)`:
//!
//! `T ← (W T + w t) / (W + w)`, `C ← (W C + w c) / (W + w)`, `W ← W + w`,
//!
//! computed in f64 from the stored f32 values and rounded once to f32. Observations are integrated
//! in call order; every voxel is updated by exactly one task (rayon over z slabs), so the result is
//! bit-identical for any number of threads.

use nalgebra::{Matrix3, Vector3};
use ndarray::{ArrayView2, ArrayView3};
use rayon::prelude::*;

use super::grid::VoxelGrid;
use crate::error::{Error, Result};
use crate::geometry::{PinholeCamera, Pose};
use crate::image::is_valid_depth;

/// One depth map to integrate.
#[derive(Clone, Copy, Debug)]
pub struct DepthObservation<'a> {
    /// Depth, metres, `[H, W]`; `0` (or non-finite) = no measurement.
    pub depth: ArrayView2<'a, f32>,
    /// Per-pixel weight (the mapper's confidence), `[H, W]`; `None` = 1 everywhere.
    pub weight: Option<ArrayView2<'a, f32>>,
    /// Colour `[H, W, 3]`, 0-255; `None` = grey 128.
    pub colour: Option<ArrayView3<'a, f32>>,
    /// The depth map's camera.
    pub camera: PinholeCamera,
    /// Camera-to-world pose `T_wc`.
    pub pose: Pose,
}

impl DepthObservation<'_> {
    /// Check that the maps have the camera's size.
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] naming the mismatch.
    pub fn validate(&self) -> Result<()> {
        let want = (self.camera.height, self.camera.width);
        let bad = |what: &str, got: (usize, usize)| {
            Error::invalid_argument("depth observation", format!("{what} is {got:?}, camera is {want:?}"))
        };
        if self.depth.dim() != want {
            return Err(bad("depth", self.depth.dim()));
        }
        if let Some(w) = &self.weight {
            if w.dim() != want {
                return Err(bad("weight", w.dim()));
            }
        }
        if let Some(c) = &self.colour {
            if (c.dim().0, c.dim().1) != want || c.dim().2 != 3 {
                return Err(bad("colour", (c.dim().0, c.dim().1)));
            }
        }
        Ok(())
    }

    /// `R_cw`, `t_cw` of the world-to-camera transform.
    pub(crate) fn world_to_camera(&self) -> (Matrix3<f64>, Vector3<f64>) {
        let inv = self.pose.inverse();
        (*inv.rotation.to_rotation_matrix().matrix(), inv.translation.vector)
    }
}

/// What one observation says about one voxel, if anything: `(t, w, colour)` (SPEC.md §16.2).
/// Shared by [`Tsdf::integrate`] and the reference so that the pixel each voxel reads (a gather)
/// is the same bit for bit.
#[inline]
pub(crate) fn observe(
    obs: &DepthObservation,
    r: &Matrix3<f64>,
    t: &Vector3<f64>,
    truncation: f64,
    p: Vector3<f64>,
) -> Option<(f64, f64, [f64; 3])> {
    let xc = r * p + t;
    let uv = obs.camera.project(&xc)?;
    let (h, w) = obs.depth.dim();
    let (u, v) = (uv.x.round(), uv.y.round());
    if !(u >= 0.0 && v >= 0.0 && u <= (w - 1) as f64 && v <= (h - 1) as f64) {
        return None;
    }
    let (u, v) = (u as usize, v as usize);
    let d = obs.depth[[v, u]];
    if !is_valid_depth(d) {
        return None;
    }
    let weight = obs.weight.map_or(1.0, |m| m[[v, u]] as f64);
    if !(weight > 0.0 && weight.is_finite()) {
        return None;
    }
    let eta = d as f64 - xc.z;
    if eta < -truncation {
        return None;
    }
    let colour = match &obs.colour {
        Some(c) => [c[[v, u, 0]] as f64, c[[v, u, 1]] as f64, c[[v, u, 2]] as f64],
        None => [128.0; 3],
    };
    Some(((eta / truncation).min(1.0), weight, colour))
}

/// A TSDF volume: normalised signed distance `T ∈ [-1, 1]` (positive in front of the surface,
/// toward the cameras), accumulated weight `W` (0 = never observed) and mean colour per grid point.
#[derive(Clone, Debug)]
pub struct Tsdf {
    /// The grid.
    pub grid: VoxelGrid,
    /// Truncation distance `μ`, metres.
    pub truncation: f64,
    /// `T` per grid point (0 where unobserved).
    pub tsdf: Vec<f32>,
    /// `W` per grid point.
    pub weight: Vec<f32>,
    /// Mean colour per grid point, 0-255.
    pub colour: Vec<[f32; 3]>,
}

impl Tsdf {
    /// An empty volume (every weight 0).
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] (`--truncation`) unless `truncation > 0`.
    pub fn new(grid: VoxelGrid, truncation: f64) -> Result<Self> {
        if !(truncation.is_finite() && truncation > 0.0) {
            return Err(Error::invalid_argument("--truncation", format!("{truncation}: must be > 0")));
        }
        let n = grid.len();
        Ok(Self { grid, truncation, tsdf: vec![0.0; n], weight: vec![0.0; n], colour: vec![[0.0; 3]; n] })
    }

    /// Integrate one depth map (SPEC.md §16.2), in parallel over z slabs.
    ///
    /// # Errors
    /// [`DepthObservation::validate`].
    pub fn integrate(&mut self, obs: &DepthObservation) -> Result<()> {
        obs.validate()?;
        let (r, t) = obs.world_to_camera();
        let g = self.grid;
        let slab = g.dims[0] * g.dims[1];
        let mu = self.truncation;
        self.tsdf
            .par_chunks_mut(slab)
            .zip(self.weight.par_chunks_mut(slab))
            .zip(self.colour.par_chunks_mut(slab))
            .enumerate()
            .for_each(|(k, ((ts, ws), cs))| {
                for j in 0..g.dims[1] {
                    for i in 0..g.dims[0] {
                        let Some((tv, w, c)) = observe(obs, &r, &t, mu, g.point(i, j, k)) else {
                            continue;
                        };
                        let n = j * g.dims[0] + i;
                        let w0 = ws[n] as f64;
                        let w1 = w0 + w;
                        ts[n] = ((w0 * ts[n] as f64 + w * tv) / w1) as f32;
                        for a in 0..3 {
                            cs[n][a] = ((w0 * cs[n][a] as f64 + w * c[a]) / w1) as f32;
                        }
                        ws[n] = w1 as f32;
                    }
                }
            });
        Ok(())
    }

    /// Number of observed grid points (`W > 0`).
    pub fn observed(&self) -> usize {
        self.weight.iter().filter(|&&w| w > 0.0).count()
    }
}
