//! The affine-warped 7x7 patch cost volume (SPEC.md §9a.5): the paper's "7x7 patches that are affine
//! warped before matching (similar to what is used in DSO)". Not a per-pixel descriptor: the live
//! patch's shape depends on the hypothesis, so it has its own kernels, with §9's layout (`[H, W, K]`,
//! hypothesis fastest), counts and validity.
//!
//! For reference pixel `u`, hypothesis `ρ` and live frame `n`, the fronto-parallel plane at depth
//! `1/ρ` through `u` maps reference pixel `u + δ` to `π_n(p + δ_x a_x + δ_y a_y)`, `p = R K_r⁻¹ u̇ + ρ t`
//! (§9.1's warp), `a_x`, `a_y` the first two columns of `R K_r⁻¹` (the plane-induced homography
//! `K_n (R + ρ t e₃ᵀ) K_r⁻¹`). Its linearisation at `δ = 0`: centre `c = π_n(p)` (§9.1's `x', y'`,
//! the same f64 expressions) and Jacobian
//!
//! `J = 1/p_z [[f_x (a_x,x - x̂ a_x,z), f_x (a_y,x - x̂ a_y,z)], [f_y (a_x,y - ŷ a_x,z), f_y (a_y,y - ŷ a_y,z)]]`,
//! `x̂ = p_x / p_z`, `ŷ = p_y / p_z`.
//!
//! The live patch samples the live grey image bilinearly (§2.1) at `c + J δ`, `δ ∈ {-3..3}²`, each
//! position clamped into the image; the reference patch is the keyframe's grey at `u + δ`, clamped.
//! Per frame `e = Σ_δ |(r_δ - r̄) - (l_δ - l̄)|` (L1 of the mean-removed patches, grey levels; `r̄`, `l̄`
//! the patch means), truncated at `τ` (§9.13). Frame `n` counts for the cell iff `c` is valid by §9.1
//! (`p_z > 0` and finite, `0 <= c <= (W-1, H-1)`) and every sample position is a number.
//!
//! [`PatchImpl::Reference`]: loops over cells, f64. [`PatchImpl::Fast`]: rows in parallel, the
//! reference patch mean-removed once per pixel and frame, samples and sums in f32; positions,
//! corners and validity in the same f64 expressions as the reference (counts equal bit for bit).

mod fast;
mod reference;

use ndarray::{Array3, ArrayView2};

use crate::costvolume::{check_truncation, CostVolume, MAX_FRAMES};
use crate::error::{Error, Result};
use crate::geometry::{InverseDepthBins, PinholeCamera, Pose, Warp};
use crate::image::sample::axis;

/// Half the patch side.
pub const PATCH_RADIUS: i64 = 3;
/// Samples per patch, 7x7.
pub const PATCH_SAMPLES: usize = 49;

/// Which patch-volume implementation to run. Both are always compiled and tested.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum PatchImpl {
    /// Loops over cells, f64 samples and sums, one thread: the oracle.
    Reference,
    /// Rows in parallel, f32 samples and sums.
    Fast,
}

/// The linearised plane-induced warp of a patch: its centre in the live image and `J`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PatchWarp {
    /// Centre `(x', y')`, §9.1's warp of the patch's pixel.
    pub centre: (f64, f64),
    /// `J[r][c] = ∂(x', y')_r / ∂δ_c`.
    pub jacobian: [[f64; 2]; 2],
}

impl PatchWarp {
    /// The (unclamped) live position of patch offset `(dx, dy)`: `c + J δ`.
    #[inline]
    pub fn position(&self, dx: i64, dy: i64) -> (f64, f64) {
        let (dx, dy) = (dx as f64, dy as f64);
        let j = &self.jacobian;
        (self.centre.0 + j[0][0] * dx + j[0][1] * dy, self.centre.1 + j[1][0] * dx + j[1][1] * dy)
    }
}

/// The patch warp of reference pixel `(x, y)` at `rho`, or `None` unless the centre is valid by
/// SPEC.md §9.1 (in front of the live camera, finite, inside its image). The centre has the bits of
/// [`Warp::apply_volume`].
pub fn patch_warp(warp: &Warp, x: f64, y: f64, rho: f64) -> Option<PatchWarp> {
    let p = warp.point(x, y, rho);
    if !(p.z > 0.0 && p.z.is_finite()) {
        return None;
    }
    let inv = 1.0 / p.z;
    let cam = warp.target();
    let centre = (cam.fx * p.x * inv + cam.cx, cam.fy * p.y * inv + cam.cy);
    axis(centre.0, cam.width)?;
    axis(centre.1, cam.height)?;
    let rk = warp.rotation_k_inv();
    let (xh, yh) = (p.x * inv, p.y * inv);
    let jacobian = [
        [cam.fx * inv * (rk[(0, 0)] - xh * rk[(2, 0)]), cam.fx * inv * (rk[(0, 1)] - xh * rk[(2, 1)])],
        [cam.fy * inv * (rk[(1, 0)] - yh * rk[(2, 0)]), cam.fy * inv * (rk[(1, 1)] - yh * rk[(2, 1)])],
    ];
    Some(PatchWarp { centre, jacobian })
}

/// Corners and weight along one axis of a position clamped into `[0, n-1]`; `None` for NaN.
#[inline]
pub(crate) fn clamped_axis(x: f64, n: usize) -> Option<(usize, usize, f64)> {
    axis(x.clamp(0.0, (n - 1) as f64), n)
}

