//! Per-pixel ray casting, parallel over rows.
//!
//! For pixel `(x, y)` (centre at integer coordinates) of a camera with pose `T_wc = (R, c)`:
//!
//! ```text
//! depth(x, y) = t*   where   c + t* R K⁻¹(x, y, 1)ᵀ is the nearest hit   (camera z of the hit)
//! L(x, y)     = 1/n² Σ_{i,j < n} 255 · EXPOSURE · albedo · shade   at   (x + (i+½)/n - ½, y + (j+½)/n - ½)
//! ```
//! then the camera response ([`Photometric`](super::Photometric)) turns `L` into 8-bit values. Each
//! pixel is computed alone and sums run in a fixed order, so any thread count gives the same bits.

use nalgebra::{Matrix3, Vector3};
use ndarray::{Array2, Array3};
use rayon::prelude::*;

use super::scene::Scene;
use super::sensor::{jpeg_round_trip, Sensor};
use super::surface::{Hit, Shape};
use crate::error::Result;
use crate::geometry::Pose;
use crate::image::{DepthMap, RgbImage};

/// Radiance (grey levels) of a white surface at shade 1, before gain; leaves headroom for gain.
const EXPOSURE: f64 = 0.9 * 255.0;

/// Realistic style: the room's leading surfaces (floor, ceiling, four walls) darken towards their
/// edges, a cheap stand-in for the ambient occlusion of room corners.
const ROOM_QUADS: usize = 6;
/// Darkening at a room edge, and the distance (metres) at which it vanishes.
const CORNER_DARKENING: f64 = 0.3;
const CORNER_REACH: f64 = 0.8;

/// `1 - CORNER_DARKENING · max(0, 1 - d / CORNER_REACH)²`, `d` the distance of `uv` to the quad's
/// edge (basic operations only, no `libm`).
#[inline]
fn corner_darkening(shape: &Shape, uv: &[f64; 2]) -> f64 {
    match shape {
        Shape::Quad(q) => {
            let d = uv[0].min(q.size[0] - uv[0]).min(uv[1]).min(q.size[1] - uv[1]).max(0.0);
            let t = (1.0 - d / CORNER_REACH).max(0.0);
            1.0 - CORNER_DARKENING * t * t
        }
        Shape::Cuboid(_) => 1.0,
    }
}

/// One rendered row: `W·3` colour values and `W` depths.
struct Row {
    rgb: Vec<f32>,
    depth: Vec<f32>,
}

impl Scene {
    /// The nearest hit of ray `o + t d` and the index of the surface hit.
    #[inline]
    fn trace(&self, o: &Vector3<f64>, d: &Vector3<f64>) -> Option<(Hit, usize)> {
        let mut best: Option<(Hit, usize)> = None;
        let mut t_max = f64::INFINITY;
        for (k, s) in self.surfaces.iter().enumerate() {
            if let Some(h) = s.intersect(o, d, t_max) {
                t_max = h.t;
                best = Some((h, k));
            }
        }
        best
    }

    /// Shaded radiance of the ray, grey levels per channel; black if it hits nothing.
    #[inline]
    fn radiance(&self, o: &Vector3<f64>, d: &Vector3<f64>) -> [f64; 3] {
        match self.trace(o, d) {
            Some((hit, k)) => {
                let a = self.surfaces[k].texture.eval(hit.uv[0], hit.uv[1]);
                let mut shade = self.light.shade(&hit.normal);
                if let Some(lamp) = &self.lamp {
                    shade += lamp.shade(&(o + d * hit.t), &hit.normal);
                    if k < ROOM_QUADS {
                        shade *= corner_darkening(&self.surfaces[k].shape, &hit.uv);
                    }
                }
                let s = EXPOSURE * shade;
                [a[0] * s, a[1] * s, a[2] * s]
            }
            None => [0.0; 3],
        }
    }

    fn render_row(&self, rot: &Matrix3<f64>, o: &Vector3<f64>, y: usize, frame: usize) -> Row {
        let k = &self.camera;
        let n = self.samples_per_axis;
        let inv_n2 = 1.0 / (n * n) as f64;
        let offsets: Vec<f64> = (0..n).map(|i| (i as f64 + 0.5) / n as f64 - 0.5).collect();
        let exposure = self.photometric.exposure(frame);
        let w = k.width;
        let mut row = Row { rgb: Vec::with_capacity(3 * w), depth: Vec::with_capacity(w) };
        for x in 0..w {
            let centre = rot * k.ray(x as f64, y as f64);
            let depth = self.trace(o, &centre).map_or(0.0, |(h, _)| h.t as f32);
            let mut sum = [0.0f64; 3];
            for &dy in &offsets {
                for &dx in &offsets {
                    let d = rot * k.ray(x as f64 + dx, y as f64 + dy);
                    let l = self.radiance(o, &d);
                    for c in 0..3 {
                        sum[c] += l[c];
                    }
                }
            }
            let nx = (x as f64 - k.cx) / k.fx;
            let ny = (y as f64 - k.cy) / k.fy;
            let vig = self.photometric.vignetting(nx, ny);
            let pixel = y * w + x;
            for (c, s) in sum.iter().enumerate() {
                let noise = self.photometric.noise(frame, pixel, c);
                row.rgb.push(self.photometric.record(s * inv_n2, &exposure, vig, noise));
            }
            row.depth.push(depth);
        }
        row
    }

