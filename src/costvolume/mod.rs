//! The photometric cost volume of the paper (eq. 4), built one live frame at a time.
//!
//! For reference pixel `u` and inverse-depth hypothesis `ρ_k` ([`InverseDepthBins`]):
//!
//! `E(u, ρ_k) = 1/N_{u,k} Σ_n ‖ f_r(u) - f_n(π(T_nr π⁻¹(u, ρ_k))) ‖_1`
//!
//! where `f_n` is bilinearly sampled (SPEC.md §2.1) from the live feature map `[H, W, C]` and the warp
//! is the homogeneous form of SPEC.md §2.4, exact at `ρ = 0`. A sample that lands outside the live
//! image (`0 <= x <= W-1`, `0 <= y <= H-1` fails) or behind the live camera (`p_z <= 0`) does not
//! count: `N_{u,k}` is the number of frames that saw the cell. A cell no frame saw has count 0; its
//! [`CostVolume::cost`] is `None`, [`CostVolume::costs`] stores [`UNSEEN_COST`] there and
//! [`CostVolume::winner_take_all`] skips it.
//!
//! # Shapes
//! ```text
//! reference features  [H, W, C]  f32, channels last
//! live features       [H, W, C]  f32, channels last, same camera
//! sums, counts, costs [H, W, K]  hypothesis fastest
//! ```
//! Hypothesis fastest because every consumer walks the hypotheses of one pixel: the fast kernel
//! updates a pixel's `K` cells after hoisting its geometry, winner-take-all scans them for the
//! argmin and parabola, and the regulariser of the paper reads one pixel's cost curve at a time.
//! Each row `[W, K]` is a contiguous block, so a rayon task per row owns its cells outright.
//!
//! # Implementations and determinism
//! [`CostVolumeImpl::Reference`] is plain loops over [`Warp::apply_volume`] and
//! [`sample_bilinear`](crate::image::sample_bilinear), accumulating in `f64`, one thread.
//! [`CostVolumeImpl::Fast`] hoists the per-pixel geometry and runs a channel loop written for
//! 16-lane vectorisation (AVX-512 selected at run time); see `fast.rs`. Both compute the warped
//! positions with the same `f64` expressions, so their counts are equal bit for bit; their costs
//! agree within the budget of SPEC.md §9. The fast kernel parallelises over rows, each cell is
//! updated by exactly one task, and frames are added in call order, so its output is bit-identical
//! for any thread count (and for the portable and AVX-512 paths).
//!
//! # Example
//! ```
//! use densefeat::costvolume::{CostVolume, CostVolumeImpl};
//! use densefeat::geometry::{InverseDepthBins, PinholeCamera, Pose};
//! use ndarray::Array3;
//! let cam = PinholeCamera::new(3.0, 3.0, 1.0, 1.0, 3, 3).unwrap();
//! let f = Array3::from_shape_fn((3, 3, 1), |(y, x, _)| (3 * y + x) as f32);
//! let bins = InverseDepthBins::new(0.0, 1.0, 2).unwrap();
//! let mut cv = CostVolume::with_impl(f.clone(), cam, bins, CostVolumeImpl::Reference).unwrap();
//! cv.add_frame(f.view(), &Pose::identity()).unwrap();
//! // The identity pose maps every pixel onto itself at every hypothesis: zero cost, one view.
//! assert_eq!(cv.cost(1, 2, 0), Some(0.0));
//! assert_eq!(cv.count(1, 2, 1), 1);
//! ```

pub mod curve;
mod fast;
pub mod patch;
mod reference;
mod wta;

use ndarray::{Array1, Array3, ArrayView3};
use rayon::prelude::*;

use crate::error::{Error, Result};
use crate::geometry::{InverseDepthBins, PinholeCamera, Pose, Warp};
use crate::runtime::CpuFeatureLevel;
use crate::util::alloc::zeroed_aligned;

