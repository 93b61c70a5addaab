//! `densefeat bench`: timing of the feature network's forward pass, the machine's SGEMM peak, the
//! cost volume, the DTAM solver and the depth refinement, each inside a rayon pool of `--threads` threads.

use std::time::Instant;

use clap::{Args, Subcommand};

use crate::cli::synth::parse_size;
use densefeat::error::{Error, Result};
use densefeat::nn::{FeatureNet, NetworkWeights};
use densefeat::ops::NetworkConfig;

/// Arguments of `densefeat bench`.
#[derive(Debug, Clone, Args)]
pub struct BenchArgs {
    /// What to time.
    #[command(subcommand)]
    pub what: BenchCommand,
}

/// Bench subcommands.
#[derive(Debug, Clone, Subcommand)]
pub enum BenchCommand {
    /// Median time of the network's forward pass (Xavier weights, a synthetic pattern image).
    Forward(ForwardArgs),
    /// SGEMM throughput (matrixmultiply, parallel over row blocks): the machine's practical peak.
    Gemm(GemmArgs),
    /// Time adding one live frame to a cost volume (median ms per frame, hypotheses per second).
    Costvolume(super::bench_costvolume::BenchCostvolumeArgs),
    /// Time the DTAM Huber-TV solver: one iteration (with its parts) and a full default solve.
    Tv(super::bench_tv::BenchTvArgs),
    /// Time the photometric sub-bin refinement of one keyframe (SPEC.md §10.3) on a synthetic plane.
    Refine(super::bench_refine::BenchRefineArgs),
    /// Time one training step (forward, deeply supervised loss, backward) on a synthetic pair.
    Train(super::train::BenchTrainArgs),
}

/// Arguments of `densefeat bench forward`.
#[derive(Debug, Clone, Args)]
pub struct ForwardArgs {
    /// Image size WIDTHxHEIGHT.
    #[arg(long, default_value = "320x240")]
    pub size: String,
    /// Stride of block 1 (1 or 2).
    #[arg(long, default_value_t = 2)]
    pub b1_stride: usize,
    /// Rayon threads.
    #[arg(long, default_value_t = 1)]
    pub threads: usize,
    /// Timed runs (at least 20), after two warm-up runs.
    #[arg(long, default_value_t = 20)]
    pub runs: usize,
    /// Size of the GEMM used to measure the peak.
    #[arg(long, default_value_t = 1024)]
    pub gemm_size: usize,
    /// Also print where the time goes: mean ms and GFLOP/s per kind of operation.
    #[arg(long)]
    pub profile: bool,
    /// Memory limit.
    #[command(flatten)]
    pub memory: super::validate::MemoryLimit,
    /// Where the network runs.
    #[command(flatten)]
    pub backend: super::backend_flag::BackendFlag,
}

/// Arguments of `densefeat bench gemm`.
#[derive(Debug, Clone, Args)]
pub struct GemmArgs {
    /// Side of the square matrices.
    #[arg(long, default_value_t = 1024)]
    pub size: usize,
    /// Rayon threads.
    #[arg(long, default_value_t = 1)]
    pub threads: usize,
    /// Timed runs, after one warm-up run.
    #[arg(long, default_value_t = 10)]
    pub runs: usize,
    /// Memory limit.
    #[command(flatten)]
    pub memory: super::validate::MemoryLimit,
}

/// Warm-up runs before timing.
const WARMUP: usize = 2;
/// Fewest timed forward runs.
const MIN_RUNS: usize = 20;

pub(crate) use densefeat::runtime::thread_pool as pool;

pub(crate) fn median(mut v: Vec<f64>) -> f64 {
    densefeat::runtime::median(&mut v)
}

