//! `densefeat bench refine`: time the photometric sub-bin refinement (SPEC.md §10.3) of one keyframe
//! at the input resolution on a synthetic textured plane: the fast path (median of `--runs`) and,
//! once, its plain-loop reference; both results are compared bit for bit. The SGEMM indicator
//! measured right after shows a loaded machine.

use std::time::Instant;

use clap::Args;

use super::synth::parse_size;
use densefeat::error::{Error, Result};
use densefeat::mapping::refine::{
    refine_level0, refine_level0_reference, Level0, RefineView, REFINE_DEFAULTS,
};
use densefeat::perf::{refine_inputs, RefineInputs};

/// Arguments of `densefeat bench refine`.
#[derive(Debug, Clone, Args)]
pub struct BenchRefineArgs {
    /// Keyframe size WIDTHxHEIGHT (the input resolution; `map` refines there).
    #[arg(long, default_value = "640x480")]
    pub size: String,
    /// Live frames (the refinement's default takes at most 12).
    #[arg(long, default_value_t = 12)]
    pub frames: usize,
    /// Worker threads (rayon pool size).
    #[arg(long, default_value_t = 2)]
    pub threads: usize,
    /// Timed runs (at least 3) after one warm-up run.
    #[arg(long, default_value_t = 5)]
    pub runs: usize,
    /// Also time the plain-loop reference once (slow: about 30x the fast path at 640x480 on 2 threads).
    #[arg(long)]
    pub reference: bool,
    /// Memory limit.
    #[command(flatten)]
    pub memory: super::validate::MemoryLimit,
}

/// Runs the benchmark and prints the median time, pixel-hypothesis-frame rate and moved share.
///
/// # Errors
/// [`Error::InvalidArgument`] for bad arguments.
pub fn run(args: &BenchRefineArgs) -> Result<()> {
    let (width, height) = parse_size(&args.size)?;
    if args.runs < 3 {
        return Err(Error::invalid_argument("--runs", format!("{}: must be at least 3", args.runs)));
    }
    let images = densefeat::memory::product(&[height as u64, width as u64, 8 * (args.frames as u64 + 3)]);
    let bytes = images.saturating_add(densefeat::mapping::refine::memory_bytes(height, width, args.frames));
    args.memory.check(&format!("refining a {width}x{height} keyframe"), bytes, "use a smaller --size")?;
    let pool = super::bench::pool(args.threads)?;
    let RefineInputs { camera, key, rho0, greys, poses, step } = refine_inputs(width, height, args.frames)?;
    let views: Vec<RefineView> =
        greys.iter().zip(&poses).map(|(g, p)| RefineView { grey: g.view(), camera, pose: *p }).collect();
    let problem = Level0 { key: key.view(), camera: &camera, rho0: rho0.view(), views: &views, step };
    let p = REFINE_DEFAULTS;
    let mut times = Vec::with_capacity(args.runs);
    let out = pool.install(|| -> Result<_> {
        let out = refine_level0(&problem, &p)?; // warm-up
        for _ in 0..args.runs {
            let t = Instant::now();
            refine_level0(&problem, &p)?;
            times.push(t.elapsed().as_secs_f64());
        }
        Ok(out)
    })?;
    // The machine's SGEMM yardstick, measured right after (a loaded machine shows here).
    let sgemm = pool.install(|| densefeat::perf::gemm_gflops(256, 5));
    let moved = out.iter().filter(|v| v.is_finite()).count() as f64 / out.len() as f64;
    let ms = super::bench_tv::median_ms(times);
    let work = (width * height * p.samples * args.frames) as f64;
    println!("| size | frames | hypotheses | threads | fast path ms | M pixel-hypothesis-frames/s | moved |");
    println!("|---|---|---|---|---|---|---|");
    println!(
        "| {width}x{height} | {} | {} | {} | {ms:.1} | {:.1} | {:.1} % |",
        args.frames,
        p.samples,
        args.threads,
        work / (ms / 1e3) / 1e6,
        100.0 * moved
    );
    println!("SGEMM indicator (256x256x256, {} threads): {sgemm:.1} GFLOP/s", args.threads);
    if args.reference {
        let t = Instant::now();
        let r = pool.install(|| refine_level0_reference(&problem, &p))?;
        let ref_ms = t.elapsed().as_secs_f64() * 1e3;
        let same = r.iter().zip(out.iter()).all(|(a, b)| a.to_bits() == b.to_bits());
        println!("reference: {ref_ms:.1} ms ({:.1}x the fast path), bit-identical: {same}", ref_ms / ms);
        if !same {
            return Err(Error::invalid_argument("refine", "the fast path and the reference differ"));
        }
    }
    Ok(())
}
