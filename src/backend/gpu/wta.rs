//! Winner-take-all on the GPU (SPEC.md §9.5, §15.5): `wta.wgsl`, one invocation per pixel, the
//! CPU's comparisons (`f32`) and parabola (`f64`), so the result is the CPU's bit for bit on a device
//! with correctly rounded `f64` arithmetic.

use ndarray::{Array2, ArrayView3};

use super::{check_finite, f32s, record, GpuBackend};
use crate::costvolume::{WtaDepth, UNSEEN_COST};
use crate::error::Result;
use crate::geometry::InverseDepthBins;

const MODULE: &str = "wta";
const SOURCE: &str = include_str!("wta.wgsl");

/// [`crate::backend::Backend::winner_take_all`] on `gpu`: uploads the cost array, then
/// [`winner_take_all_on`].
///
/// # Errors
/// No shader f64; a non-finite cost; a cost array over the adapter's binding limit; device errors.
pub(super) fn winner_take_all(
    gpu: &GpuBackend,
    costs: ArrayView3<f32>,
    bins: &InverseDepthBins,
) -> Result<WtaDepth> {
    gpu.require_f64("winner_take_all", "the parabola refinement is the CPU's f64 arithmetic")?;
    crate::backend::resident::check_bins(costs.dim(), bins)?;
    let (h, w, k) = costs.dim();
    let costs = costs.as_standard_layout();
    let flat = costs.as_slice().expect("standard layout is contiguous");
    check_finite("winner_take_all", "cost", flat.iter().copied())?;
    gpu.check_size(flat.len())?;
    winner_take_all_on(gpu, &gpu.storage_init(flat), (h, w, k), bins)
}

/// Winner-take-all on a device cost array `[H, W, K]` (`dim`; every cost finite): downloads only
/// the `[H, W, 4]` results (the resident volume's path, SPEC.md §15.6).
///
/// # Errors
/// No shader f64; device errors.
pub(super) fn winner_take_all_on(
    gpu: &GpuBackend,
    cb: &wgpu::Buffer,
    (h, w, k): (usize, usize, usize),
    bins: &InverseDepthBins,
) -> Result<WtaDepth> {
    gpu.require_f64("winner_take_all", "the parabola refinement is the CPU's f64 arithmetic")?;
    let out_bytes = gpu.check_size(h * w * 4)?;
    let pixels = h * w;
    let p = super::params([pixels, k, UNSEEN_COST.to_bits() as usize]);
    let mut g = vec![bins.rho_min, bins.step()];
    g.extend(bins.values());
    let (pb, gb) = (gpu.storage_bytes(bytemuck::cast_slice(&p)), gpu.storage_bytes(bytemuck::cast_slice(&g)));
    let ob = gpu.storage_zeroed(out_bytes)?;
    let pipeline = gpu.pipeline_entry(MODULE, "wta", || SOURCE.to_string())?;
    let group = gpu.bind(&pipeline, &[(0, &pb), (1, &gb), (2, cb), (3, &ob)]);
    let mut encoder = gpu.device.create_command_encoder(&Default::default());
    {
        let mut pass = encoder.begin_compute_pass(&Default::default());
        record(&mut pass, &pipeline, &group, p[0]);
    }
    gpu.queue.submit([encoder.finish()]);
    let out = f32s(&gpu.read_back(&ob, 0, out_bytes)?);
    let field = |j: usize| Array2::from_shape_fn((h, w), |(y, x)| out[4 * (y * w + x) + j]);
    Ok(WtaDepth {
        valid: field(0).mapv(|v| v != 0.0),
        inverse_depth: field(1),
        depth: field(2),
        bin: field(3),
    })
}
