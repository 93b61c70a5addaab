//! `densefeat train` (train the feature network, SPEC.md §13) and `densefeat bench train`.

use std::path::PathBuf;
use std::time::Instant;

use clap::Args;

use crate::cli::init_weights::parse_mean;
use crate::cli::validate::{self, MemoryLimit};
use densefeat::backend::CpuBackend;
use densefeat::error::{Error, Result};
use densefeat::geometry::InverseDepthBins;
use densefeat::io::write_npy_f32;
use densefeat::nn::{FeatureNet, NetworkWeights};
use densefeat::ops::NetworkConfig;
use densefeat::train::data::{Augment, DataConfig, DataSet, PairRule};
use densefeat::train::loss::LossConfig;
use densefeat::train::optim::OptimConfig;
use densefeat::train::step::{batch_step, pair_step, pair_step_timed, StepTimes, Supervision, TrainingPair};
use densefeat::train::trainer::{train, training_init, TrainConfig};

/// Arguments of `densefeat train`.
#[derive(Debug, Clone, Args)]
pub struct TrainArgs {
    /// Output folder: checkpoint.safetensors, weights.safetensors, log.csv, curves.png.
    #[arg(long)]
    pub out: PathBuf,
    /// Posed RGB-D sequences to train on (repeat the flag); the last --val-fraction of each is held out.
    #[arg(long = "data")]
    pub data: Vec<PathBuf>,
    /// Posed RGB-D sequences used only for validation (repeat the flag): validation scenes of
    /// SPEC §3a, never trained on.
    #[arg(long = "val-data")]
    pub val_data: Vec<PathBuf>,
    /// Synthetic training scenes rendered on the fly (0: none).
    #[arg(long, default_value_t = 64)]
    pub synthetic_scenes: usize,
    /// Synthetic validation scenes.
    #[arg(long, default_value_t = 4)]
    pub synthetic_val_scenes: usize,
    /// Probability that a pair is synthetic when --data is given too.
    #[arg(long, default_value_t = 0.5)]
    pub synthetic_fraction: f64,
    /// Style of the synthetic scenes: `classic`, `real` (photo textures, realistic sensor) or
    /// `mixed` (even seeds classic, odd seeds real).
    #[arg(long, default_value = "classic")]
    pub synthetic_style: String,
    /// Fraction of each sequence's frames, at its end, held out for validation.
    #[arg(long, default_value_t = 0.2)]
    pub val_fraction: f64,
    /// Crop WIDTHxHEIGHT.
    #[arg(long, default_value = "256x192")]
    pub crop: String,
    /// Pair rule: baseline range in metres, "min,max".
    #[arg(long, default_value = "0.05,0.5")]
    pub baseline: String,
    /// Pair rule: largest rotation, degrees.
    #[arg(long, default_value_t = 30.0)]
    pub max_rotation: f64,
    /// Pair rule: smallest view overlap.
    #[arg(long, default_value_t = 0.6)]
    pub min_overlap: f64,
    /// Optimiser steps.
    #[arg(long, default_value_t = 2000)]
    pub steps: usize,
    /// Pairs per step.
    #[arg(long, default_value_t = 1)]
    pub batch: usize,
    /// Peak learning rate (AdamW).
    #[arg(long, default_value_t = 1e-3)]
    pub lr: f64,
    /// Warm-up steps.
    #[arg(long, default_value_t = 100)]
    pub warmup: usize,
    /// Clip the global gradient norm to this (0: never); a safety net when well above the
    /// norms the log shows.
    #[arg(long, default_value_t = 10.0)]
    pub clip_norm: f64,
    /// Decoupled weight decay.
    #[arg(long, default_value_t = 1e-4)]
    pub weight_decay: f64,
    /// Inverse-depth bins.
    #[arg(long, default_value_t = 256)]
    pub bins: usize,
    /// Largest inverse depth of the bins, 1/m (the smallest is 0).
    #[arg(long, default_value_t = 4.0)]
    pub rho_max: f64,
    /// Stride of block 1 (1 or 2).
    #[arg(long, default_value_t = 2)]
    pub b1_stride: usize,
    /// Encoder blocks.
    #[arg(long, default_value_t = 5)]
    pub blocks: usize,
    /// Channels.
    #[arg(long, default_value_t = 32)]
    pub channels: usize,
    /// Input mean "r,g,b" (0-255).
    #[arg(long, default_value = "110,110,110")]
    pub mean: String,
    /// Seed of the data draws.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Seed of the Xavier initialisation.
    #[arg(long, default_value_t = 0)]
    pub init_seed: u64,
    /// Validate every N steps.
    #[arg(long, default_value_t = 100)]
    pub val_every: usize,
    /// Validation pairs per source.
    #[arg(long, default_value_t = 4)]
    pub val_per_source: usize,
    /// Checkpoint every N steps.
    #[arg(long, default_value_t = 50)]
    pub ckpt_every: usize,
    /// Start from these weights (same network) instead of the Xavier initialisation: fine-tuning.
    #[arg(long)]
    pub init_weights: Option<PathBuf>,
    /// Resume from this checkpoint (the configuration must match).
    #[arg(long)]
    pub resume: Option<PathBuf>,
    /// Stop after this many steps in total (the schedule still spans --steps).
    #[arg(long)]
    pub stop_after: Option<usize>,
    /// Live frames per training reference: 1 trains on pairs (the paper); N > 1 averages the
    /// costs of N live frames per hypothesis before the softmax, as the mapper's cost volume
    /// does (the multi-frame loss, SPEC.md §13.1b).
    #[arg(long, default_value_t = 1)]
    pub live_frames: usize,
    /// Where each live crop is cut (SPEC.md §13.5): `flow` (the reference window shifted by the
    /// mean flow, so it sees the same surfaces) or `same` (the reference window's own image
    /// coordinates, as the mapper compares full frames)
    #[arg(long, default_value = "flow")]
    pub live_crop: String,
    /// Occlusion masking of the loss (SPEC.md §13.1c): leave out a reference pixel whose true
    /// match, in any live frame, lies behind that frame's depth by more than this fraction of its
    /// depth (a point hidden by a nearer surface, whose "match" is the occluder). 0: off (the paper)
    #[arg(long, default_value_t = 0.0)]
    pub occlusion_mask: f64,
    /// Motion-blur augmentation (SPEC.md §13.5): each training crop is blurred along a line of
    /// length uniform in [0, L] pixels in a uniform direction, as a hand-held camera blurs. 0: off
    #[arg(long, default_value_t = 0.0)]
    pub augment_blur: f64,
    /// Gamma augmentation (SPEC.md §13.5): each training crop goes through 255 (I/255)^γ with ln γ
    /// uniform in [-G, G], a camera's tone curve. 0: off
    #[arg(long, default_value_t = 0.0)]
    pub augment_gamma: f64,
    /// How the multi-frame loss treats live frames that do not all see a hypothesis (SPEC.md
    /// §13.1d): `all` (§13.1b: every frame counts, m outside it, and a pixel only when its true
    /// match is inside every frame) or `seen` (the mapper's rule: per hypothesis the mean over the
    /// frames that see it, with §9.10's evidence minimum 0.25; a pixel whenever its true bin passes it)
    #[arg(long, default_value = "all")]
    pub multi_cost: String,
    /// Which outputs the loss supervises (SPEC.md §13.2): `deep` (the block outputs L1..Ln and the
    /// aggregated features L, the paper's deep supervision) or `final` (L alone, the features the
    /// mapper matches)
    #[arg(long, default_value = "deep")]
    pub supervision: String,
    /// Weight of each block output's loss (L1..Ln) against the aggregated features' (SPEC.md §13.2),
    /// in (0, 1]: 1 is the paper's deep supervision (every scale counts alike), smaller values move
    /// the objective towards `--supervision final`
    #[arg(long, default_value_t = 1.0)]
    pub deep_weight: f64,
    /// Weight of the loss's regression term against the paper's (SPEC.md §13.1 step 5):
    /// λ_ρ = 5 W, λ_d = W. 1: the paper's loss; 0: the cross-entropy alone
    #[arg(long, default_value_t = 1.0)]
    pub regression_weight: f64,
    /// Weight of the ranking term (SPEC.md §13.1e): per pixel w max(0, μ + E_true − min E), the
    /// minimum over the hypotheses more than 2 bins from the true one, so the lowest cost (the
    /// mapper's winner) is asked to lie at the truth. 0: off, the paper's loss
    #[arg(long, default_value_t = 0.0)]
    pub hinge_weight: f64,
    /// The ranking term's margin μ, in the cost's units (SPEC.md §13.1e)
    #[arg(long, default_value_t = 1.0)]
    pub hinge_margin: f64,
    /// Loss pixel sampling (SPEC.md §13.1a): evaluate one pixel per SxS block at the finest
    /// supervised level (S/2 one level coarser, ...), weighted S²: unbiased; 1 evaluates every
    /// pixel (the paper).
    #[arg(long, default_value_t = 1)]
    pub loss_sample_stride: usize,
    /// Memory for decoded and rendered training frames, MiB (frames past it are made again on
    /// every use; never changes a result).
    #[arg(long, default_value_t = densefeat::train::data::DEFAULT_CACHE_MB)]
    pub frame_cache_mb: usize,
    /// Rayon threads (0: all cores).
    #[arg(long, default_value_t = 0)]
    pub threads: usize,
    /// No progress bar.
    #[arg(long)]
    pub quiet: bool,
    /// Memory limit.
    #[command(flatten)]
    pub memory: MemoryLimit,
}

