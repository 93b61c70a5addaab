//! Undistortion of raw images into the pinhole camera with the same intrinsics.
//!
//! For every output pixel `u` of the ideal pinhole camera: `x = K⁻¹ u`, `x_d = distort(x)`,
//! `u_d = K x_d`, and the output takes the raw image at `u_d` (bilinear for colour, nearest for
//! depth so that no depth is invented across an edge). Outputs whose `u_d` falls outside the raw
//! image are 0 (black, invalid depth).

use ndarray::{Array2, Array3};
use rayon::prelude::*;

use super::sample::{sample_bilinear, sample_nearest};
use super::{DepthMap, RgbImage};
use crate::geometry::{PinholeCamera, RadTan};

/// A precomputed map from ideal-pinhole pixels to raw (distorted) pixel positions.
#[derive(Clone, Debug)]
pub struct UndistortMap {
    width: usize,
    height: usize,
    /// Raw position for each output pixel, row-major.
    source: Vec<(f64, f64)>,
}

impl UndistortMap {
    /// Build the map for a camera with intrinsics `k` whose raw images are distorted by `d`.
    pub fn new(k: &PinholeCamera, d: &RadTan) -> Self {
        let source = (0..k.height * k.width)
            .map(|i| {
                let (u, v) = ((i % k.width) as f64, (i / k.width) as f64);
                let ray = k.ray(u, v);
                let (xd, yd) = d.distort(ray.x, ray.y);
                (k.fx * xd + k.cx, k.fy * yd + k.cy)
            })
            .collect();
        Self { width: k.width, height: k.height, source }
    }

    /// Undistort an RGB image (bilinear). The image must be `height x width`.
    ///
    /// # Panics
    /// If the image size differs from the map's (callers check sizes when reading).
    pub fn rgb(&self, raw: &RgbImage) -> RgbImage {
        assert_eq!((raw.dim().0, raw.dim().1), (self.height, self.width), "image size must match the camera");
        let view = raw.view();
        let mut out = Array3::<f32>::zeros((self.height, self.width, 3));
        let slice = out.as_slice_mut().expect("freshly allocated arrays are contiguous");
        slice.par_chunks_mut(self.width * 3).enumerate().for_each(|(y, row)| {
            for x in 0..self.width {
                let (sx, sy) = self.source[y * self.width + x];
                sample_bilinear(&view, sx, sy, &mut row[x * 3..x * 3 + 3]);
            }
        });
        out
    }

    /// Undistort a depth map (nearest neighbour).
    ///
    /// # Panics
    /// If the map size differs from the camera's.
    pub fn depth(&self, raw: &DepthMap) -> DepthMap {
        assert_eq!(raw.dim(), (self.height, self.width), "depth size must match the camera");
        let view = raw.view();
        Array2::from_shape_fn((self.height, self.width), |(y, x)| {
            let (sx, sy) = self.source[y * self.width + x];
            sample_nearest(&view, sx, sy).unwrap_or(0.0)
        })
    }
}