    /// A realistic-style row: sub-pixel sample `s` of a pixel is taken at the shutter time
    /// stratum `(s + shift) mod n²` (`shift` hashed from the pixel), i.e. from `blur[...]`.
    fn render_row_real(
        &self,
        rot: &Matrix3<f64>,
        o: &Vector3<f64>,
        blur: &[(Matrix3<f64>, Vector3<f64>)],
        y: usize,
        frame: usize,
        sensor: &Sensor,
    ) -> Row {
        let k = &self.camera;
        let n = self.samples_per_axis;
        let n2 = n * n;
        let inv_n2 = 1.0 / n2 as f64;
        let offsets: Vec<f64> = (0..n).map(|i| (i as f64 + 0.5) / n as f64 - 0.5).collect();
        let exposure = self.photometric.exposure(frame);
        let jitter = sensor.exposure_factor(frame);
        let w = k.width;
        let mut row = Row { rgb: Vec::with_capacity(3 * w), depth: Vec::with_capacity(w) };
        for x in 0..w {
            let centre = rot * k.ray(x as f64, y as f64);
            let depth = self.trace(o, &centre).map_or(0.0, |(h, _)| h.t as f32);
            let pixel = y * w + x;
            let shift = sensor.time_shift(pixel, n2);
            let mut sum = [0.0f64; 3];
            for (j, &dy) in offsets.iter().enumerate() {
                for (i, &dx) in offsets.iter().enumerate() {
                    let (r, c) = &blur[(j * n + i + shift) % n2];
                    let d = r * k.ray(x as f64 + dx, y as f64 + dy);
                    let l = self.radiance(c, &d);
                    for ch in 0..3 {
                        sum[ch] += l[ch];
                    }
                }
            }
            let nx = (x as f64 - k.cx) / k.fx;
            let ny = (y as f64 - k.cy) / k.fy;
            let vig = self.photometric.vignetting(nx, ny);
            for (ch, s) in sum.iter().enumerate() {
                let noise = self.photometric.noise(frame, pixel, ch);
                row.rgb.push(sensor.record(&self.photometric, s * inv_n2, ch, &exposure, jitter, vig, noise));
            }
            row.depth.push(depth);
        }
        row
    }

    /// The `n²` camera poses `(R, c)` of the shutter time strata around `pose` (realistic style):
    /// `pose · T(t)⁻¹ T(t + τ_k)` with `T` the camera path and `τ_k` stratum `k`'s centre.
    fn blur_poses(&self, pose: &Pose, frame: usize, sensor: &Sensor) -> Vec<(Matrix3<f64>, Vector3<f64>)> {
        let n2 = self.samples_per_axis * self.samples_per_axis;
        (0..n2)
            .map(|k| {
                let p = match &self.path {
                    Some(path) => {
                        let t = frame as f64;
                        let tau = sensor.time_offset(k, n2);
                        pose * path.pose_at(t).inverse() * path.pose_at(t + tau)
                    }
                    None => *pose,
                };
                (*p.rotation.to_rotation_matrix().matrix(), p.translation.vector)
            })
            .collect()
    }

    /// Render the scene from any camera-to-world `pose`; `frame` selects the exposure, noise and
    /// (realistic style) JPEG quality. Rows are rendered in parallel on the current rayon pool.
    ///
    /// # Errors
    /// Only if the realistic style's JPEG codec fails (it does not on a valid image).
    pub fn render_pose(&self, pose: &Pose, frame: usize) -> Result<(RgbImage, DepthMap)> {
        let rot = *pose.rotation.to_rotation_matrix().matrix();
        let o = pose.translation.vector;
        let (h, w) = (self.camera.height, self.camera.width);
        let rows: Vec<Row> = match &self.sensor {
            None => (0..h).into_par_iter().map(|y| self.render_row(&rot, &o, y, frame)).collect(),
            Some(sensor) => {
                let blur = self.blur_poses(pose, frame, sensor);
                (0..h)
                    .into_par_iter()
                    .map(|y| self.render_row_real(&rot, &o, &blur, y, frame, sensor))
                    .collect()
            }
        };
        let mut rgb = Array3::from_shape_fn((h, w, 3), |(y, x, c)| rows[y].rgb[3 * x + c]);
        let depth = Array2::from_shape_fn((h, w), |(y, x)| rows[y].depth[x]);
        if let Some(sensor) = &self.sensor {
            rgb = jpeg_round_trip(&rgb, sensor.jpeg_quality(frame))?;
        }
        Ok((rgb, depth))
    }
}