fn parse_pair(text: &str, name: &str) -> Result<(f64, f64)> {
    super::validate::pair(text).map_err(|e| super::validate::flag(name, e))
}

impl TrainArgs {
    /// The training configuration these arguments describe.
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] for a malformed value.
    pub fn config(&self) -> Result<TrainConfig> {
        let (min_baseline, max_baseline) = parse_pair(&self.baseline, "--baseline")?;
        let network = NetworkConfig {
            blocks: self.blocks,
            channels: self.channels,
            b1_stride: self.b1_stride,
            input_mean: parse_mean(&self.mean)?,
        };
        network.validate()?;
        Ok(TrainConfig {
            network,
            init_seed: self.init_seed,
            seed: self.seed,
            steps: self.steps,
            batch: self.batch,
            optim: OptimConfig {
                lr: self.lr,
                warmup: self.warmup,
                weight_decay: self.weight_decay,
                clip_norm: self.clip_norm,
                ..OptimConfig::default()
            },
            loss: LossConfig {
                bins: InverseDepthBins::new(0.0, self.rho_max, self.bins)?,
                sample_stride: self.loss_sample_stride,
                multi_cost: self.multi_cost.parse()?,
                ..LossConfig::default()
            }
            .with_regression_weight(self.regression_weight)?
            .with_hinge(self.hinge_weight, self.hinge_margin)?,
            supervision: self.supervision.parse::<Supervision>()?.with_deep_weight(self.deep_weight)?,
            data: DataConfig {
                crop: validate::size("crop", &self.crop)?,
                rule: PairRule {
                    min_baseline,
                    max_baseline,
                    max_rotation_deg: self.max_rotation,
                    min_overlap: self.min_overlap,
                },
                sequences: self.data.clone(),
                val_sequences: self.val_data.clone(),
                synthetic_scenes: self.synthetic_scenes,
                synthetic_val_scenes: self.synthetic_val_scenes,
                synthetic_fraction: self.synthetic_fraction,
                synthetic_style: self.synthetic_style.parse()?,
                val_fraction: self.val_fraction,
                live_frames: self.live_frames,
                live_crop: self.live_crop.parse()?,
                occlusion_tolerance: self.occlusion_mask,
                augment: Augment {
                    blur: check_augment("augment-blur", self.augment_blur, 16.0)?,
                    gamma: check_augment("augment-gamma", self.augment_gamma, 1.0)?,
                    ..Augment::default()
                },
            },
            val_every: self.val_every,
            val_per_source: self.val_per_source,
            ckpt_every: self.ckpt_every,
            frame_cache_mb: self.frame_cache_mb,
            init_weights: self.init_weights.clone(),
        })
    }
}

