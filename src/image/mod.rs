//! Images in memory and on disk.
//!
//! Layouts (SPEC.md §2.2): an RGB image is an `ndarray` `[H, W, 3]` of `f32` in `0..=255`
//! (row-major, channel fastest, "HWC"); a depth map is `[H, W]` `f32` metres with `0` meaning
//! "no measurement". Feature maps use the same channels-last layout `[H, W, C]`.

mod depth_exr;
mod io;
pub(crate) mod sample;
mod undistort;

pub use depth_exr::{load_depth_exr, read_exr_dimensions, DEPTH_CHANNELS};
pub use io::{load_depth_png, load_rgb, read_dimensions, save_depth_png_mm, save_rgb_png};
pub use sample::{sample_bilinear, sample_nearest};
pub use undistort::UndistortMap;

use ndarray::{Array2, Array3};

/// RGB image, `[H, W, 3]`, values `0..=255`.
pub type RgbImage = Array3<f32>;

/// Depth map, `[H, W]`, metres along the optical axis; `0` (or any non-finite value) is invalid.
pub type DepthMap = Array2<f32>;

/// Whether a depth value counts as a measurement: finite and strictly positive (SPEC.md §2.8).
#[inline]
pub fn is_valid_depth(z: f32) -> bool {
    z.is_finite() && z > 0.0
}

/// Mean of the three channels: a grey image `[H, W]` in `0..=255`.
pub fn to_gray(rgb: &RgbImage) -> Array2<f32> {
    let (h, w, _) = rgb.dim();
    Array2::from_shape_fn((h, w), |(y, x)| (rgb[[y, x, 0]] + rgb[[y, x, 1]] + rgb[[y, x, 2]]) / 3.0)
}
