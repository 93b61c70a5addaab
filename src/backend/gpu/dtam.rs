//! DTAM's Huber-TV solve on the GPU (SPEC.md §10, §15.5): `dtam.wgsl`'s kernels over state that
//! stays on the device for the whole solve (`d`, `d̄`, `q`, `a`, the cost array, its per-pixel range
//! and the edge weights). The host uploads once, records iterations in batches, reads back only
//! each iteration's energy and gap (16 bytes) for the stopping rule, and downloads `d` and `a` once
//! at the end.
//!
//! An iteration records: a copy of its `θ` constants into the constant buffer, `steps_per_search`
//! × (`dual`, `primal`), `search` (the a-search and every pixel's energy and gap terms),
//! `row_sums` (per row, `x` ascending), `total` (rows in order; one invocation) and a copy of the
//! result into the energy log. Before the schedule ends (`n + 1 < N`) no iteration can stop the
//! solve, so those run in batches of [`SCHEDULE_BATCH`] without waiting; after it, batches of
//! [`TAIL_BATCH`] also copy `d` and `a` into a ring of [`TAIL_BATCH`] slots, and the host takes the
//! slot of the first iteration the stopping rule accepts (the iterations after it in the batch are
//! discarded).

use std::time::Instant;

use ndarray::{Array2, ArrayView2};

use super::{check_finite, f32s, f64s, record, GpuBackend};
use crate::costvolume::UNSEEN_COST;
use crate::dtam::huber_tv::STEP;
use crate::dtam::{edge_weights, DtamParams, DtamProblem, DtamReport, DtamResult, History};
use crate::error::Result;
use crate::geometry::InverseDepthBins;

const MODULE: &str = "dtam";
const SOURCE: &str = include_str!("dtam.wgsl");
/// Iterations recorded per submission while the θ schedule runs (nothing is read back in between).
const SCHEDULE_BATCH: usize = 32;
/// Iterations per submission after the schedule; also the number of `d`, `a` ring slots.
const TAIL_BATCH: usize = 8;
/// Index of the per-iteration constants in the constant buffer (`dtam.wgsl`'s header).
const ITERATION_CONSTANTS: usize = 8;
/// Constants per iteration: `θ, 2θ, 1/(1 + τ/θ), 1/(2θ)`.
const PER_ITERATION: usize = 4;

/// Where the time of a GPU solve went (for `densefeat bench tv --backend gpu`).
#[derive(Clone, Copy, Debug, Default)]
pub struct DtamTimings {
    /// Host preparation (edge weights, constants) and uploads, ending with the device idle.
    pub upload_s: f64,
    /// The iterations, including the energy read-backs of the stopping rule.
    pub iterate_s: f64,
    /// Downloading `d` and `a`.
    pub download_s: f64,
}

impl DtamTimings {
    /// The three parts' sum.
    pub fn total_s(&self) -> f64 {
        self.upload_s + self.iterate_s + self.download_s
    }
}

/// The device state of one solve.
struct State<'a> {
    gpu: &'a GpuBackend,
    pixels: usize,
    /// Constants (`c` in `dtam.wgsl`) and the per-iteration table copied into them.
    consts: wgpu::Buffer,
    table: wgpu::Buffer,
    /// `(energy, gap)` per iteration.
    log: wgpu::Buffer,
    measure: wgpu::Buffer,
    d: wgpu::Buffer,
    a: wgpu::Buffer,
    ring_d: wgpu::Buffer,
    ring_a: wgpu::Buffer,
    /// Pipelines with their bind groups, by kernel.
    dual: (wgpu::ComputePipeline, wgpu::BindGroup),
    primal: (wgpu::ComputePipeline, wgpu::BindGroup),
    search: (wgpu::ComputePipeline, wgpu::BindGroup),
    rows: (wgpu::ComputePipeline, wgpu::BindGroup),
    total: (wgpu::ComputePipeline, wgpu::BindGroup),
    h: usize,
    steps: usize,
}

/// [`crate::backend::Backend::dtam_solve`] on `gpu`.
///
/// # Errors
/// Bad parameters or shapes (as the CPU); no shader f64; non-finite costs or initial depth; buffers
/// over the adapter's binding limit; device errors.
pub(super) fn solve(gpu: &GpuBackend, problem: &DtamProblem) -> Result<(DtamResult, DtamReport)> {
    solve_timed(gpu, problem).map(|(r, report, _)| (r, report))
}