use densefeat::runtime::thread_pool as pool;

/// An augmentation range must be finite and in `0..=max`.
fn check_augment(name: &str, v: f64, max: f64) -> Result<f64> {
    if v.is_finite() && (0.0..=max).contains(&v) {
        Ok(v)
    } else {
        Err(validate::flag(name, format!("{v}: must be between 0 and {max}")))
    }
}

/// `--loss-sample-stride` must be 1..=64.
fn check_sample_stride(s: usize) -> Result<()> {
    if (1..=64).contains(&s) {
        Ok(())
    } else {
        Err(validate::flag("loss-sample-stride", format!("{s}: must be between 1 and 64")))
    }
}

/// Runs `densefeat train`.
///
/// # Errors
/// Whatever training returns.
pub fn run(args: TrainArgs) -> Result<()> {
    check_sample_stride(args.loss_sample_stride)?;
    let cfg = args.config()?;
    let (w, h) = cfg.data.crop;
    let bytes = densefeat::memory::train_step_bytes(w, h, cfg.network.channels);
    args.memory.check(&format!("a training step on a {w}x{h} crop"), bytes, "use a smaller --crop")?;
    for (name, v) in [("lr", args.lr), ("rho-max", args.rho_max)] {
        validate::positive(name, v)?;
    }
    let t = Instant::now();
    pool(densefeat::runtime::all_cores_if_zero(args.threads))?.install(|| {
        train(
            &cfg,
            &args.out,
            args.resume.as_deref(),
            args.stop_after,
            &mut crate::cli::progress_bar::Bar::new(!args.quiet),
        )
    })?;
    eprintln!("trained in {:.1} s; outputs in {}", t.elapsed().as_secs_f64(), args.out.display());
    Ok(())
}

