//! The normal predictor's training loop (SPEC.md §13.11): batches of frames, AdamW, validation,
//! `log.csv`, `normalnet.safetensors` and `checkpoint.safetensors` written together as one staged
//! set, exact resume. Bit-identical weights for any thread count.

use std::path::{Path, PathBuf};
use std::time::Instant;

use crate::backend::CpuBackend;
use crate::error::{Error, Result};
use crate::io::{write_atomic, Staging};
use crate::nn::NetworkWeights;
use crate::normals_net::NormalNetWeights;
use crate::progress::Progress;
use crate::train::data::{DataConfig, DataSet};
use crate::train::normals::checkpoint::{NormalAdam, NormalCheckpoint};
use crate::train::normals::step::{normals_batch_step, validate_normals, NormalSample};
use crate::train::optim::{adam_step_layers, AdamLayers, OptimConfig};

/// Everything a normal-predictor training run depends on (besides the trunk it starts from).
#[derive(Clone, Debug, PartialEq)]
pub struct NormalsTrainConfig {
    /// Where the initial trunk came from (a file, or the built-in features), for the fingerprint
    /// and the provenance.
    pub init_trunk: String,
    /// Seed of the head's initialisation.
    pub head_seed: u64,
    /// Seed of the data draws.
    pub seed: u64,
    /// Total optimiser steps.
    pub steps: usize,
    /// Frames per step.
    pub batch: usize,
    /// Optimiser.
    pub optim: OptimConfig,
    /// Data (§13.5's pairs; their reference crops are the frames).
    pub data: DataConfig,
    /// Validate every this many steps (and at the last).
    pub val_every: usize,
    /// Validation frames per source.
    pub val_per_source: usize,
    /// Write the outputs every this many steps (and at the last).
    pub ckpt_every: usize,
    /// The loss's raw-norm floor ([`crate::normals_net::head::RAW_NORM_FLOOR`] by default; 0: none).
    pub raw_norm_floor: f64,
    /// Frame cache, MiB (not in the fingerprint: it never changes a result).
    pub frame_cache_mb: usize,
}

impl NormalsTrainConfig {
    /// Checks the settings [`train_normals`] needs before any data is read.
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] naming `--raw-norm-floor` for a negative or non-finite floor.
    pub fn validate(&self) -> Result<()> {
        if !(self.raw_norm_floor >= 0.0 && self.raw_norm_floor.is_finite()) {
            return Err(Error::invalid_argument(
                "--raw-norm-floor",
                format!("{}: must be a finite number >= 0", self.raw_norm_floor),
            ));
        }
        Ok(())
    }

    /// The settings that determine the weights, as text (stored in checkpoints; a resume must
    /// match it).
    pub fn fingerprint(&self, trunk: &NetworkWeights) -> String {
        format!(
            "normals: init_trunk={} network={:?} head_seed={} seed={} steps={} batch={} optim={:?} data={:?} raw_norm_floor={}",
            self.init_trunk,
            trunk.config,
            self.head_seed,
            self.seed,
            self.steps,
            self.batch,
            self.optim,
            self.data,
            self.raw_norm_floor
        )
    }
}

/// Output files of a run in `out`.
pub struct NormalRunPaths {
    /// `checkpoint.safetensors`.
    pub checkpoint: PathBuf,
    /// `normalnet.safetensors`.
    pub weights: PathBuf,
    /// `log.csv`.
    pub csv: PathBuf,
    /// `best_normalnet.safetensors`: the weights at the validation with the lowest mean angle so far.
    pub best: PathBuf,
}

impl NormalRunPaths {
    /// The files in `out`.
    pub fn new(out: &Path) -> Self {
        NormalRunPaths {
            checkpoint: out.join("checkpoint.safetensors"),
            weights: out.join("normalnet.safetensors"),
            csv: out.join("log.csv"),
            best: out.join("best_normalnet.safetensors"),
        }
    }
}

const CSV_HEADER: &str =
    "step,lr,loss,mean_angle_deg,grad_norm,val_loss,val_mean_angle_deg,frames_per_s,elapsed_s";

/// The validation mean angle as the log writes it (3 decimals), parsed back: the best-so-far is
/// compared on this value, so a resumed run (which reads it from the log) decides as an
/// uninterrupted one.
fn logged_angle(a: f64) -> f64 {
    format!("{a:.3}").parse().unwrap_or(a)
}

/// The CSV rows of an earlier run up to `step`.
fn rows_up_to(csv: &Path, step: usize) -> String {
    let mut text = String::new();
    if let Ok(old) = std::fs::read_to_string(csv) {
        for line in old.lines().skip(1) {
            if line.split(',').next().and_then(|s| s.parse::<usize>().ok()).is_some_and(|s| s <= step) {
                text.push_str(line);
                text.push('\n');
            }
        }
    }
    text
}

