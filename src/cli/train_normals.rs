//! `densefeat train-normals`: train the built-in surface-normal predictor (SPEC.md §13.11) on the
//! training scenes' frames with normals from their depth.

use std::path::{Path, PathBuf};
use std::time::Instant;

use clap::Args;

use crate::cli::validate::{self, MemoryLimit};
use densefeat::error::Result;
use densefeat::mapping::features::{SHIPPED_WEIGHTS, SHIPPED_WEIGHTS_NAME};
use densefeat::nn::NetworkWeights;
use densefeat::normals_net::HEAD_SEED;
use densefeat::train::data::{DataConfig, PairRule};
use densefeat::train::normals::trainer::{train_normals, NormalsTrainConfig};
use densefeat::train::optim::OptimConfig;

/// Arguments of `densefeat train-normals`.
#[derive(Debug, Clone, Args)]
pub struct TrainNormalsArgs {
    /// Output folder: normalnet.safetensors, checkpoint.safetensors, log.csv.
    #[arg(long)]
    pub out: PathBuf,
    /// Posed RGB-D sequences to train on (repeat the flag): training scenes (SPEC §3a).
    #[arg(long = "data")]
    pub data: Vec<PathBuf>,
    /// Posed RGB-D sequences used only for validation (repeat the flag): validation scenes.
    #[arg(long = "val-data")]
    pub val_data: Vec<PathBuf>,
    /// Synthetic training scenes rendered on the fly (seeds 100000..; 0: none).
    #[arg(long, default_value_t = 64)]
    pub synthetic_scenes: usize,
    /// Synthetic validation scenes (seeds 200000..).
    #[arg(long, default_value_t = 4)]
    pub synthetic_val_scenes: usize,
    /// Probability that a frame is synthetic when --data is given too.
    #[arg(long, default_value_t = 0.5)]
    pub synthetic_fraction: f64,
    /// Style of the synthetic scenes: `classic`, `real` or `mixed` (even seeds classic, odd seeds real).
    #[arg(long, default_value = "classic")]
    pub synthetic_style: String,
    /// Fraction of each training sequence's frames, at its end, held out for validation (0: the
    /// scene-level protocol, validation from --val-data).
    #[arg(long, default_value_t = 0.0)]
    pub val_fraction: f64,
    /// Crop WIDTHxHEIGHT.
    #[arg(long, default_value = "256x192")]
    pub crop: String,
    /// Pair rule of the frame draws (SPEC §13.5): baseline range in metres, "min,max".
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
    /// Frames per step.
    #[arg(long, default_value_t = 4)]
    pub batch: usize,
    /// Peak learning rate (AdamW).
    #[arg(long, default_value_t = 3e-4)]
    pub lr: f64,
    /// Warm-up steps.
    #[arg(long, default_value_t = 50)]
    pub warmup: usize,
    /// Clip the global gradient norm to this (0: never).
    #[arg(long, default_value_t = 10.0)]
    pub clip_norm: f64,
    /// Decoupled weight decay.
    #[arg(long, default_value_t = 1e-4)]
    pub weight_decay: f64,
    /// The trunk's initial weights (a feature-network file, SPEC §8.4); default: the shipped
    /// trained features built into the binary.
    #[arg(long)]
    pub init_trunk: Option<PathBuf>,
    /// Seed of the head's initialisation.
    #[arg(long, default_value_t = HEAD_SEED)]
    pub head_seed: u64,
    /// Seed of the data draws.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Validate every N steps.
    #[arg(long, default_value_t = 100)]
    pub val_every: usize,
    /// Validation frames per source.
    #[arg(long, default_value_t = 4)]
    pub val_per_source: usize,
    /// Write the outputs every N steps.
    #[arg(long, default_value_t = 50)]
    pub ckpt_every: usize,
    /// The loss is linear in the head's raw output below this norm (a bounded gradient for pixels
    /// with a near-zero output, SPEC.md §13.11; 0: none).
    #[arg(long, default_value_t = densefeat::normals_net::head::RAW_NORM_FLOOR)]
    pub raw_norm_floor: f64,
    /// Resume from this checkpoint (the configuration must match).
    #[arg(long)]
    pub resume: Option<PathBuf>,
    /// Stop after this many steps in total (the schedule still spans --steps).
    #[arg(long)]
    pub stop_after: Option<usize>,
    /// Memory for decoded and rendered frames, MiB.
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

impl TrainNormalsArgs {
    /// The configuration these arguments describe, every flag checked (nothing heavy runs).
    ///
    /// # Errors
    /// [`densefeat::Error::InvalidArgument`] naming the flag.
    pub fn config(&self) -> Result<NormalsTrainConfig> {
        let (min_baseline, max_baseline) =
            validate::pair(&self.baseline).map_err(|e| validate::flag("baseline", e))?;
        validate::positive("lr", self.lr)?;
        for (name, v) in [
            ("steps", self.steps),
            ("batch", self.batch),
            ("val-every", self.val_every),
            ("ckpt-every", self.ckpt_every),
        ] {
            if v == 0 {
                return Err(validate::flag(name, "0: must be at least 1"));
            }
        }
        if let Some(p) = self.resume.as_deref().filter(|p| !p.is_file()) {
            return Err(validate::flag("resume", format!("{}: no such file", p.display())));
        }
        let optim = OptimConfig {
            lr: self.lr,
            warmup: self.warmup,
            weight_decay: self.weight_decay,
            clip_norm: self.clip_norm,
            ..OptimConfig::default()
        };
        optim.validate().map_err(|e| validate::flag("lr/warmup/clip-norm/weight-decay", e.to_string()))?;
        let cfg = NormalsTrainConfig {
            init_trunk: self
                .init_trunk
                .as_ref()
                .map_or(SHIPPED_WEIGHTS_NAME.to_string(), |p| p.display().to_string()),
            head_seed: self.head_seed,
            seed: self.seed,
            steps: self.steps,
            batch: self.batch,
            optim,
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
                live_frames: 1,
                ..DataConfig::default()
            },
            val_every: self.val_every,
            val_per_source: self.val_per_source,
            ckpt_every: self.ckpt_every,
            raw_norm_floor: self.raw_norm_floor,
            frame_cache_mb: self.frame_cache_mb,
        };
        cfg.validate()?;
        Ok(cfg)
    }