/// [`solve`] with the time of its parts.
///
/// # Errors
/// As [`solve`].
pub(super) fn solve_timed(
    gpu: &GpuBackend,
    problem: &DtamProblem,
) -> Result<(DtamResult, DtamReport, DtamTimings)> {
    problem.check()?;
    let start = Instant::now();
    let costs = problem.costs.as_standard_layout();
    let flat = costs.as_slice().expect("standard layout is contiguous");
    check_finite("dtam_solve", "cost", flat.iter().copied())?;
    gpu.check_size(flat.len())?;
    let cb = gpu.storage_init(flat);
    let (result, mut report, mut timings) = solve_on(gpu, problem, &cb, problem.costs.dim())?;
    // The host path's upload counts in its time.
    report.seconds = start.elapsed().as_secs_f64();
    timings.upload_s += report.seconds - timings.total_s();
    Ok((result, report, timings))
}

/// The solve on a device cost array `[H, W, K]` (`dim`; every cost finite; `problem.costs` is not
/// read): the resident volume's path (SPEC.md §15.6), and [`solve_timed`]'s after its upload.
///
/// # Errors
/// As [`solve`].
pub(super) fn solve_on<C>(
    gpu: &GpuBackend,
    problem: &DtamProblem<'_, C>,
    cb: &wgpu::Buffer,
    dim: (usize, usize, usize),
) -> Result<(DtamResult, DtamReport, DtamTimings)> {
    problem.check_costs(dim)?;
    if problem.slope.is_some() {
        return Err(super::unsupported(
            "the surface-normal prior (--regularizer normals) runs on the CPU only; use --backend cpu",
        ));
    }
    if problem.second_order.is_some() {
        return Err(super::unsupported("TGV (--regularizer tgv) runs on the CPU only; use --backend cpu"));
    }
    let DtamProblem { bins, grey, init, params, .. } = *problem;
    gpu.require_f64("dtam_solve", "the solver's per-pixel arithmetic is the CPU's f64")?;
    let start = Instant::now();
    let state = State::new(gpu, (cb, dim), bins, grey, init, params)?;
    gpu.wait()?;
    let uploaded = Instant::now();
    let mut history = History::new(params);
    let (mut n, mut last) = (0, 0);
    'batches: while n < params.max_iterations {
        let tail = n + 1 >= params.iterations;
        let size = if tail { TAIL_BATCH } else { SCHEDULE_BATCH.min(params.iterations - 1 - n) };
        let end = (n + size).min(params.max_iterations);
        state.run(n, end, tail);
        let log = f64s(&gpu.read_back(&state.log, 16 * n as u64, 16 * (end - n) as u64)?);
        for (it, m) in (n..end).zip(log.chunks_exact(2)) {
            last = it;
            if history.push(it, m[0], m[1], params, bins) {
                break 'batches;
            }
        }
        n = end;
    }
    let iterated = Instant::now();
    let slot = (last % TAIL_BATCH) as u64;
    let bytes = 4 * state.pixels as u64;
    let (h, w) = init.dim();
    let field = |b: &wgpu::Buffer| -> Result<Array2<f32>> {
        let v = f32s(&gpu.read_back(b, slot * bytes, bytes)?);
        Ok(Array2::from_shape_vec((h, w), v).expect("one value per pixel"))
    };
    let result = DtamResult { inverse_depth: field(&state.ring_d)?, auxiliary: field(&state.ring_a)? };
    let done = Instant::now();
    let timings = DtamTimings {
        upload_s: (uploaded - start).as_secs_f64(),
        iterate_s: (iterated - uploaded).as_secs_f64(),
        download_s: (done - iterated).as_secs_f64(),
    };
    Ok((result, history.report(start), timings))
}

