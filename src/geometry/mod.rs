//! Camera geometry: pinhole intrinsics and their pyramid scaling, radial-tangential distortion, SE(3)
//! poses, and the inverse-depth warp of the paper, `u' = π(T_nr π⁻¹(u, ρ))`.
//!
//! Conventions (SPEC.md §2): pixel centres at integer coordinates, poses stored camera-to-world
//! (`T_wc`), inverse depth `ρ = 1/z` along the optical axis, metres.

mod camera;
mod distortion;
mod invdepth;
mod pose;
mod warp;

pub use camera::{Camera, PinholeCamera};
pub use distortion::RadTan;
pub use invdepth::InverseDepthBins;
pub use pose::{
    pose_from_matrix, pose_from_opengl, pose_from_tum, pose_to_matrix, relative_pose, slerp_pose, Pose,
    QUATERNION_NORM_TOLERANCE, ROTATION_TOLERANCE,
};
pub use warp::{warp_pixel, Warp, WarpedPixel};
