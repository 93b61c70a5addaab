//! The TSDF oracle (SPEC.md §16.2): for every grid point, every observation in order, the update
//! of [`super::tsdf`] in f64 storage, one thread, no slabs. Keep it naive.

use super::grid::VoxelGrid;
use super::tsdf::{observe, DepthObservation};
use crate::error::Result;

/// An f64 TSDF volume, laid out as [`super::Tsdf`].
#[derive(Clone, Debug)]
pub struct ReferenceTsdf {
    /// `T` per grid point.
    pub tsdf: Vec<f64>,
    /// `W` per grid point.
    pub weight: Vec<f64>,
    /// Mean colour per grid point.
    pub colour: Vec<[f64; 3]>,
}

/// Fuse `observations` in order into a fresh f64 volume on `grid`.
///
/// # Errors
/// [`DepthObservation::validate`].
pub fn integrate_reference(
    grid: &VoxelGrid,
    truncation: f64,
    observations: &[DepthObservation],
) -> Result<ReferenceTsdf> {
    let n = grid.len();
    let mut v = ReferenceTsdf { tsdf: vec![0.0; n], weight: vec![0.0; n], colour: vec![[0.0; 3]; n] };
    for obs in observations {
        obs.validate()?;
    }
    let transforms: Vec<_> = observations.iter().map(|o| o.world_to_camera()).collect();
    for k in 0..grid.dims[2] {
        for j in 0..grid.dims[1] {
            for i in 0..grid.dims[0] {
                let idx = grid.index(i, j, k);
                for (obs, (r, t)) in observations.iter().zip(&transforms) {
                    if let Some((tv, w, c)) = observe(obs, r, t, truncation, grid.point(i, j, k)) {
                        let w0 = v.weight[idx];
                        let w1 = w0 + w;
                        v.tsdf[idx] = (w0 * v.tsdf[idx] + w * tv) / w1;
                        for (vc, c) in v.colour[idx].iter_mut().zip(c) {
                            *vc = (w0 * *vc + w * c) / w1;
                        }
                        v.weight[idx] = w1;
                    }
                }
            }
        }
    }
    Ok(v)
}