impl<'a> State<'a> {
    fn new(
        gpu: &'a GpuBackend,
        (cb, (h, w, k)): (&wgpu::Buffer, (usize, usize, usize)),
        bins: &InverseDepthBins,
        grey: ArrayView2<f32>,
        init: ArrayView2<f32>,
        params: &DtamParams,
    ) -> Result<Self> {
        let pixels = h * w;
        check_finite("dtam_solve", "initial inverse depth", init.iter().copied())?;
        let pair_bytes = gpu.check_size(2 * pixels)?;
        let terms_bytes = gpu.check_size(8 * pixels)?; // 4 f64 per pixel
        let ring_bytes = gpu.check_size(TAIL_BATCH * pixels.max(1))?;
        let p = super::params([pixels, h, w, k, UNSEEN_COST.to_bits() as usize]);
        let mut c = vec![STEP, params.epsilon, 1.0 / (1.0 + STEP * params.epsilon), params.lambda];
        c.extend([bins.rho_min, bins.step(), (k - 1) as f64, 1.0 / params.lambda, 0.0, 0.0, 0.0, 0.0]);
        c.extend(bins.values());
        let table: Vec<f64> = (0..params.max_iterations)
            .flat_map(|n| {
                let theta = params.theta(n);
                [theta, 2.0 * theta, 1.0 / (1.0 + STEP / theta), 1.0 / (2.0 * theta)]
            })
            .collect();
        let init = init.as_standard_layout();
        let init = init.as_slice().expect("standard layout is contiguous");
        let g = edge_weights(grey, params.alpha, params.beta);
        let g = g.as_slice().expect("owned arrays are contiguous");
        let bytes = |v: &[f64]| gpu.storage_bytes(bytemuck::cast_slice(v));
        let (pb, consts, table) = (gpu.storage_bytes(bytemuck::cast_slice(&p)), bytes(&c), bytes(&table));
        let range = gpu.storage_zeroed(pair_bytes)?;
        let (d, d_bar, a) = (gpu.storage_init(init), gpu.storage_init(init), gpu.storage_init(init));
        let gb = gpu.storage_init(g);
        let q = gpu.storage_zeroed(pair_bytes)?;
        let terms = gpu.storage_zeroed(terms_bytes)?;
        let rows = gpu.storage_zeroed(32 * h as u64)?;
        let measure = gpu.storage_zeroed(16)?;
        let log = gpu.storage_zeroed(16 * params.max_iterations as u64)?;
        let (ring_d, ring_a) = (gpu.storage_zeroed(ring_bytes)?, gpu.storage_zeroed(ring_bytes)?);
        let kernel = |entry: &'static str, bindings: &[(u32, &wgpu::Buffer)]| -> Result<_> {
            let pipeline = gpu.pipeline_entry(MODULE, entry, || SOURCE.to_string())?;
            let group = gpu.bind(&pipeline, bindings);
            Ok((pipeline, group))
        };
        let range_kernel = kernel("cost_range", &[(0, &pb), (2, cb), (3, &range)])?;
        let state = Self {
            dual: kernel("dual", &[(0, &pb), (1, &consts), (5, &d_bar), (6, &gb), (7, &q)])?,
            primal: kernel(
                "primal",
                &[(0, &pb), (1, &consts), (4, &d), (5, &d_bar), (6, &gb), (7, &q), (8, &a)],
            )?,
            search: kernel(
                "search",
                &[(0, &pb), (1, &consts), (2, cb), (3, &range), (4, &d), (6, &gb), (8, &a), (9, &terms)],
            )?,
            rows: kernel("row_sums", &[(0, &pb), (9, &terms), (10, &rows)])?,
            total: kernel("total", &[(0, &pb), (10, &rows), (11, &measure)])?,
            gpu,
            pixels,
            consts,
            table,
            log,
            measure,
            d,
            a,
            ring_d,
            ring_a,
            h,
            steps: params.steps_per_search,
        };
        let mut encoder = gpu.device.create_command_encoder(&Default::default());
        {
            let mut pass = encoder.begin_compute_pass(&Default::default());
            record(&mut pass, &range_kernel.0, &range_kernel.1, p[0]);
        }
        gpu.queue.submit([encoder.finish()]);
        Ok(state)
    }

    /// Records and submits iterations `n0..n1`; `keep`: copy each iteration's `d` and `a` into the
    /// ring.
    fn run(&self, n0: usize, n1: usize, keep: bool) {
        let f64_bytes = 8;
        let per = (PER_ITERATION * f64_bytes) as u64;
        let bytes = 4 * self.pixels as u64;
        let pixels = self.pixels as u32;
        let mut encoder = self.gpu.device.create_command_encoder(&Default::default());
        for it in n0..n1 {
            let dst = (ITERATION_CONSTANTS * f64_bytes) as u64;
            encoder.copy_buffer_to_buffer(&self.table, it as u64 * per, &self.consts, dst, per);
            {
                let mut pass = encoder.begin_compute_pass(&Default::default());
                for _ in 0..self.steps {
                    record(&mut pass, &self.dual.0, &self.dual.1, pixels);
                    record(&mut pass, &self.primal.0, &self.primal.1, pixels);
                }
                record(&mut pass, &self.search.0, &self.search.1, pixels);
                record(&mut pass, &self.rows.0, &self.rows.1, self.h as u32);
                record(&mut pass, &self.total.0, &self.total.1, 1);
            }
            encoder.copy_buffer_to_buffer(&self.measure, 0, &self.log, 16 * it as u64, 16);
            if keep && bytes > 0 {
                let slot = (it % TAIL_BATCH) as u64 * bytes;
                encoder.copy_buffer_to_buffer(&self.d, 0, &self.ring_d, slot, bytes);
                encoder.copy_buffer_to_buffer(&self.a, 0, &self.ring_a, slot, bytes);
            }
        }
        self.gpu.queue.submit([encoder.finish()]);
    }
}
