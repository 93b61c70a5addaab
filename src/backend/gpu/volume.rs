//! The cost volume on the GPU (SPEC.md §9, §15.5): [`GpuVolume`] keeps the running sums (`f32`)
//! and counts (`u32`) of the `[H, W, K]` volume in device buffers from the first frame to
//! [`VolumeBuilder::finish`]; `add_frame` uploads a few hundred bytes of geometry and submits one
//! dispatch of `volume.wgsl` (one invocation per cell), and only `snapshot` / `finish` read the
//! volume back.
//!
//! The warp, the validity test and the bilinear weights are the CPU's `f64` expressions
//! (`costvolume::fast`), so the counts equal the CPU's exactly; the sampling and the L1 distance are
//! `f32`, summed over channels in order, within SPEC.md §9.6's budget of the reference.

use std::sync::Arc;

use super::resident::GpuResident;
use super::{f32s, record, u32s, unsupported, GpuBackend, NAME};
use crate::backend::{ResidentVolume, Tensor, VolumeBuilder};
use crate::costvolume::{CostVolume, MAX_FRAMES};
use crate::error::{Error, Result};
use crate::geometry::{InverseDepthBins, PinholeCamera, Pose, Warp};

const MODULE: &str = "volume";
const SOURCE: &str = include_str!("volume.wgsl");

/// A cost volume accumulating on the device.
pub(super) struct GpuVolume {
    gpu: Arc<GpuBackend>,
    reference: Tensor,
    camera: PinholeCamera,
    bins: InverseDepthBins,
    /// `[H, W, K]` running sums, `f32`.
    sums: wgpu::Buffer,
    /// `[H, W, K]` counts, `u32` (at most [`MAX_FRAMES`]).
    counts: wgpu::Buffer,
    cells: usize,
    frames: usize,
    /// Per-frame truncation `τ` (SPEC.md §9.13).
    truncation: f32,
}

impl GpuVolume {
    /// An empty volume for device features `reference` (`[H, W, C]`, `H x W` the camera's).
    ///
    /// # Errors
    /// A host tensor or a shape mismatch; no shader f64; a volume over the adapter's binding limit; a
    /// truncation that is not positive.
    pub(super) fn new(
        gpu: Arc<GpuBackend>,
        reference: &Tensor,
        camera: PinholeCamera,
        bins: InverseDepthBins,
        truncation: f32,
    ) -> Result<Self> {
        crate::costvolume::check_truncation("--truncate", truncation)?;
        gpu.buffer(reference)?;
        gpu.require_f64("cost_volume", "the warp and the bounds test are the CPU's f64 expressions")?;
        let (h, w, c) = reference.dim();
        check_shape("reference features", (h, w, c), &camera, None)?;
        let cells = h * w * bins.count;
        let bytes = gpu.check_size(cells)?;
        let (sums, counts) = (gpu.storage_zeroed(bytes)?, gpu.storage_zeroed(bytes)?);
        Ok(Self {
            gpu,
            reference: reference.clone(),
            camera,
            bins,
            sums,
            counts,
            cells,
            frames: 0,
            truncation,
        })
    }

    /// The volume so far on the host.
    fn download(&self) -> Result<CostVolume> {
        let reference = crate::backend::Backend::download(self.gpu.as_ref(), &self.reference)?;
        let bytes = self.cells as u64 * 4;
        let sums = f32s(&self.gpu.read_back(&self.sums, 0, bytes)?);
        // Every count is at most `frames <= MAX_FRAMES`, so it fits a u16.
        let counts = u32s(&self.gpu.read_back(&self.counts, 0, bytes)?)
            .into_iter()
            .map(|n| u16::try_from(n).map_err(|_| unsupported(format!("a cell count of {n} (> 65535)"))))
            .collect::<Result<Vec<u16>>>()?;
        CostVolume::from_sums(reference, self.camera, self.bins, (sums, counts, self.frames), self.truncation)
    }
}