/// Running sums: f64 for the reference, f32 for the fast path.
#[derive(Clone, Debug)]
enum Sums {
    F64(Vec<f64>),
    F32(Vec<f32>),
}

/// A streaming patch cost volume `[H, W, K]` for one keyframe's grey image.
#[derive(Clone, Debug)]
pub struct PatchVolume {
    /// The keyframe's grey image `[H, W, 1]`.
    reference: Array3<f32>,
    camera: PinholeCamera,
    bins: InverseDepthBins,
    rhos: Vec<f64>,
    imp: PatchImpl,
    sums: Sums,
    counts: Vec<u16>,
    frames: usize,
    truncation: f32,
}

impl PatchVolume {
    /// An empty volume for the keyframe's grey image `[H, W, 1]` seen by `camera`, with per-frame
    /// truncation `truncation` ([`crate::costvolume::NO_TRUNCATION`] for none).
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] if the image is not `[camera.height, camera.width, 1]` or the
    /// truncation is not positive.
    pub fn new(
        reference: Array3<f32>,
        camera: PinholeCamera,
        bins: InverseDepthBins,
        truncation: f32,
        imp: PatchImpl,
    ) -> Result<Self> {
        check_grey("patch7 keyframe", &reference, &camera)?;
        check_truncation("truncation", truncation)?;
        let n = camera.height * camera.width * bins.count;
        let rhos: Vec<f64> = (0..bins.count).map(|k| bins.rho(k)).collect();
        let sums = match imp {
            PatchImpl::Reference => Sums::F64(vec![0.0; n]),
            PatchImpl::Fast => Sums::F32(vec![0.0; n]),
        };
        let reference = reference.as_standard_layout().into_owned();
        Ok(Self { reference, camera, bins, rhos, imp, sums, counts: vec![0; n], frames: 0, truncation })
    }

    /// Add one live frame's grey image `[H', W', 1]` seen by `camera` with `T_nr`.
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] for a shape mismatch or past [`MAX_FRAMES`] frames.
    pub fn add_frame_seen_by(
        &mut self,
        live: &Array3<f32>,
        camera: &PinholeCamera,
        t_nr: &Pose,
    ) -> Result<()> {
        check_grey("patch7 live frame", live, camera)?;
        if self.frames >= MAX_FRAMES {
            return Err(Error::invalid_argument(
                "cost volume",
                format!("already {MAX_FRAMES} frames: the per-cell count is a u16"),
            ));
        }
        let live = live.as_standard_layout();
        // `[H', W', 1]` standard layout: the `[H', W']` view is standard layout too.
        let live = live.index_axis(ndarray::Axis(2), 0);
        let key = self.reference.index_axis(ndarray::Axis(2), 0);
        let warp = Warp::new(&self.camera, camera, t_nr);
        let problem = Problem { key, live, warp: &warp, rhos: &self.rhos, truncation: self.truncation };
        match &mut self.sums {
            Sums::F64(s) => reference::add_frame(&problem, s, &mut self.counts),
            Sums::F32(s) => fast::add_frame(&problem, s, &mut self.counts),
        }
        self.frames += 1;
        Ok(())
    }

    /// The keyframe's camera.
    pub fn camera(&self) -> &PinholeCamera {
        &self.camera
    }

    /// Frames added so far.
    pub fn frames(&self) -> usize {
        self.frames
    }

    /// The implementation.
    pub fn implementation(&self) -> PatchImpl {
        self.imp
    }

    /// Frames that saw cell `(y, x, k)`.
    pub fn count(&self, y: usize, x: usize, k: usize) -> u16 {
        self.counts[self.index(y, x, k)]
    }

    /// The mean per-frame cost of a cell (`sum / count` in the sums' precision, rounded to f32),
    /// `None` if no frame saw it.
    pub fn cost(&self, y: usize, x: usize, k: usize) -> Option<f32> {
        let i = self.index(y, x, k);
        let n = self.counts[i];
        (n > 0).then(|| match &self.sums {
            Sums::F64(s) => (s[i] / f64::from(n)) as f32,
            Sums::F32(s) => s[i] / f32::from(n),
        })
    }

    fn index(&self, y: usize, x: usize, k: usize) -> usize {
        (y * self.camera.width + x) * self.bins.count + k
    }

    /// The finished volume as a [`CostVolume`] (f32 sums; the reference's f64 sums rounded), for
    /// winner-take-all, the evidence filter and DTAM (SPEC.md §11.1).
    ///
    /// # Errors
    /// As [`CostVolume::from_sums`].
    pub fn into_cost_volume(self) -> Result<CostVolume> {
        let sums = match self.sums {
            Sums::F64(s) => s.into_iter().map(|v| v as f32).collect(),
            Sums::F32(s) => s,
        };
        CostVolume::from_sums(
            self.reference,
            self.camera,
            self.bins,
            (sums, self.counts, self.frames),
            self.truncation,
        )
    }
}

/// One frame's inputs to a kernel.
pub(crate) struct Problem<'a> {
    key: ArrayView2<'a, f32>,
    live: ArrayView2<'a, f32>,
    warp: &'a Warp,
    rhos: &'a [f64],
    truncation: f32,
}

fn check_grey(what: &str, img: &Array3<f32>, camera: &PinholeCamera) -> Result<()> {
    let (h, w, c) = img.dim();
    if (h, w, c) != (camera.height, camera.width, 1) {
        return Err(Error::invalid_argument(
            what,
            format!("shape {:?}, expected [{}, {}, 1] (grey)", img.shape(), camera.height, camera.width),
        ));
    }
    Ok(())
}