/// Arguments of `densefeat bench train`.
#[derive(Debug, Clone, Args)]
pub struct BenchTrainArgs {
    /// Crop WIDTHxHEIGHT of both frames.
    #[arg(long, default_value = "256x192")]
    pub crop: String,
    /// Rayon threads.
    #[arg(long, default_value_t = 2)]
    pub threads: usize,
    /// Timed steps (after one warm-up).
    #[arg(long, default_value_t = 5)]
    pub runs: usize,
    /// Inverse-depth bins.
    #[arg(long, default_value_t = 256)]
    pub bins: usize,
    /// Stride of block 1.
    #[arg(long, default_value_t = 2)]
    pub b1_stride: usize,
    /// Loss pixel sampling stride at the finest supervised level (as `densefeat train`).
    #[arg(long, default_value_t = 1)]
    pub loss_sample_stride: usize,
    /// Live frames per reference (as `densefeat train`).
    #[arg(long, default_value_t = 1)]
    pub live_frames: usize,
    /// Pairs per optimiser step for the batch timing (as `densefeat train --batch`; the pairs of
    /// a batch run at once). 0 skips it.
    #[arg(long, default_value_t = 4)]
    pub batch: usize,
    /// Also time the stages (forward with tape, each scale's loss, backward) in separate steps and
    /// print their medians.
    #[arg(long)]
    pub profile: bool,
    /// Also write the pair, the weights, our per-scale losses and gradients to this folder (for
    /// `benches/compare/train_torch.py`).
    #[arg(long)]
    pub dump: Option<PathBuf>,
    /// Time the step with these weights (e.g. the shipped ones, or a chain's checkpoint's) instead
    /// of the initialisation; their block-1 stride is used (`--b1-stride` is ignored).
    #[arg(long)]
    pub weights: Option<PathBuf>,
    /// Memory limit.
    #[command(flatten)]
    pub memory: MemoryLimit,
}