/// The geometry `volume.wgsl` reads (see its header): `R K⁻¹`, `t`, intrinsics, bounds, `τ`, `ρ_k`.
fn geometry(
    camera: &PinholeCamera,
    live: &PinholeCamera,
    bins: &InverseDepthBins,
    t_nr: &Pose,
    truncation: f32,
) -> Vec<f64> {
    let warp = Warp::new(camera, live, t_nr);
    let rk = warp.rotation_k_inv();
    let t = warp.translation();
    let camera = live;
    let (w, h) = (camera.width, camera.height);
    let mut g: Vec<f64> = (0..3).flat_map(|r| (0..3).map(move |c| rk[(r, c)])).collect();
    g.extend([t.x, t.y, t.z, camera.fx, camera.fy, camera.cx, camera.cy]);
    g.extend([(w - 1) as f64, (h - 1) as f64, w.saturating_sub(2) as f64, h.saturating_sub(2) as f64]);
    // f32::MAX, never infinity, when untruncated: WGSL need not preserve infinities.
    g.push(f64::from(truncation.min(f32::MAX)));
    g.extend(bins.values());
    g
}

impl VolumeBuilder for GpuVolume {
    fn camera(&self) -> &PinholeCamera {
        &self.camera
    }

    fn add_frame_seen_by(&mut self, live: &Tensor, camera: &PinholeCamera, t_nr: &Pose) -> Result<()> {
        let lb = self.gpu.buffer(live)?;
        check_shape("live features", live.dim(), camera, Some(self.reference.dim().2))?;
        if self.frames >= MAX_FRAMES {
            return Err(Error::invalid_argument(
                "cost volume",
                format!("already {MAX_FRAMES} frames: the per-cell count is a u16"),
            ));
        }
        let gpu = &self.gpu;
        let (lh, lw, c) = live.dim();
        let (_, w, _) = self.reference.dim();
        let p = super::params([self.cells, lh, w, c, self.bins.count, lw]);
        let pb = gpu.storage_bytes(bytemuck::cast_slice(&p));
        let gb = gpu.storage_bytes(bytemuck::cast_slice(&geometry(
            &self.camera,
            camera,
            &self.bins,
            t_nr,
            self.truncation,
        )));
        let pipeline = gpu.pipeline_entry(MODULE, "add_frame", || SOURCE.to_string())?;
        let rb = &gpu.buffer(&self.reference)?.buffer;
        let group = gpu.bind(
            &pipeline,
            &[(0, &pb), (1, &gb), (2, rb), (3, &lb.buffer), (4, &self.sums), (5, &self.counts)],
        );
        let mut encoder = gpu.device.create_command_encoder(&Default::default());
        {
            let mut pass = encoder.begin_compute_pass(&Default::default());
            record(&mut pass, &pipeline, &group, p[0]);
        }
        gpu.queue.submit([encoder.finish()]);
        self.frames += 1;
        Ok(())
    }

    fn frames(&self) -> usize {
        self.frames
    }

    fn snapshot(&self) -> Result<CostVolume> {
        self.download()
    }

    fn finish(self: Box<Self>) -> Result<CostVolume> {
        self.download()
    }

    fn finish_resident(self: Box<Self>) -> Result<Box<dyn ResidentVolume>> {
        let (h, w, _) = self.reference.dim();
        let dim = (h, w, self.bins.count);
        let Self { gpu, sums, counts, frames, .. } = *self;
        Ok(Box::new(GpuResident::from_sums(gpu, (sums, counts), dim, frames)?))
    }
}

/// `costvolume::check_shape`'s rule for a device map: `H x W` the camera's, at least one channel,
/// and the reference's channel count.
fn check_shape(
    what: &str,
    (h, w, c): (usize, usize, usize),
    camera: &PinholeCamera,
    channels: Option<usize>,
) -> Result<()> {
    let bad = |why: String| Err(Error::invalid_argument(what, format!("{why} (backend {NAME})")));
    if (h, w) != (camera.height, camera.width) {
        return bad(format!("{h}x{w} (HxW) but the camera is {}x{}", camera.height, camera.width));
    }
    if c == 0 {
        return bad("no channel".into());
    }
    match channels {
        Some(want) if c != want => bad(format!("{c} channels, the reference has {want}")),
        _ => Ok(()),
    }
}