fn run_forward(args: &ForwardArgs) -> Result<()> {
    let backend = args.backend.resolve()?;
    let backend = backend.as_ref();
    let (w, h) = parse_size(&args.size)?;
    let gemm = densefeat::memory::product(&[3, args.gemm_size as u64, args.gemm_size as u64, 4]);
    let net =
        densefeat::memory::network_forward_bytes(h, w, NetworkConfig::default().channels, args.b1_stride);
    let what = format!("the network on {w}x{h} and a {} GEMM", args.gemm_size);
    args.memory.check(&what, net.max(gemm), "use a smaller --size or --gemm-size")?;
    if args.runs < MIN_RUNS {
        return Err(Error::invalid_argument("--runs", format!("{} is below {MIN_RUNS}", args.runs)));
    }
    let config =
        NetworkConfig { b1_stride: args.b1_stride, input_mean: [128.0; 3], ..NetworkConfig::default() };
    let net = FeatureNet::new(NetworkWeights::xavier_uniform(&config, 0)?)?;
    let image = densefeat::perf::pattern(h, w);
    let pool = pool(args.threads)?;
    let (ms, peak) = pool.install(|| -> Result<(f64, f64)> {
        for _ in 0..WARMUP {
            net.features(image.view(), backend)?;
        }
        let mut times = Vec::with_capacity(args.runs);
        for _ in 0..args.runs {
            let start = Instant::now();
            std::hint::black_box(net.features(image.view(), backend)?);
            times.push(start.elapsed().as_secs_f64() * 1e3);
        }
        Ok((median(times), densefeat::perf::gemm_gflops(args.gemm_size, 10)))
    })?;
    let gflop = net.flops(h, w) / 1e9;
    let gflops = gflop / (ms / 1e3);
    println!(
        "| size | b1 stride | threads | runs | median ms | GFLOP | GFLOP/s | SGEMM peak GFLOP/s | of peak |"
    );
    println!("|---|---|---|---|---|---|---|---|---|");
    println!(
        "| {w}x{h} | {} | {} | {} | {ms:.2} | {gflop:.3} | {gflops:.1} | {peak:.1} | {:.0} % |",
        args.b1_stride,
        args.threads,
        args.runs,
        100.0 * gflops / peak
    );
    if backend.name() == "cpu" {
        let kinds = densefeat::backend::CpuBackend::default().network_kernels(&config, h, w)?;
        let list: Vec<String> = kinds.iter().map(|(kind, imp)| format!("{kind}: {imp}")).collect();
        println!("\nkernels (cpu backend, this CPU): {}", list.join("; "));
    }
    if args.profile {
        let (rows, total) =
            pool.install(|| densefeat::nn::profile_forward(&net, backend, image.view(), args.runs))?;
        println!("\nprofile (mean per forward pass, {} passes):", args.runs);
        println!("| operation | calls | ms | share | GFLOP/s |");
        println!("|---|---|---|---|---|");
        let mut accounted = 0.0;
        for (op, t) in &rows {
            accounted += t.ms;
            let rate =
                if t.flops > 0.0 { format!("{:.1}", t.flops / 1e9 / (t.ms / 1e3)) } else { "-".into() };
            println!("| {op} | {} | {:.2} | {:.0} % | {rate} |", t.calls, t.ms, 100.0 * t.ms / total);
        }
        let rest = total - accounted;
        println!("| pad, mean, image pyramid | - | {rest:.2} | {:.0} % | - |", 100.0 * rest / total);
        println!("| total | - | {total:.2} | 100 % | {:.1} |", gflop / (total / 1e3));
    }
    Ok(())
}

fn run_gemm(args: &GemmArgs) -> Result<()> {
    if args.size == 0 {
        return Err(Error::invalid_argument("--size", "must be at least 1"));
    }
    let bytes = densefeat::memory::product(&[3, args.size as u64, args.size as u64, 4]);
    args.memory.check(&format!("a {} GEMM", args.size), bytes, "use a smaller --size")?;
    let gflops = pool(args.threads)?.install(|| densefeat::perf::gemm_gflops(args.size, args.runs));
    println!("| n | threads | runs | median GFLOP/s |");
    println!("|---|---|---|---|");
    println!("| {} | {} | {} | {gflops:.1} |", args.size, args.threads, args.runs);
    Ok(())
}

/// Runs the bench.
///
/// # Errors
/// [`Error::InvalidArgument`] for bad sizes, strides or thread counts.
pub fn run(args: BenchArgs) -> Result<()> {
    match &args.what {
        BenchCommand::Forward(a) => run_forward(a),
        BenchCommand::Gemm(a) => run_gemm(a),
        BenchCommand::Costvolume(a) => super::bench_costvolume::run(a.clone()),
        BenchCommand::Tv(a) => super::bench_tv::run(a),
        BenchCommand::Refine(a) => super::bench_refine::run(a),
        BenchCommand::Train(a) => super::train::run_bench(a),
    }
}