    /// The trunk to start from: `--init-trunk` or the built-in shipped features.
    ///
    /// # Errors
    /// The file's load errors.
    pub fn trunk(&self) -> Result<NetworkWeights> {
        match &self.init_trunk {
            Some(p) => NetworkWeights::load(p),
            None => NetworkWeights::from_safetensors_bytes(SHIPPED_WEIGHTS, Path::new(SHIPPED_WEIGHTS_NAME)),
        }
    }
}

/// Runs `densefeat train-normals`.
///
/// # Errors
/// A bad flag (named, before any heavy work) or whatever training returns.
pub fn run(args: TrainNormalsArgs) -> Result<()> {
    let cfg = args.config()?;
    let trunk = args.trunk()?;
    let (w, h) = cfg.data.crop;
    let bytes =
        densefeat::memory::train_step_bytes(w, h, trunk.config.channels).saturating_mul(cfg.batch as u64);
    args.memory.check(
        &format!("a batch of {} frames of {w}x{h}", cfg.batch),
        bytes,
        "use a smaller --crop or --batch",
    )?;
    let pool = densefeat::runtime::thread_pool(densefeat::runtime::all_cores_if_zero(args.threads))?;
    let t = Instant::now();
    pool.install(|| {
        train_normals(
            &cfg,
            &trunk,
            &args.out,
            args.resume.as_deref(),
            args.stop_after,
            &mut crate::cli::progress_bar::Bar::new(!args.quiet),
        )
    })?;
    eprintln!("trained in {:.1} s; outputs in {}", t.elapsed().as_secs_f64(), args.out.display());
    Ok(())
}
