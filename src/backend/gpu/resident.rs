//! The resident volume on the GPU (SPEC.md §15.6): [`GpuResident`] keeps the finished volume's
//! mean costs (the running sums' buffer, turned into means in place) and counts on the device, and
//! runs the evidence filter, the confidence and cost scale, winner-take-all, the border taper and
//! DTAM there (`resident.wgsl`, `wta.wgsl`, `dtam.wgsl`). What crosses the bus: a few hundred bytes
//! of constants, the taper's per-pixel weights, and per-pixel results (confidence and spread,
//! winner-take-all, DTAM's `d` and `a`); never the `[H, W, K]` volume.

use std::sync::Arc;

use ndarray::{Array2, Array3};

use super::{f32s, record, u32s, unsupported, GpuBackend};
use crate::backend::resident::{check_bins, check_radius};
use crate::backend::ResidentVolume;
use crate::costvolume::{
    border_weight, check_evidence_fraction, evidence_threshold, scale_of_spreads, WtaDepth, UNSEEN_COST,
};
use crate::dtam::{DtamProblem, DtamReport, DtamResult, Resident};
use crate::error::Result;
use crate::geometry::InverseDepthBins;

const MODULE: &str = "resident";
const SOURCE: &str = include_str!("resident.wgsl");

/// A finished cost volume on the device.
pub(super) struct GpuResident {
    gpu: Arc<GpuBackend>,
    /// `[H, W, K]` mean costs, `f32` (UNSEEN_COST where unseen).
    costs: wgpu::Buffer,
    /// `[H, W, K]` counts, `u32`.
    counts: wgpu::Buffer,
    dim: (usize, usize, usize),
    frames: usize,
}

impl GpuResident {
    /// The volume of `sums` and `counts` (`[H, W, K]`, `frames` live frames), its sums turned into
    /// means in place.
    ///
    /// # Errors
    /// A non-finite sum (the GPU kernels take finite values only); device failures.
    pub(super) fn from_sums(
        gpu: Arc<GpuBackend>,
        (sums, counts): (wgpu::Buffer, wgpu::Buffer),
        dim: (usize, usize, usize),
        frames: usize,
    ) -> Result<Self> {
        let v = Self { gpu, costs: sums, counts, dim, frames };
        let cells = dim.0 * dim.1 * dim.2;
        let bad = v.gpu.storage_zeroed(8)?;
        v.run("mean", cells, &[(1, &v.costs), (2, &v.counts), (6, &bad)])?;
        let non_finite = u32s(&v.gpu.read_back(&bad, 0, 4)?)[0];
        if non_finite > 0 {
            return Err(unsupported(format!(
                "the cost volume has {non_finite} non-finite sums; the GPU kernels take finite values only \
                 (check the features for infinities or NaN), or use --backend cpu"
            )));
        }
        Ok(v)
    }

    fn pixels(&self) -> usize {
        self.dim.0 * self.dim.1
    }

    /// Submits kernel `entry` over `n` invocations with `p = [n, K, UNSEEN_COST bits, frames]` at
    /// binding 0 and `bindings`.
    fn run(&self, entry: &'static str, n: usize, bindings: &[(u32, &wgpu::Buffer)]) -> Result<()> {
        let gpu = &self.gpu;
        let p = super::params([n, self.dim.2, UNSEEN_COST.to_bits() as usize, self.frames]);
        let pb = gpu.storage_bytes(bytemuck::cast_slice(&p));
        let pipeline = gpu.pipeline_entry(MODULE, entry, || SOURCE.to_string())?;
        let mut entries = vec![(0, &pb)];
        entries.extend_from_slice(bindings);
        let group = gpu.bind(&pipeline, &entries);
        let mut encoder = gpu.device.create_command_encoder(&Default::default());
        {
            let mut pass = encoder.begin_compute_pass(&Default::default());
            record(&mut pass, &pipeline, &group, p[0]);
        }
        gpu.queue.submit([encoder.finish()]);
        Ok(())
    }
}

impl ResidentVolume for GpuResident {
    fn dim(&self) -> (usize, usize, usize) {
        self.dim
    }

    fn frames(&self) -> usize {
        self.frames
    }

    fn filter_evidence(&mut self, fraction: f64) -> Result<()> {
        check_evidence_fraction(fraction)?;
        // Counts are at most `frames` (<= MAX_FRAMES, a u16), so the table is indexed by any count.
        let table: Vec<u32> = (0..=self.frames)
            .map(|n| u32::from(evidence_threshold(u16::try_from(n).unwrap_or(u16::MAX), fraction)))
            .collect();
        let tb = self.gpu.storage_bytes(bytemuck::cast_slice(&table));
        self.run("evidence", self.pixels(), &[(1, &self.costs), (2, &self.counts), (3, &tb)])
    }

    fn confidence_and_scale(&self) -> Result<(Array2<f32>, f64)> {
        let pixels = self.pixels();
        let bytes = self.gpu.check_size(2 * pixels)?;
        let out = self.gpu.storage_zeroed(bytes)?;
        self.run("confidence", pixels, &[(1, &self.costs), (2, &self.counts), (5, &out)])?;
        let v = f32s(&self.gpu.read_back(&out, 0, 8 * pixels as u64)?);
        let conf = Array2::from_shape_fn((self.dim.0, self.dim.1), |(y, x)| v[2 * (y * self.dim.1 + x)]);
        let spreads = v.chunks_exact(2).map(|c| c[1]).filter(|&s| s >= 0.0).collect();
        Ok((conf, scale_of_spreads(spreads)))
    }

    fn winner_take_all(&self, bins: &InverseDepthBins) -> Result<WtaDepth> {
        check_bins(self.dim, bins)?;
        super::wta::winner_take_all_on(&self.gpu, &self.costs, self.dim, bins)
    }

    fn taper_border(&mut self, radius: f64) -> Result<()> {
        check_radius(radius)?;
        if radius <= 0.0 {
            return Ok(());
        }
        let (h, w, k) = self.dim;
        let weights: Vec<f32> = (0..h * w).map(|i| border_weight(i / w, i % w, h, w, radius)).collect();
        let wb = self.gpu.storage_init(&weights);
        self.run("taper", h * w * k, &[(1, &self.costs), (4, &wb)])
    }

    fn dtam_solve(&self, problem: &DtamProblem<'_, Resident>) -> Result<(DtamResult, DtamReport)> {
        super::dtam::solve_on(&self.gpu, problem, &self.costs, self.dim).map(|(r, report, _)| (r, report))
    }

    fn costs(&self) -> Result<Array3<f32>> {
        let v = f32s(&self.gpu.read_back(&self.costs, 0, 4 * (self.pixels() * self.dim.2) as u64)?);
        Array3::from_shape_vec(self.dim, v).map_err(|e| unsupported(format!("download: {e}")))
    }
}
