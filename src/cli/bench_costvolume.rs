//! `densefeat bench costvolume`: time [`CostVolume::add_frame`] on random features and a realistic
//! pose, and print the median milliseconds per added frame and hypotheses per second.

use std::time::Instant;

use std::sync::Arc;

use clap::Args;

use super::synth::parse_size;
use densefeat::backend::{Backend, CpuBackend};
use densefeat::costvolume::{fast_kernel_name, CostVolume, CostVolumeImpl, UNSEEN_COST};
use densefeat::error::{Error, Result};

use densefeat::io::{write_atomic, write_npy_f32};

/// Arguments of `densefeat bench costvolume`.
#[derive(Debug, Clone, Args)]
pub struct BenchCostvolumeArgs {
    /// Feature-map size as WIDTHxHEIGHT.
    #[arg(long, default_value = "320x240")]
    pub size: String,
    /// Number of inverse-depth hypotheses K.
    #[arg(long, default_value_t = 64)]
    pub bins: usize,
    /// Feature channels C (RGB = 3, learned = 32).
    #[arg(long, default_value_t = 32)]
    pub channels: usize,
    /// Worker threads (rayon pool size).
    #[arg(long, default_value_t = 2)]
    pub threads: usize,
    /// Timed runs (at least 10) after two warm-up runs.
    #[arg(long, default_value_t = 10)]
    pub runs: usize,
    /// Time the single-threaded reference instead of the fast kernel.
    #[arg(long)]
    pub reference: bool,
    /// Also write the inputs and one frame's volume to this folder for an external check
    /// (`benches/compare/`): `ref.npy`, `live.npy` `[H, W, C]`; `costs.npy`, `counts.npy`,
    /// `magnitude.npy` `[H, W, K]` (f32; unseen costs are `UNSEEN_COST`; magnitude is SPEC.md §9.6's
    /// `M̄`); `meta.json` (camera, `T_nr`, hypotheses, kernel, timing).
    #[arg(long)]
    pub dump: Option<std::path::PathBuf>,
    /// Memory limit.
    #[command(flatten)]
    pub memory: super::validate::MemoryLimit,
    /// Where the volume is built (`--reference` overrides it with the CPU reference).
    #[command(flatten)]
    pub backend: super::backend_flag::BackendFlag,
}

