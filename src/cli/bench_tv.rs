//! `densefeat bench tv`: time the DTAM Huber-TV solver (SPEC.md §10, §12.2; `--tgv-beta B`: TGV,
//! §10.4) on a synthetic cost volume: one iteration (median, with its parts: the primal-dual step and the fused a-search with
//! the energy and gap, plus the a-search alone for scale), the same iteration in the unfused
//! reference formulation, and a full solve (`--schedule mapping`: the pipeline's normalised
//! defaults; `raw`: [`DtamParams::default`]).

use std::time::Instant;

use clap::Args;

use super::synth::parse_size;
use densefeat::dtam::{
    exhaustive_search, exhaustive_search_reference, rms_gap, search_with_energy, solve, total_energy,
    CostRange, DtamParams, DtamProblem, HuberTv,
};
use densefeat::error::{Error, Result};
use densefeat::perf::{tv_inputs, TvInputs};
use densefeat::runtime::CpuFeatureLevel;

/// Arguments of `densefeat bench tv`.
#[derive(Debug, Clone, Args)]
pub struct BenchTvArgs {
    /// Cost-volume size WIDTHxHEIGHT.
    #[arg(long, default_value = "320x240")]
    pub size: String,
    /// Number of inverse-depth hypotheses K.
    #[arg(long, default_value_t = 64)]
    pub bins: usize,
    /// Worker threads (rayon pool size).
    #[arg(long, default_value_t = 2)]
    pub threads: usize,
    /// Timed iterations (at least 5) after two warm-up iterations; the full solve runs 3 times.
    #[arg(long, default_value_t = 20)]
    pub runs: usize,
    /// Memory limit.
    #[command(flatten)]
    pub memory: super::validate::MemoryLimit,
    /// Where the solver runs (`gpu`: uploads, iterations and download timed separately).
    #[command(flatten)]
    pub backend: super::backend_flag::BackendFlag,
    /// DTAM parameters: `mapping` (what `reconstruct`, `eval` and `map` run: `dtam::MAPPING_DEFAULTS`
    /// normalised with the volume's cost scale, hypothesis range and width, SPEC.md §10.1) or `raw`
    /// (`DtamParams::default()`, the solver's own defaults, §10).
    #[arg(long, default_value = "mapping", value_parser = ["mapping", "raw"])]
    pub schedule: String,
    /// Time second-order TGV (SPEC.md §10.4) with this β (pixels at 640 px width) instead of
    /// Huber-TV; CPU only.
    #[arg(long)]
    pub tgv_beta: Option<f64>,
}

/// The DTAM parameters `--schedule` names, for this volume.
pub(super) fn schedule_params(schedule: &str, inputs: &TvInputs) -> DtamParams {
    if schedule == "raw" {
        return DtamParams::default();
    }
    let scale = densefeat::costvolume::cost_scale(inputs.costs.view());
    let (_, w, _) = inputs.costs.dim();
    densefeat::dtam::MAPPING_DEFAULTS.normalised(scale, w, inputs.bins.rho_max - inputs.bins.rho_min)
}

pub(super) fn median_ms(mut v: Vec<f64>) -> f64 {
    densefeat::runtime::median(&mut v) * 1e3
}