/// Writes what `benches/compare/train_torch.py` needs to recompute the step in PyTorch.
fn dump(
    dir: &std::path::Path,
    pair: &TrainingPair,
    weights: &NetworkWeights,
    loss: &LossConfig,
    sup: &Supervision,
) -> Result<()> {
    std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    write_npy_f32(&dir.join("ref.npy"), pair.ref_rgb.view())?;
    write_npy_f32(&dir.join("live.npy"), pair.live_rgb.view())?;
    let depth = pair.ref_depth.view().insert_axis(ndarray::Axis(2));
    write_npy_f32(&dir.join("depth.npy"), depth)?;
    weights.save(&dir.join("weights.safetensors"))?;
    let mut grads = weights.zeros_like();
    let l = pair_step(weights, pair, loss, sup, &CpuBackend::default(), Some((&mut grads, 1.0)))?;
    grads.provenance = "gradient of the pair objective".into();
    grads.save(&dir.join("grads.safetensors"))?;
    let cam = |c: &densefeat::geometry::PinholeCamera| serde_json::json!({"fx": c.fx, "fy": c.fy, "cx": c.cx, "cy": c.cy, "width": c.width, "height": c.height});
    let m = densefeat::geometry::pose_to_matrix(&pair.t_lr);
    let t_lr: Vec<Vec<f64>> = (0..4).map(|r| (0..4).map(|c| m[(r, c)]).collect()).collect();
    let json = serde_json::json!({
        "ref_camera": cam(&pair.ref_camera),
        "live_camera": cam(&pair.live_camera),
        "T_lr": t_lr,
        "bins": {"rho_min": loss.bins.rho_min, "rho_max": loss.bins.rho_max, "count": loss.bins.count},
        "outside_cost": loss.outside_cost, "lambda_rho": loss.lambda_rho, "lambda_d": loss.lambda_d,
        "rho_floor": loss.rho_floor, "prob_floor": loss.prob_floor,
        "loss_blocks": l.blocks.iter().map(|s| s.mean()).collect::<Vec<_>>(),
        "pixels_blocks": l.blocks.iter().map(|s| s.pixels).collect::<Vec<_>>(),
        "loss_aggregated": l.aggregated.mean(),
        "pixels_aggregated": l.aggregated.pixels,
        "total": l.total(sup),
    });
    densefeat::io::write_atomic(
        &dir.join("pair.json"),
        serde_json::to_string_pretty(&json)
            .map_err(|e| Error::invalid_argument("json", e.to_string()))?
            .as_bytes(),
    )
}

