//! `densefeat bench tv --backend gpu`: the DTAM solve on the wgpu backend (SPEC.md §12.2, §15.5),
//! with the uploads (cost array, edge weights, initial depth, constants), the iterations (including
//! the energy read-backs of the stopping rule) and the download of `d` and `a` timed separately.

use super::bench_tv::{median_ms, BenchTvArgs};
use densefeat::backend::{Backend, GpuBackend};
use densefeat::dtam::{DtamParams, DtamProblem};
use densefeat::error::Result;
use densefeat::perf::{tv_inputs, TvInputs};

/// Solves timed per part, after one warm-up solve (pipeline compilation).
const REPEATS: usize = 3;

/// Runs the GPU benchmark and prints it.
///
/// # Errors
/// No GPU adapter; device errors.
pub(super) fn run(args: &BenchTvArgs, width: usize, height: usize) -> Result<()> {
    let gpu = GpuBackend::shared()?;
    let inputs = tv_inputs(width, height, args.bins)?;
    let params = super::bench_tv::schedule_params(&args.schedule, &inputs);
    let TvInputs { costs, bins, grey, init } = inputs;
    // A fixed number of iterations: a schedule as long as the cap, so nothing stops early.
    let fixed = DtamParams { iterations: args.runs, max_iterations: args.runs, ..params };
    let warm = DtamParams { iterations: 2, max_iterations: 2, ..fixed };
    gpu.dtam_solve_timed(&DtamProblem::new(costs.view(), &bins, grey.view(), init.view(), &warm))?;
    let (mut upload, mut iteration, mut download) = (vec![], vec![], vec![]);
    for _ in 0..REPEATS {
        let (_, report, t) =
            gpu.dtam_solve_timed(&DtamProblem::new(costs.view(), &bins, grey.view(), init.view(), &fixed))?;
        upload.push(t.upload_s);
        iteration.push(t.iterate_s / report.iterations.max(1) as f64);
        download.push(t.download_s);
    }
    let (mut solves, mut iterations) = (vec![], 0);
    for _ in 0..REPEATS {
        let (_, report, t) =
            gpu.dtam_solve_timed(&DtamProblem::new(costs.view(), &bins, grey.view(), init.view(), &params))?;
        solves.push(t.upload_s + t.iterate_s + t.download_s);
        iterations = report.iterations;
    }
    let it_ms = median_ms(iteration);
    let cells = (width * height * args.bins) as f64;
    println!(
        "dtam {width}x{height}, K={}, {}: one iteration median {it_ms:.2} ms ({} iterations per solve, \
         {REPEATS} solves; {:.1} M cost cells per second); upload {:.2} ms, download {:.2} ms per solve",
        args.bins,
        gpu.device(),
        args.runs,
        cells / it_ms * 1e-3,
        median_ms(upload),
        median_ms(download),
    );
    let solve_ms = median_ms(solves);
    println!(
        "  full solve, {} schedule ({} iterations scheduled, {iterations} run): median {solve_ms:.1} ms \
         over {REPEATS} solves ({:.2} ms per iteration run, uploads and download included)",
        args.schedule,
        params.iterations,
        solve_ms / iterations.max(1) as f64
    );
    if gpu.device().contains("(Cpu,") {
        println!(
            "  note: this adapter is a software (CPU) implementation of the GPU API: these times say \
             nothing about a GPU; the command only shows that the path runs"
        );
    }
    Ok(())
}