/// Runs the benchmark and prints one iteration's parts and a full solve.
///
/// # Errors
/// [`Error::InvalidArgument`] for bad arguments.
pub fn run(args: &BenchTvArgs) -> Result<()> {
    let (width, height) = parse_size(&args.size)?;
    // The costs (f32), their pruning range and about 16 f32 DTAM arrays per pixel.
    let bytes = densefeat::memory::product(&[
        height as u64,
        width as u64,
        (args.bins as u64).saturating_mul(8).saturating_add(64),
    ]);
    let what = format!("the {height}x{width}x{} TV problem", args.bins);
    args.memory.check(&what, bytes, "use a smaller --size or fewer --bins")?;
    if args.runs < 5 {
        return Err(Error::invalid_argument("--runs", format!("{}: must be at least 5", args.runs)));
    }
    if let Some(b) = args.tgv_beta {
        densefeat::dtam::tgv::check_beta(b)?;
    }
    if args.backend.resolve()?.name() != "cpu" {
        if args.tgv_beta.is_some() {
            return Err(Error::invalid_argument("--tgv-beta", "TGV runs on the CPU only: use --backend cpu"));
        }
        return device(args, width, height);
    }
    let second_order = args.tgv_beta.map(|b| densefeat::dtam::tgv::normalised_beta(b, width));
    let state = |init: &ndarray::Array2<f32>, g: &ndarray::Array2<f32>, eps: f64| match second_order {
        Some(b) => HuberTv::with_second_order(init.clone(), g.clone(), eps, b),
        None => HuberTv::new(init.clone(), g.clone(), eps),
    };
    let pool = super::bench::pool(args.threads)?;
    let inputs = tv_inputs(width, height, args.bins)?;
    let params = schedule_params(&args.schedule, &inputs);
    let TvInputs { costs, bins, grey, init } = inputs;
    let lambda = params.lambda;
    let (mut step, mut fused, mut search, mut iter) = (vec![], vec![], vec![], vec![]);
    let (mut ref_step, mut ref_search, mut ref_energy, mut ref_iter) = (vec![], vec![], vec![], vec![]);
    let (mut solves, mut solve_iterations) = (vec![], 0);
    pool.install(|| -> Result<()> {
        let g = densefeat::dtam::edge_weights(grey.view(), params.alpha, params.beta);
        let range = CostRange::new(costs.view());
        // Iterations at θ_start: the widest pruned search, the slowest iteration of a solve.
        let theta = params.theta_start;
        let mut tv = state(&init, &g, params.epsilon);
        let mut a = init.clone();
        for run in 0..args.runs + 2 {
            let t0 = Instant::now();
            tv.step(a.view(), theta);
            let t1 = Instant::now();
            let m = search_with_energy(
                costs.view(),
                &range,
                &bins,
                &tv,
                theta,
                lambda,
                &mut a,
                CpuFeatureLevel::get(),
            );
            let t2 = Instant::now();
            std::hint::black_box(m);
            std::hint::black_box(exhaustive_search(costs.view(), &range, &bins, tv.primal(), theta, lambda));
            let t3 = Instant::now();
            if run >= 2 {
                step.push((t1 - t0).as_secs_f64());
                fused.push((t2 - t1).as_secs_f64());
                search.push((t3 - t2).as_secs_f64());
                iter.push((t2 - t0).as_secs_f64());
            }
        }
        // The same iterations in the unfused reference formulation (`dtam::solve_reference`).
        let mut tv = state(&init, &g, params.epsilon);
        let mut a = init.clone();
        for run in 0..args.runs + 2 {
            let t0 = Instant::now();
            tv.step_reference(a.view(), theta);
            let t1 = Instant::now();
            a = exhaustive_search_reference(costs.view(), &range, &bins, tv.primal(), theta, lambda);
            let t2 = Instant::now();
            std::hint::black_box(total_energy(&tv, costs.view(), &bins, a.view(), theta, lambda));
            std::hint::black_box(rms_gap(tv.primal(), a.view()));
            let t3 = Instant::now();
            if run >= 2 {
                ref_step.push((t1 - t0).as_secs_f64());
                ref_search.push((t2 - t1).as_secs_f64());
                ref_energy.push((t3 - t2).as_secs_f64());
                ref_iter.push((t3 - t0).as_secs_f64());
            }
        }
        for _ in 0..3 {
            let t = Instant::now();
            let problem = DtamProblem::new(costs.view(), &bins, grey.view(), init.view(), &params);
            let problem = DtamProblem { second_order, ..problem };
            let (_, report) = std::hint::black_box(solve(&problem)?);
            solves.push(t.elapsed().as_secs_f64());
            solve_iterations = report.iterations;
        }
        Ok(())
    })?;
    let solve_ms = median_ms(solves);
    let what = match args.tgv_beta {
        Some(b) => format!("dtam with TGV (β {b} at 640 px)"),
        None => "dtam".to_string(),
    };
    println!(
        "{what} {width}x{height}, K={}, {} thread(s): one iteration (θ = θ_start) median {:.2} ms \
         = primal-dual step {:.2} + a-search with energy and gap {:.2} ms (a-search alone {:.2} ms; \
         {} runs)",
        args.bins,
        args.threads,
        median_ms(iter),
        median_ms(step),
        median_ms(fused),
        median_ms(search),
        args.runs
    );
    println!(
        "  unfused reference iteration (solve_reference): median {:.2} ms = primal-dual step {:.2} \
         + a-search {:.2} + energy and gap {:.2} ms",
        median_ms(ref_iter),
        median_ms(ref_step),
        median_ms(ref_search),
        median_ms(ref_energy),
    );
    println!(
        "  full solve, {} schedule ({} iterations scheduled, {} primal-dual steps each, {solve_iterations} \
         run): median {solve_ms:.1} ms over 3 solves ({:.2} ms per scheduled iteration, {:.2} per \
         iteration run)",
        args.schedule,
        params.iterations,
        params.steps_per_search,
        solve_ms / params.iterations as f64,
        solve_ms / solve_iterations.max(1) as f64
    );
    Ok(())
}

#[cfg(feature = "gpu")]
fn device(args: &BenchTvArgs, width: usize, height: usize) -> Result<()> {
    super::bench_tv_gpu::run(args, width, height)
}

#[cfg(not(feature = "gpu"))]
fn device(args: &BenchTvArgs, _: usize, _: usize) -> Result<()> {
    Err(Error::Unsupported {
        backend: args.backend.name.clone(),
        what: "bench tv: no device backend in this build".into(),
    })
}
