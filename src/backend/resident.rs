//! [`ResidentVolume`]: a finished cost volume that stays where its backend computed it, and the
//! steps between the volume and DTAM run on it there (SPEC.md §15.6). The keyframe mapper runs
//! finish -> evidence filter (§9.10) -> confidence and cost scale (§9.12) -> winner-take-all (§9.5)
//! -> border taper (§10.1c) -> DTAM (§10) on one value, so on a device backend the `[H, W, K]`
//! volume never crosses the bus: only per-pixel maps and scalars come back.
//!
//! [`HostVolume`] is the host's (the CPU backend's, and any builder's default): the host functions of
//! [`crate::costvolume`] on owned arrays, so the CPU mapper's bits are those of calling them
//! directly.

use ndarray::{Array2, Array3};

use crate::costvolume::{
    check_evidence_fraction, confidence_and_scale, filter_evidence, taper_border, winner_take_all_costs,
    CostVolume, WtaDepth,
};
use crate::dtam::{DtamProblem, DtamReport, DtamResult, Resident};
use crate::error::Result;
use crate::geometry::InverseDepthBins;
use crate::runtime::CpuFeatureLevel;

/// A finished cost volume (mean costs and per-cell counts, `[H, W, K]`) kept by its backend,
/// with the ops that turn it into a keyframe's depth (SPEC.md §15.6). Made by
/// [`super::VolumeBuilder::finish_resident`]. Each op agrees with the host function it names within
/// SPEC.md §15.3's budgets (the GPU's: bit for bit on a device with correctly rounded `f64`).
pub trait ResidentVolume: Send {
    /// `(H, W, K)`.
    fn dim(&self) -> (usize, usize, usize);
    /// The live frames the volume holds.
    fn frames(&self) -> usize;
    /// The evidence filter in place ([`crate::costvolume::filter_evidence`], SPEC.md §9.10).
    ///
    /// # Errors
    /// A fraction outside `[0, 1]`; device failures.
    fn filter_evidence(&mut self, fraction: f64) -> Result<()>;
    /// Per-pixel confidence and the volume's cost scale
    /// ([`crate::costvolume::confidence_and_scale`], SPEC.md §9.12).
    ///
    /// # Errors
    /// Device failures.
    fn confidence_and_scale(&self) -> Result<(Array2<f32>, f64)>;
    /// Winner-take-all with sub-bin refinement ([`crate::costvolume::winner_take_all_costs`],
    /// SPEC.md §9.5).
    ///
    /// # Errors
    /// `bins` that do not match the volume; device failures.
    fn winner_take_all(&self, bins: &InverseDepthBins) -> Result<WtaDepth>;
    /// The border taper of `radius` pixels of the volume's grid, in place
    /// ([`crate::costvolume::taper_border`], SPEC.md §10.1c).
    ///
    /// # Errors
    /// A radius that is not finite; device failures.
    fn taper_border(&mut self, radius: f64) -> Result<()>;
    /// DTAM's solve on these costs ([`super::Backend::dtam_solve`], SPEC.md §10).
    ///
    /// # Errors
    /// As [`super::Backend::dtam_solve`].
    fn dtam_solve(&self, problem: &DtamProblem<'_, Resident>) -> Result<(DtamResult, DtamReport)>;
    /// A host copy of the costs as they are now (for diagnostics and tests).
    ///
    /// # Errors
    /// Device read-back failures.
    fn costs(&self) -> Result<Array3<f32>>;
}

/// The host's [`ResidentVolume`]: owned mean costs and counts.
#[derive(Debug)]
pub struct HostVolume {
    costs: Array3<f32>,
    counts: Array3<u16>,
    frames: usize,
    level: CpuFeatureLevel,
}

impl HostVolume {
    /// The finished `volume`'s mean costs and counts ([`CostVolume::into_costs`]); DTAM runs with
    /// the row kernels of `level`.
    pub fn new(volume: CostVolume, level: CpuFeatureLevel) -> Self {
        let frames = volume.frames();
        let (costs, counts) = volume.into_costs();
        Self { costs, counts, frames, level }
    }
}

impl ResidentVolume for HostVolume {
    fn dim(&self) -> (usize, usize, usize) {
        self.costs.dim()
    }

    fn frames(&self) -> usize {
        self.frames
    }

    fn filter_evidence(&mut self, fraction: f64) -> Result<()> {
        check_evidence_fraction(fraction)?;
        filter_evidence(&mut self.costs, self.counts.view(), fraction);
        Ok(())
    }

    fn confidence_and_scale(&self) -> Result<(Array2<f32>, f64)> {
        Ok(confidence_and_scale(self.costs.view(), self.counts.view(), self.frames))
    }

    fn winner_take_all(&self, bins: &InverseDepthBins) -> Result<WtaDepth> {
        check_bins(self.dim(), bins)?;
        Ok(winner_take_all_costs(self.costs.view(), bins))
    }

    fn taper_border(&mut self, radius: f64) -> Result<()> {
        check_radius(radius)?;
        taper_border(&mut self.costs, radius);
        Ok(())
    }

    fn dtam_solve(&self, problem: &DtamProblem<'_, Resident>) -> Result<(DtamResult, DtamReport)> {
        crate::dtam::solve_with(&problem.with_costs(self.costs.view()), self.level)
    }

    fn costs(&self) -> Result<Array3<f32>> {
        Ok(self.costs.clone())
    }
}

/// The taper radius's rule (SPEC.md §10.1c): finite (`<= 0` is off).
pub(crate) fn check_radius(radius: f64) -> Result<()> {
    if radius.is_finite() {
        Ok(())
    } else {
        Err(crate::error::Error::invalid_argument("border-taper", format!("{radius}: must be finite")))
    }
}

/// Hypotheses that match a volume of shape `dim`.
pub(crate) fn check_bins((_, _, k): (usize, usize, usize), bins: &InverseDepthBins) -> Result<()> {
    if k == bins.count {
        Ok(())
    } else {
        Err(crate::error::Error::invalid_argument(
            "winner_take_all",
            format!("{k} costs per pixel for {} hypotheses", bins.count),
        ))
    }
}
