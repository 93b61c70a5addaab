//! Inference (SPEC.md §13.11): image → trunk features → head → oriented unit normals at the
//! features' level → bilinear upsampling to level 0, renormalised and re-oriented.

use ndarray::{Array3, ArrayView3};

use crate::backend::CpuBackend;
use crate::error::Result;
use crate::geometry::PinholeCamera;
use crate::nn::FeatureNet;
use crate::normals_net::head::{head_forward, orient, ray, unit_normals};
use crate::normals_net::weights::NormalNetWeights;

/// A normal predictor ready to run (its trunk's weights packed once).
pub struct NormalNet {
    weights: NormalNetWeights,
    trunk: FeatureNet,
}

impl NormalNet {
    /// Prepares `weights`.
    ///
    /// # Errors
    /// [`crate::Error::InvalidArgument`] for inconsistent weights.
    pub fn new(weights: NormalNetWeights) -> Result<Self> {
        let trunk = FeatureNet::new(weights.trunk.clone())?;
        Ok(NormalNet { weights, trunk })
    }

    /// The weights.
    pub fn weights(&self) -> &NormalNetWeights {
        &self.weights
    }

    /// The pyramid level of the head's output (the aggregated features', SPEC.md §8.1).
    pub fn level(&self) -> u32 {
        self.weights.trunk.config.block_level(0) as u32
    }

    /// Oriented unit normals at [`NormalNet::level`], `[ceil(H/2^l), ceil(W/2^l), 3]` (NaN where
    /// the head's output is zero), for `image` (`[H, W, 3]`, 0-255) seen by `camera` (level 0).
    ///
    /// # Errors
    /// [`crate::Error::InvalidArgument`] if the image does not match the camera.
    pub fn head_normals(&self, image: ArrayView3<f32>, camera: &PinholeCamera) -> Result<Array3<f32>> {
        let (h, w, _) = image.dim();
        crate::ops::expect_shape("normal predictor image", &[h, w], &[camera.height, camera.width])?;
        let features = self.trunk.features(image, &CpuBackend::default())?;
        let raw = head_forward(&self.weights.head, features.view())?;
        Ok(unit_normals(raw.view(), &camera.at_level(self.level())))
    }

    /// Camera-frame unit normals at level 0, `[H, W, 3]` (NaN: none), oriented towards the camera
    /// as [`crate::mapping::normals::normals_from_depth`]'s: [`NormalNet::head_normals`] upsampled
    /// by [`upsample_normals`].
    ///
    /// # Errors
    /// As [`NormalNet::head_normals`].
    pub fn predict(&self, image: ArrayView3<f32>, camera: &PinholeCamera) -> Result<Array3<f32>> {
        let coarse = self.head_normals(image, camera)?;
        Ok(upsample_normals(coarse.view(), self.level(), camera))
    }
}

/// Level-`level` normals to level 0 (`camera`'s grid): level-0 pixel `(x, y)` sits at level
/// coordinate `(x, y) / 2^level` (SPEC.md §2.6); the four surrounding normals are blended with
/// bilinear weights (those without a normal left out), the sum normalised to unit length and
/// oriented towards the pixel's ray. NaN where no neighbour has a normal or the blend vanishes.
pub fn upsample_normals(coarse: ArrayView3<f32>, level: u32, camera: &PinholeCamera) -> Array3<f32> {
    let (hc, wc, _) = coarse.dim();
    let (h, w) = (camera.height, camera.width);
    let scale = 0.5f64.powi(level as i32);
    let mut out = Array3::from_elem((h, w, 3), f32::NAN);
    if hc == 0 || wc == 0 {
        return out;
    }
    let axis = |p: usize, n: usize| {
        let u = (p as f64 * scale).min((n - 1) as f64);
        let i0 = u.floor() as usize;
        let i1 = (i0 + 1).min(n - 1);
        (i0, i1, u - i0 as f64)
    };
    for y in 0..h {
        let (y0, y1, b) = axis(y, hc);
        for x in 0..w {
            let (x0, x1, a) = axis(x, wc);
            let mut v = [0.0f64; 3];
            for (yy, xx, wt) in [
                (y0, x0, (1.0 - a) * (1.0 - b)),
                (y0, x1, a * (1.0 - b)),
                (y1, x0, (1.0 - a) * b),
                (y1, x1, a * b),
            ] {
                let n: [f64; 3] = std::array::from_fn(|k| f64::from(coarse[[yy, xx, k]]));
                if wt == 0.0 || n.iter().any(|c| !c.is_finite()) {
                    continue;
                }
                for k in 0..3 {
                    v[k] += wt * n[k];
                }
            }
            if let Some((n, _, _)) = orient(v, ray(camera, x, y)) {
                for k in 0..3 {
                    out[[y, x, k]] = n[k] as f32;
                }
            }
        }
    }
    out
}

/// Angular errors (degrees) between two normal maps of one shape, at pixels where both have a
/// normal, in row-major order.
///
/// # Panics
/// If `b` is smaller than `a`.
pub fn angular_errors(a: ArrayView3<f32>, b: ArrayView3<f32>) -> Vec<f64> {
    let (h, w, _) = a.dim();
    let mut v = Vec::new();
    for y in 0..h {
        for x in 0..w {
            let p: [f64; 3] = std::array::from_fn(|k| f64::from(a[[y, x, k]]));
            let q: [f64; 3] = std::array::from_fn(|k| f64::from(b[[y, x, k]]));
            let norm = |n: [f64; 3]| (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
            let (np, nq) = (norm(p), norm(q));
            if !(np > 0.0 && nq > 0.0 && np.is_finite() && nq.is_finite()) {
                continue;
            }
            let cos = (p[0] * q[0] + p[1] * q[1] + p[2] * q[2]) / (np * nq);
            v.push(cos.clamp(-1.0, 1.0).acos().to_degrees());
        }
    }
    v
}

/// Mean and median (the lower middle value for an even count) of angular errors; `None` when empty.
pub fn mean_and_median(errors: &[f64]) -> Option<(f64, f64)> {
    if errors.is_empty() {
        return None;
    }
    let mean = errors.iter().sum::<f64>() / errors.len() as f64;
    let mut s = errors.to_vec();
    s.sort_by(f64::total_cmp);
    Some((mean, s[(s.len() - 1) / 2]))
}
