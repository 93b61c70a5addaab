//! TSDF fusion of keyframe depth maps and the mesh of its zero level set (SPEC.md §16).
//!
//! - [`consistency`]: the depth filter before fusion: multi-view geometric consistency and
//!   depth discontinuities (SPEC.md §16.10).
//! - [`grid`]: the voxel grid (origin, voxel size, dimensions), its bounds from camera frusta and
//!   depth points, and the memory estimate.
//! - [`tsdf`]: integration of a depth map into a truncated signed distance volume: per voxel,
//!   projective distance `d(π(X_c)) - z`, truncated to `[-μ, μ]` (voxels further than `μ` behind
//!   the surface are left alone), weighted running average. Parallel over z slabs, so every voxel
//!   is owned by one task: bit-identical for any thread count.
//! - [`reference`](mod@reference): the same maths as naive f64 loops, the oracle [`tsdf`] is tested against.
//! - [`mesh`]: masked surface nets (one vertex per active cell, one quad per active edge) with
//!   vertex colours, boundary-edge count.
//! - [`ply`]: binary PLY with faces, writer and parser.
//! - [`metrics`]: accuracy, completeness, precision, recall and F-score between two meshes.
//! - [`render`]: a z-buffer rasteriser for PNG pictures of a mesh.

pub mod components;
pub mod consistency;
pub mod grid;
pub mod mesh;
pub mod metrics;
pub mod ply;
pub mod reference;
pub mod render;
pub mod tsdf;
pub mod weights;

pub use components::{remove_small_components, ComponentReport};
pub use grid::{Aabb, VoxelGrid, BYTES_PER_VOXEL};
pub use mesh::{extract_mesh, Mesh};
pub use metrics::{mesh_metrics, MeshMetrics, ThresholdScores, STANDARD_THRESHOLDS};
pub use tsdf::{DepthObservation, Tsdf};
pub use weights::{fusion_weights, FusionWeight};