/// Run the benchmark and print the result.
///
/// # Errors
/// [`Error::InvalidArgument`] for bad arguments.
pub fn run(args: BenchCostvolumeArgs) -> Result<()> {
    let backend: Arc<dyn Backend> =
        if args.reference { Arc::new(CpuBackend::reference()) } else { args.backend.resolve()? };
    let (width, height) = parse_size(&args.size)?;
    let bytes = densefeat::memory::cost_volume_bytes(height, width, args.bins, args.channels);
    let what = format!("the {height}x{width}x{} volume with {} channels", args.bins, args.channels);
    args.memory.check(&what, bytes, "use a smaller --size, fewer --bins or --channels")?;
    if args.runs < 10 {
        return Err(Error::invalid_argument("--runs", format!("{}: must be at least 10", args.runs)));
    }
    if args.threads == 0 {
        return Err(Error::invalid_argument("--threads", "0: must be at least 1"));
    }
    let densefeat::perf::BenchInputs { reference, live, camera: cam, bins, t_nr } =
        densefeat::perf::bench_inputs(width, height, args.channels, args.bins)?;
    let pool = densefeat::runtime::thread_pool(args.threads)?;
    // Uploads are explicit and outside the timed loop (SPEC.md §15.2); timed on their own.
    let t = Instant::now();
    let reference = backend.upload_owned(reference)?;
    let live = backend.upload_owned(live)?;
    backend.synchronize()?;
    let upload = t.elapsed().as_secs_f64();
    // Untruncated (SPEC.md §9.13): the truncation is one `min` per hypothesis block either way.
    let mut cv = backend.cost_volume(&reference, cam, bins, densefeat::costvolume::NO_TRUNCATION)?;
    let mut times = Vec::with_capacity(args.runs);
    let mut cpu_start = None;
    pool.install(|| -> Result<()> {
        for run in 0..args.runs + 2 {
            if run == 2 {
                cpu_start = densefeat::perf::process_cpu_seconds();
            }
            let start = Instant::now();
            cv.add_frame(&live, &t_nr)?;
            // A device backend only submits: the clock stops when the frame is done.
            backend.synchronize()?;
            if run >= 2 {
                times.push(start.elapsed().as_secs_f64());
            }
        }
        Ok(())
    })?;
    let t = Instant::now();
    let cv = cv.finish()?;
    let download = t.elapsed().as_secs_f64();
    let cpu = cpu_start.zip(densefeat::perf::process_cpu_seconds()).map(|(a, b)| (b - a) / args.runs as f64);
    let total: f64 = times.iter().sum::<f64>() / args.runs as f64;
    times.sort_by(f64::total_cmp);
    let median = times[times.len() / 2];
    let hyps = (width * height * args.bins) as f64;
    let seen = cv.counts().iter().filter(|&&n| n > 0).count() as f64 / hyps;
    let kernel = match (args.reference, backend.name()) {
        (true, _) => "reference".to_string(),
        (false, "cpu") => fast_kernel_name().to_string(),
        (false, _) => backend.device(),
    };
    println!(
        "cost volume {width}x{height}, K={}, C={}, {} thread(s), {kernel}: median {:.2} ms per added frame \
         over {} runs (min {:.2}, max {:.2}), {:.1} M hypotheses/s, {:.1}% of cells in view",
        args.bins,
        args.channels,
        args.threads,
        median * 1e3,
        times.len(),
        times[0] * 1e3,
        times[times.len() - 1] * 1e3,
        hyps / median / 1e6,
        seen * 100.0
    );
    println!(
        "  upload (reference and one live frame, {} MB) {:.2} ms; finish (volume to the host: sums and \
         counts, {} MB) {:.2} ms",
        2 * width * height * args.channels * 4 / 1_000_000,
        upload * 1e3,
        hyps as usize * 6 / 1_000_000,
        download * 1e3
    );
    if backend.device().contains("(Cpu,") {
        println!(
            "  note: {} is a software (CPU) implementation of the GPU API: these times say nothing about \
             a GPU; the command only shows that the path runs",
            backend.device()
        );
    }
    if let Some(dir) = &args.dump {
        let mut staging = densefeat::io::Staging::new();
        let staged = staging.dir(dir)?;
        dump(
            &staged,
            &densefeat::perf::bench_inputs(width, height, args.channels, args.bins)?,
            &kernel,
            args.threads,
            median,
        )?;
        staging.commit()?;
        println!("  inputs and one frame's volume written to {}", dir.display());
    }
    if let Some(cpu) = cpu {
        // On a shared machine the wall time includes waiting for a core; CPU time does not.
        println!(
            "  CPU time {:.2} ms per frame (all threads; {:.0}% of {} core(s) while timed); \
             CPU time / threads = {:.2} ms",
            cpu * 1e3,
            100.0 * cpu / (total * args.threads as f64),
            args.threads,
            cpu * 1e3 / args.threads as f64
        );
    }
    Ok(())
}

/// Write the bench inputs, one frame's volume (the fast kernel), its counts and the magnitude `M̄`
/// (the reference on `|f_r|`, `-|f_n|`, SPEC.md §9.6) and `meta.json` to `dir` (created).
fn dump(
    dir: &std::path::Path,
    inputs: &densefeat::perf::BenchInputs,
    kernel: &str,
    threads: usize,
    median_s: f64,
) -> Result<()> {
    std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    let densefeat::perf::BenchInputs { reference, live, camera, bins, t_nr } = inputs;
    let mut cv = CostVolume::new(reference.clone(), *camera, *bins)?;
    cv.add_frame(live.view(), t_nr)?;
    let mut mag = CostVolume::with_impl(reference.mapv(f32::abs), *camera, *bins, CostVolumeImpl::Reference)?;
    mag.add_frame(live.mapv(|v| -v.abs()).view(), t_nr)?;
    write_npy_f32(&dir.join("ref.npy"), reference.view())?;
    write_npy_f32(&dir.join("live.npy"), live.view())?;
    write_npy_f32(&dir.join("costs.npy"), cv.costs().view())?;
    write_npy_f32(&dir.join("counts.npy"), cv.counts().mapv(f32::from).view())?;
    write_npy_f32(&dir.join("magnitude.npy"), mag.costs().view())?;
    let m = t_nr.to_homogeneous();
    let meta = serde_json::json!({
        "width": camera.width, "height": camera.height, "channels": reference.dim().2,
        "fx": camera.fx, "fy": camera.fy, "cx": camera.cx, "cy": camera.cy,
        "T_nr": (0..4).map(|r| (0..4).map(|c| m[(r, c)]).collect::<Vec<f64>>()).collect::<Vec<_>>(),
        "rhos": bins.values(), "unseen_cost": UNSEEN_COST, "kernel": kernel, "threads": threads,
        "median_ms_per_frame": median_s * 1e3,
    });
    write_atomic(&dir.join("meta.json"), meta.to_string().as_bytes())
}