pub use curve::{
    border_weight, check_evidence_fraction, confidence, confidence_and_scale, cost_scale, evidence_threshold,
    filter_evidence, scale_of_spreads, taper_border, winner_take_all_costs, BORDER_WEIGHT_FLOOR,
};
pub use fast::fast_kernel_name;
pub(crate) use wta::MAX_OFFSET as MAX_PARABOLA_OFFSET;
pub use wta::{parabola_offset, WtaDepth};

/// What [`CostVolume::costs`] stores for a cell no frame saw (count 0). Finite, so the array is
/// NaN-free; [`CostVolume::winner_take_all`] never reads it (it skips count-0 cells).
pub const UNSEEN_COST: f32 = f32::MAX;

/// The per-frame truncation that leaves every cost unchanged (`min(l1, f32::MAX) = l1` for the finite
/// distances of finite features): the default of [`CostVolume::with_impl`].
pub const NO_TRUNCATION: f32 = f32::MAX;

/// The one rule for a per-frame truncation (SPEC.md §9.13): positive ([`NO_TRUNCATION`] included),
/// not NaN.
///
/// # Errors
/// [`Error::InvalidArgument`] naming `name` otherwise.
pub fn check_truncation(name: &str, tau: f32) -> Result<()> {
    if tau.is_nan() || tau <= 0.0 {
        return Err(Error::invalid_argument(name, format!("{tau}: must be positive (or none)")));
    }
    Ok(())
}

/// Which cost-volume implementation to run. Every variant is always compiled and always tested.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum CostVolumeImpl {
    /// Plain loops over [`Warp::apply_volume`] and `sample_bilinear`, `f64` sums, one thread. The oracle.
    Reference,
    /// Per-pixel geometry hoisted, shared bilinear weights, 16-lane channel loop, rayon over rows;
    /// AVX-512 when the CPU has it (see [`fast_kernel_name`]).
    Fast,
    /// [`CostVolumeImpl::Fast`] without run-time ISA dispatch (baseline target features). Same
    /// bits as `Fast`; kept reachable so that the equality is tested.
    FastPortable,
}

/// Running sums: `f64` for the reference, `f32` for the fast kernels.
#[derive(Clone, Debug)]
enum Sums {
    F64(Array1<f64>),
    F32(Array1<f32>),
}

/// A streaming cost volume `[H, W, K]` for one reference (key) frame.
#[derive(Clone, Debug)]
pub struct CostVolume {
    reference: Array3<f32>,
    camera: PinholeCamera,
    bins: InverseDepthBins,
    /// `ρ_k`, `k = 0..K`, from [`InverseDepthBins::rho`].
    rhos: Vec<f64>,
    imp: CostVolumeImpl,
    /// The SIMD level [`CostVolumeImpl::Fast`] is handed ([`CostVolume::with_level`]).
    level: CpuFeatureLevel,
    sums: Sums,
    counts: Array1<u16>,
    frames: usize,
    /// Per-frame truncation `τ`: each frame adds `min(l1, τ)` (SPEC.md §9.13).
    truncation: f32,
}

impl CostVolume {
    /// An empty volume computed with [`CostVolumeImpl::Fast`].
    ///
    /// # Errors
    /// As [`CostVolume::with_impl`].
    pub fn new(reference: Array3<f32>, camera: PinholeCamera, bins: InverseDepthBins) -> Result<Self> {
        Self::with_impl(reference, camera, bins, CostVolumeImpl::Fast)
    }