/// Runs `densefeat bench train`: one synthetic pair, forward + loss + backward of both images.
///
/// # Errors
/// Bad arguments.
pub fn run_bench(args: &BenchTrainArgs) -> Result<()> {
    let crop = validate::size("crop", &args.crop)?;
    let bytes = densefeat::memory::train_step_bytes(crop.0, crop.1, NetworkConfig::default().channels);
    args.memory.check(
        &format!("a training step on a {}x{} crop", crop.0, crop.1),
        bytes,
        "use a smaller --crop",
    )?;
    let data = DataSet::open(DataConfig {
        crop,
        synthetic_scenes: 1,
        synthetic_val_scenes: 0,
        live_frames: args.live_frames,
        ..DataConfig::default()
    })?;
    let pair = data.train_pair(0, 1, 0)?;
    let weights = match &args.weights {
        Some(path) => NetworkWeights::load(path)?,
        None => {
            let config = NetworkConfig {
                b1_stride: args.b1_stride,
                input_mean: [110.0; 3],
                ..NetworkConfig::default()
            };
            training_init(&config, 0)?
        }
    };
    let loss = LossConfig {
        bins: InverseDepthBins::new(0.0, 4.0, args.bins)?,
        sample_stride: args.loss_sample_stride,
        ..LossConfig::default()
    };
    check_sample_stride(args.loss_sample_stride)?;
    let sup = Supervision::default();
    let cpu = CpuBackend::default();
    let pool = pool(args.threads)?;
    if let Some(dir) = &args.dump {
        let mut staging = densefeat::io::Staging::new();
        let staged = staging.dir(dir)?;
        pool.install(|| dump(&staged, &pair, &weights, &loss, &sup))?;
        staging.commit()?;
        println!("wrote the pair, weights, losses and gradients to {}", dir.display());
    }
    let (ms_step, ms_fwd, stage) = pool.install(|| -> Result<(Vec<f64>, Vec<f64>, Vec<StepTimes>)> {
        let mut g = weights.zeros_like();
        pair_step(&weights, &pair, &loss, &sup, &cpu, Some((&mut g, 1.0)))?;
        let mut steps = Vec::new();
        let mut fwds = Vec::new();
        let mut stages = Vec::new();
        let net = FeatureNet::new(weights.clone())?;
        for _ in 0..args.runs.max(1) {
            let t = Instant::now();
            pair_step(&weights, &pair, &loss, &sup, &cpu, Some((&mut g, 1.0)))?;
            steps.push(t.elapsed().as_secs_f64() * 1e3);
            let t = Instant::now();
            net.forward(pair.ref_rgb.view(), &cpu)?;
            net.forward(pair.live_rgb.view(), &cpu)?;
            fwds.push(t.elapsed().as_secs_f64() * 1e3);
            if args.profile {
                let mut st = StepTimes::default();
                pair_step_timed(&weights, &pair, &loss, &sup, &cpu, Some((&mut g, 1.0)), &mut st)?;
                stages.push(st);
            }
        }
        Ok((steps, fwds, stages))
    })?;
    // The trainer's step: `batch` different pairs at once (SPEC.md §13.6).
    let pairs = (0..args.batch).map(|b| data.train_pair(0, 1, b)).collect::<Result<Vec<_>>>()?;
    let (ms_batch, ms_serial) = pool.install(|| -> Result<(Vec<f64>, Vec<f64>)> {
        let (mut v, mut serial) = (Vec::new(), Vec::new());
        if args.batch > 0 {
            let run = || batch_step(&weights, args.batch, |b| Ok(pairs[b].clone()), &loss, &sup, &cpu);
            run()?;
            let mut g = weights.zeros_like();
            for _ in 0..args.runs.max(1) {
                let t = Instant::now();
                run()?;
                v.push(t.elapsed().as_secs_f64() * 1e3);
                // The same pairs one after another (each using every thread), for comparison.
                let t = Instant::now();
                for p in &pairs {
                    pair_step(&weights, p, &loss, &sup, &cpu, Some((&mut g, 1.0)))?;
                }
                serial.push(t.elapsed().as_secs_f64() * 1e3);
            }
        }
        Ok((v, serial))
    })?;
    // The machine's SGEMM yardstick, measured right after (a loaded machine shows here).
    let sgemm = pool.install(|| densefeat::perf::gemm_gflops(256, 5));
    let median = |mut v: Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    let (step, fwd) = (median(ms_step), median(ms_fwd));
    let b1_stride = weights.config.b1_stride;
    let from = args
        .weights
        .as_ref()
        .map_or_else(|| "initialisation seed 0".to_string(), |p| p.display().to_string());
    let net = FeatureNet::new(weights)?;
    // Forward of two images, backward ≈ 2x forward (input and weight gradients).
    let net_flops = 3.0 * 2.0 * net.flops(crop.1, crop.0);
    println!(
        "bench train: crop {}x{}, {} bins, b1 stride {}, {} threads, deep supervision L1..L5 + L, loss sample stride {}, {} live frame(s), weights: {from}",
        crop.0, crop.1, args.bins, b1_stride, args.threads, args.loss_sample_stride, args.live_frames
    );
    println!("  SGEMM indicator (256x256x256, {} threads): {sgemm:.1} GFLOP/s", args.threads);
    println!("  one pair (forward 2 images + loss at 6 scales + backward): {step:.1} ms median of {} -> {:.3} pairs/s", args.runs, 1e3 / step);
    println!("  of which network forward of both images: {fwd:.1} ms");
    if !ms_batch.is_empty() {
        let (b, serial) = (median(ms_batch), median(ms_serial));
        println!(
            "  one step of a batch of {} pairs (the pairs at once, as the trainer runs them): {b:.1} ms median of {} -> {:.3} pairs/s (the same pairs one after another: {serial:.1} ms -> {:.3} pairs/s)",
            args.batch,
            args.runs,
            args.batch as f64 * 1e3 / b,
            args.batch as f64 * 1e3 / serial
        );
    }
    println!(
        "  network forward+backward work {:.2} GFLOP per pair -> {:.1} GFLOP/s if the loss cost nothing",
        net_flops / 1e9,
        net_flops / 1e6 / step
    );
    if !stage.is_empty() {
        print_stages(&stage, median);
    }
    Ok(())
}

/// Prints the median of each stage over the profiled steps.
fn print_stages(stages: &[StepTimes], median: impl Fn(Vec<f64>) -> f64) {
    let col = |f: &dyn Fn(&StepTimes) -> f64| median(stages.iter().map(f).collect());
    println!("  stages (median of {} separately timed steps):", stages.len());
    println!("| stage | ms |");
    println!("|---|---|");
    println!("| forward with tape, both images | {:.1} |", col(&|s| s.forward));
    let mut loss_total = 0.0;
    for (i, (name, level, _)) in stages[0].losses.iter().enumerate() {
        let m = col(&|s| s.losses[i].2);
        loss_total += m;
        println!("| loss {name} (level {level}) | {m:.1} |");
    }
    println!("| loss, all scales | {loss_total:.1} |");
    println!("| backward, both images | {:.1} |", col(&|s| s.backward));
}