/// Trains from `trunk` (the predictor's trunk is a copy; its head is drawn with `cfg.head_seed`),
/// or continues from the checkpoint `resume` (same fingerprint) up to `cfg.steps`; `stop_after`
/// ends early after that many steps in total; `progress` hears the steps and the validation
/// lines. Returns the weights.
///
/// # Errors
/// Bad configuration, unreadable data, a checkpoint that does not match, write failures, a loss
/// that is not finite.
pub fn train_normals(
    cfg: &NormalsTrainConfig,
    trunk: &NetworkWeights,
    out: &Path,
    resume: Option<&Path>,
    stop_after: Option<usize>,
    progress: &mut dyn Progress,
) -> Result<NormalNetWeights> {
    cfg.optim.validate()?;
    cfg.validate()?;
    if cfg.batch == 0 || cfg.steps == 0 || cfg.val_every == 0 || cfg.ckpt_every == 0 {
        return Err(Error::invalid_argument(
            "train-normals",
            "steps, batch, val-every and ckpt-every must be at least 1",
        ));
    }
    let paths = NormalRunPaths::new(out);
    let fingerprint = cfg.fingerprint(trunk);
    let (mut step, mut weights, mut adam) = match resume {
        Some(p) => {
            let c = NormalCheckpoint::load(p)?;
            if c.train_config != fingerprint {
                return Err(Error::bad_file(p, format!("was made with a different configuration:\n  checkpoint: {}\n  now:        {fingerprint}", c.train_config)));
            }
            (c.step, c.weights, c.adam)
        }
        None => {
            let w = NormalNetWeights::from_trunk(trunk.clone(), cfg.head_seed)?;
            let a = NormalAdam::new(&w);
            (0, w, a)
        }
    };
    let data = DataSet::open(cfg.data.clone())?.with_cache_mb(cfg.frame_cache_mb);
    for line in data.describe() {
        eprintln!("data: {line}");
    }
    let val: Vec<NormalSample> =
        data.val_pairs(cfg.val_per_source)?.into_iter().map(|(_, p)| p.into()).collect();
    eprintln!("validation: {} frames", val.len());
    let mut csv_text = format!("{CSV_HEADER}\n");
    if resume.is_some() {
        csv_text.push_str(&rows_up_to(&paths.csv, step));
    }
    // The lowest validation mean angle so far (from the log's rows, so a resume continues it), and
    // the weights that reached a new one, written with the next checkpoint.
    let val_column = CSV_HEADER.split(',').position(|c| c == "val_mean_angle_deg");
    let mut best = csv_text
        .lines()
        .skip(1)
        .filter_map(|l| l.split(',').nth(val_column?).and_then(|v| v.parse::<f64>().ok()))
        .fold(f64::INFINITY, f64::min);
    let mut pending_best: Option<NormalNetWeights> = None;
    let cpu = CpuBackend::default();
    let last = stop_after.unwrap_or(cfg.steps).min(cfg.steps);
    progress.start(cfg.steps as u64, step as u64);
    let start = Instant::now();
    while step < last {
        step += 1;
        let t0 = Instant::now();
        let (losses, grads) = normals_batch_step(
            &weights,
            cfg.batch,
            |b| data.train_pair(cfg.seed, step, b).map(Into::into),
            &cpu,
            cfg.raw_norm_floor,
        )?;
        let lr = cfg.optim.lr_at(step, cfg.steps);
        let layers = AdamLayers {
            weights: weights.layers_mut(),
            grads: grads.layers(),
            m: adam.m.layers_mut(),
            v: adam.v.layers_mut(),
        };
        let grad_norm = adam_step_layers(&cfg.optim, &mut adam.step, layers, lr);
        let loss = losses.iter().map(|l| l.mean()).sum::<f64>() / cfg.batch as f64;
        if !loss.is_finite() {
            return Err(Error::invalid_argument(
                "train-normals",
                format!("the loss became {loss} at step {step}; lower --lr"),
            ));
        }
        let (pixels, angles) =
            losses.iter().fold((0usize, 0.0f64), |(p, a), l| (p + l.pixels, a + l.angle_deg));
        let angle = if pixels > 0 { angles / pixels as f64 } else { f64::NAN };
        let frames_per_s = cfg.batch as f64 / t0.elapsed().as_secs_f64();
        let val_res = if step % cfg.val_every == 0 || step == cfg.steps {
            Some(validate_normals(&weights, &val)?)
        } else {
            None
        };
        let (vl, va) =
            val_res.map_or((String::new(), String::new()), |(l, a)| (format!("{l:.6}"), format!("{a:.3}")));
        csv_text.push_str(&format!(
            "{step},{lr:.3e},{loss:.6},{angle:.3},{grad_norm:.4},{vl},{va},{frames_per_s:.3},{:.1}\n",
            start.elapsed().as_secs_f64()
        ));
        if let Some(a) = val_res.map(|(_, a)| logged_angle(a)).filter(|&a| a < best) {
            best = a;
            let mut w = weights.clone();
            w.trunk.provenance = format!(
                "densefeat train-normals: step {step} of {} (best validation mean angle {a:.3} deg); {fingerprint}",
                cfg.steps
            );
            pending_best = Some(w);
        }
        if let Some((l, a)) = val_res {
            progress.line(&format!(
                "step {step}: train loss {loss:.4} ({angle:.2}°), val loss {l:.4}, val mean angle {a:.2}°"
            ));
        }
        progress.update(step as u64, "");
        if step % cfg.ckpt_every == 0 || step == last {
            let mut w = weights.clone();
            w.trunk.provenance =
                format!("densefeat train-normals: step {step} of {}; {fingerprint}", cfg.steps);
            let mut staging = Staging::new();
            let staged = NormalRunPaths::new(&staging.dir(out)?);
            NormalCheckpoint {
                step,
                weights: w.clone(),
                adam: adam.clone(),
                train_config: fingerprint.clone(),
            }
            .save(&staged.checkpoint)?;
            w.save(&staged.weights)?;
            if let Some(b) = pending_best.take() {
                b.save(&staged.best)?;
            }
            write_atomic(&staged.csv, csv_text.as_bytes())?;
            staging.commit()?;
        }
    }
    progress.finish();
    Ok(weights)
}