    /// An empty volume for reference features `[H, W, C]` seen by `camera` (`W x H`), hypotheses
    /// `bins`, computed with `imp`.
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] if the feature map is not `camera.height x camera.width` or has no
    /// channel.
    pub fn with_impl(
        reference: Array3<f32>,
        camera: PinholeCamera,
        bins: InverseDepthBins,
        imp: CostVolumeImpl,
    ) -> Result<Self> {
        check_shape("reference features", reference.dim(), &camera, None)?;
        let reference = reference.as_standard_layout().into_owned();
        let cells = camera.height * camera.width * bins.count;
        // Huge pages where the system allows (nn::alloc): the kernels' first touch of a cell is a
        // read, then a write, which on 4 KB zero pages costs a copy-on-write fault and a TLB
        // flush of every thread per page. Cache-line aligned: the block kernel's 64-byte sums and
        // 32-byte counts, and the a-search's 32-byte cost blocks (SPEC.md §10.1), then never
        // straddle two lines where `K` is a multiple of 16.
        let sums = match imp {
            CostVolumeImpl::Reference => Sums::F64(zeroed_aligned(cells)),
            CostVolumeImpl::Fast | CostVolumeImpl::FastPortable => Sums::F32(zeroed_aligned(cells)),
        };
        Ok(Self {
            rhos: bins.values(),
            reference,
            camera,
            bins,
            imp,
            level: CpuFeatureLevel::get(),
            sums,
            counts: zeroed_aligned(cells),
            frames: 0,
            truncation: NO_TRUNCATION,
        })
    }

    /// The same volume with every frame's cost truncated at `tau`: a frame adds `min(l1, τ)` to a cell
    /// instead of `l1` (SPEC.md §9.13; OpenDTAM's L1T). [`NO_TRUNCATION`] is the plain L1.
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] unless `tau > 0` (NaN included), or if frames were already added.
    pub fn with_truncation(mut self, tau: f32) -> Result<Self> {
        check_truncation("--truncate", tau)?;
        if self.frames > 0 {
            return Err(Error::invalid_argument(
                "cost volume",
                "the truncation is set before the first frame",
            ));
        }
        self.truncation = tau;
        Ok(self)
    }

    /// The per-frame truncation `τ` ([`NO_TRUNCATION`] when none).
    pub fn truncation(&self) -> f32 {
        self.truncation
    }

    /// A volume from running sums and counts accumulated elsewhere (a device backend's
    /// [`crate::backend::VolumeBuilder::finish`]), `[H, W, K]` hypothesis fastest, after `frames`
    /// frames with per-frame truncation `truncation`. The sums are `f32`, so it continues as a
    /// [`CostVolumeImpl::Fast`] volume.
    ///
    /// # Errors
    /// As [`CostVolume::with_impl`]; [`Error::InvalidArgument`] if `sums` or `counts` is not
    /// `H·W·K` long or `frames` exceeds [`MAX_FRAMES`]; as [`CostVolume::with_truncation`].
    pub fn from_sums(
        reference: Array3<f32>,
        camera: PinholeCamera,
        bins: InverseDepthBins,
        (sums, counts, frames): (Vec<f32>, Vec<u16>, usize),
        truncation: f32,
    ) -> Result<Self> {
        let mut cv =
            Self::with_impl(reference, camera, bins, CostVolumeImpl::Fast)?.with_truncation(truncation)?;
        if sums.len() != cv.counts.len() || counts.len() != cv.counts.len() || frames > MAX_FRAMES {
            return Err(Error::invalid_argument(
                "cost volume",
                format!(
                    "{} sums, {} counts, {frames} frames for a {:?} volume",
                    sums.len(),
                    counts.len(),
                    cv.dim()
                ),
            ));
        }
        (cv.sums, cv.counts, cv.frames) = (Sums::F32(sums.into()), counts.into(), frames);
        Ok(cv)
    }

    /// Add one live frame: its features `[H, W, C]` (same camera and channel count as the reference)
    /// and `T_nr = T_wn⁻¹ T_wr` ([`crate::geometry::relative_pose`]).
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] on a shape mismatch, or when [`MAX_FRAMES`] frames were already added.
    pub fn add_frame(&mut self, live: ArrayView3<f32>, t_nr: &Pose) -> Result<()> {
        let camera = self.camera;
        self.add_frame_seen_by(live, &camera, t_nr)
    }

    /// Add one live frame seen by its own camera: features `[H', W', C]` with `H' x W'` the live
    /// camera's size (the reference's channel count), warped with `π_n(T_nr π_r⁻¹(u, ρ))`, the
    /// reference camera's `K_r⁻¹` and the live camera's `K_n` (SPEC.md §9.1).
    ///
    /// # Errors
    /// As [`CostVolume::add_frame`].
    pub fn add_frame_seen_by(
        &mut self,
        live: ArrayView3<f32>,
        camera: &PinholeCamera,
        t_nr: &Pose,
    ) -> Result<()> {
        check_shape("live features", live.dim(), camera, Some(self.reference.dim().2))?;
        if self.frames >= MAX_FRAMES {
            return Err(Error::invalid_argument(
                "cost volume",
                format!("already {MAX_FRAMES} frames: the per-cell count is a u16"),
            ));
        }
        let live = live.as_standard_layout();
        let warp = Warp::new(&self.camera, camera, t_nr);
        let geo =
            fast::Geometry { camera: &self.camera, live: camera, warp: &warp, t: t_nr.translation.vector };
        match (&mut self.sums, self.imp) {
            (Sums::F64(sums), _) => reference::add_frame(
                &self.reference.view(),
                &live.view(),
                &warp,
                &self.rhos,
                f64::from(self.truncation),
                flat_mut(sums),
                flat_mut(&mut self.counts),
            ),
            (Sums::F32(sums), imp) => {
                let slices = fast::Slices {
                    reference: self.reference.as_slice().expect("standard layout"),
                    live: live.as_slice().expect("standard layout"),
                    channels: self.reference.dim().2,
                    truncation: self.truncation,
                };
                fast::add_frame(
                    &geo,
                    &slices,
                    &self.rhos,
                    flat_mut(sums),
                    flat_mut(&mut self.counts),
                    if imp == CostVolumeImpl::Fast { self.level } else { CpuFeatureLevel::Portable },
                )
            }
        }
        self.frames += 1;
        Ok(())
    }

    /// Number of frames added so far.
    pub fn frames(&self) -> usize {
        self.frames
    }

    /// The implementation this volume runs.
    pub fn implementation(&self) -> CostVolumeImpl {
        self.imp
    }

    /// This volume with its [`CostVolumeImpl::Fast`] kernels handed `level` instead of the process's
    /// [`CpuFeatureLevel::get`] (a backend passes its own; the same bits at every level).
    #[must_use]
    pub fn with_level(mut self, level: CpuFeatureLevel) -> Self {
        self.level = level;
        self
    }

    /// The hypotheses.
    pub fn bins(&self) -> &InverseDepthBins {
        &self.bins
    }

    /// The reference camera.
    pub fn camera(&self) -> &PinholeCamera {
        &self.camera
    }

    /// `[H, W, K]`.
    pub fn dim(&self) -> (usize, usize, usize) {
        (self.camera.height, self.camera.width, self.bins.count)
    }

    #[inline]
    fn index(&self, y: usize, x: usize, k: usize) -> usize {
        let (h, w, kk) = self.dim();
        assert!(y < h && x < w && k < kk, "cell ({y}, {x}, {k}) outside the volume {h}x{w}x{kk}");
        (y * w + x) * kk + k
    }

    /// Number of frames that saw cell `(y, x, k)`.
    ///
    /// # Panics
    /// If the cell is outside the volume.
    pub fn count(&self, y: usize, x: usize, k: usize) -> u16 {
        self.counts[self.index(y, x, k)]
    }

    /// The mean cost `E(u, ρ_k)` of cell `(y, x, k)` (pixel row `y`, column `x`), rounded to `f32`;
    /// `None` when no frame saw it.
    ///
    /// # Panics
    /// If the cell is outside the volume.
    pub fn cost(&self, y: usize, x: usize, k: usize) -> Option<f32> {
        let i = self.index(y, x, k);
        self.mean(i)
    }

    #[inline]
    fn mean(&self, i: usize) -> Option<f32> {
        let n = self.counts[i];
        if n == 0 {
            return None;
        }
        Some(match &self.sums {
            Sums::F64(s) => (s[i] / f64::from(n)) as f32,
            Sums::F32(s) => s[i] / f32::from(n),
        })
    }

    /// Every mean cost `[H, W, K]`; [`UNSEEN_COST`] where the count is 0.
    pub fn costs(&self) -> Array3<f32> {
        // Per cell, so the rows can be filled in parallel with the same bits.
        let mut v = vec![0.0f32; self.counts.len()];
        let row = (self.camera.width * self.bins.count).max(1);
        v.par_chunks_mut(row).enumerate().for_each(|(y, out)| {
            for (j, c) in out.iter_mut().enumerate() {
                *c = self.mean(y * row + j).unwrap_or(UNSEEN_COST);
            }
        });
        Array3::from_shape_vec(self.dim(), v).expect("length is H·W·K")
    }

    /// [`CostVolume::costs`] and [`CostVolume::counts`], consuming the volume: the f32 sums of the
    /// fast kernels become the costs in place (the same values, without a second `H·W·K` array of
    /// fresh memory; the reference's f64 sums are converted into a new array).
    pub fn into_costs(self) -> (Array3<f32>, Array3<u16>) {
        let dim = self.dim();
        let row = (self.camera.width * self.bins.count).max(1);
        let costs = match self.sums {
            Sums::F32(mut v) => {
                flat_mut(&mut v).par_chunks_mut(row).zip(flat(&self.counts).par_chunks(row)).for_each(
                    |(s, n)| {
                        for (s, &n) in s.iter_mut().zip(n) {
                            // `mean`'s expression.
                            *s = if n == 0 { UNSEEN_COST } else { *s / f32::from(n) };
                        }
                    },
                );
                v.into_shape_with_order(dim).expect("length is H·W·K")
            }
            Sums::F64(_) => self.costs(),
        };
        (costs, self.counts.into_shape_with_order(dim).expect("length is H·W·K"))
    }

    /// Every count `[H, W, K]`, borrowed.
    pub fn counts_view(&self) -> ArrayView3<'_, u16> {
        ArrayView3::from_shape(self.dim(), flat(&self.counts)).expect("length is H·W·K")
    }

    /// Every count `[H, W, K]`.
    pub fn counts(&self) -> Array3<u16> {
        self.counts.clone().into_shape_with_order(self.dim()).expect("length is H·W·K")
    }

    /// Winner-take-all depth with sub-bin parabola refinement (SPEC.md §9.5).
    pub fn winner_take_all(&self) -> WtaDepth {
        wta::winner_take_all(self)
    }
}

/// Most frames one volume accepts (the per-cell count is a `u16`).
pub const MAX_FRAMES: usize = u16::MAX as usize;

fn check_shape(
    what: &str,
    (h, w, c): (usize, usize, usize),
    camera: &PinholeCamera,
    channels: Option<usize>,
) -> Result<()> {
    if (h, w) != (camera.height, camera.width) {
        return Err(Error::invalid_argument(
            what,
            format!("{h}x{w} (HxW) but the camera is {}x{}", camera.height, camera.width),
        ));
    }
    if c == 0 {
        return Err(Error::invalid_argument(what, "no channel"));
    }
    if let Some(want) = channels {
        if c != want {
            return Err(Error::invalid_argument(what, format!("{c} channels, the reference has {want}")));
        }
    }
    Ok(())
}

/// The values of an owned one-dimensional array (always contiguous).
fn flat<T>(a: &Array1<T>) -> &[T] {
    a.as_slice().expect("owned one-dimensional arrays are contiguous")
}

/// [`flat`], mutable.
fn flat_mut<T>(a: &mut Array1<T>) -> &mut [T] {
    a.as_slice_mut().expect("owned one-dimensional arrays are contiguous")
}
