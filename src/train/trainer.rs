//! The training loop (SPEC.md §13.6): batches of pairs, AdamW, validation, a CSV log, a PNG plot
//! of the curves, checkpoints and resume. Bit-identical weights for any thread count.

use std::path::{Path, PathBuf};
use std::time::Instant;

use rayon::prelude::*;

use crate::backend::CpuBackend;
use crate::error::{Error, Result};
use crate::io::{write_atomic, Staging};
use crate::nn::NetworkWeights;
use crate::ops::NetworkConfig;
use crate::plot::{grid_of_plots_png, Panel, Series};
use crate::progress::Progress;
use crate::train::checkpoint::Checkpoint;
use crate::train::data::{DataConfig, DataSet};
use crate::train::loss::{LossConfig, LossSums};
use crate::train::optim::{adam_step, AdamState, OptimConfig};
use crate::train::step::{batch_step, pair_step, Supervision, TrainingPair};

/// Everything a training run depends on.
#[derive(Clone, Debug, PartialEq)]
pub struct TrainConfig {
    /// The network.
    pub network: NetworkConfig,
    /// Seed of the Xavier initialisation.
    pub init_seed: u64,
    /// Seed of the data draws.
    pub seed: u64,
    /// Total optimiser steps.
    pub steps: usize,
    /// Pairs per step.
    pub batch: usize,
    /// Optimiser.
    pub optim: OptimConfig,
    /// Loss.
    pub loss: LossConfig,
    /// Supervised scales.
    pub supervision: Supervision,
    /// Data.
    pub data: DataConfig,
    /// Validate every this many steps (and at the last).
    pub val_every: usize,
    /// Validation pairs per source.
    pub val_per_source: usize,
    /// Write a checkpoint every this many steps (and at the last).
    pub ckpt_every: usize,
    /// Byte budget of the frame cache, MiB (not in the fingerprint: it never changes a result).
    pub frame_cache_mb: usize,
    /// Start from these weights (a SPEC.md §8.4 file of the same network) instead of §13.4's
    /// initialisation: fine-tuning, e.g. to branch a chain into two objectives.
    pub init_weights: Option<PathBuf>,
}

impl TrainConfig {
    /// The settings that determine the weights, as text. Stored in checkpoints; a resume must
    /// match it exactly (including `steps`, since the learning-rate schedule depends on it).
    pub fn fingerprint(&self) -> String {
        // `live_frames` joined DataConfig after chain b1s2 had started (SPEC.md §13.10): it is
        // written only when it is not 1, so the fingerprints of pair runs stay what they were and
        // their checkpoints remain resumable.
        // `live_crop` (2026-12-05) likewise only when it is not `Flow`.
        // `occlusion_tolerance` (2026-12-06) likewise only when it is not 0.
        let data = format!("{:?}", self.data);
        let data =
            data.strip_suffix(", occlusion_tolerance: 0.0 }").map_or(data.clone(), |d| format!("{d} }}"));
        let data = data.strip_suffix(", live_crop: Flow }").map_or(data.clone(), |d| format!("{d} }}"));
        let data = data.strip_suffix(", live_frames: 1 }").map_or(data.clone(), |d| format!("{d} }}"));
        // `multi_cost` (2026-12-06) joined LossConfig likewise: written only when it is not `All`.
        // `hinge_weight` and `hinge_margin` (2026-12-07) likewise: written only when the ranking term
        // is on (a margin without weight changes nothing).
        let loss = format!("{:?}", self.loss);
        let loss = match loss.find(", hinge_weight: 0.0, hinge_margin: ") {
            Some(i) => format!("{} }}", &loss[..i]),
            None => loss,
        };
        let loss = loss.strip_suffix(", multi_cost: All }").map_or(loss.clone(), |l| format!("{l} }}"));
        let mut f = format!(
            "network={:?} init_seed={} seed={} steps={} batch={} optim={:?} loss={loss} supervision={:?} data={data}",
            self.network, self.init_seed, self.seed, self.steps, self.batch, self.optim, self.supervision
        );
        // Only when set, so the fingerprints of runs from §13.4's initialisation are unchanged.
        if let Some(p) = &self.init_weights {
            f.push_str(&format!(" init_weights={}", p.display()));
        }
        f
    }
}

/// One CSV row.
#[derive(Clone, Debug, Default)]
struct Row {
    step: usize,
    lr: f64,
    loss: f64,
    per_scale: Vec<f64>,
    grad_norm: f64,
    val: Option<(f64, f64, f64)>,
    pairs_per_s: f64,
    elapsed_s: f64,
}

/// Validation result: mean objective over pairs, δ<1.25 of the expected and WTA depth at `L`.
pub fn validate(
    weights: &NetworkWeights,
    pairs: &[(String, TrainingPair)],
    cfg: &TrainConfig,
    cpu: &CpuBackend,
) -> Result<(f64, f64, f64)> {
    let mut total = 0.0;
    let mut agg = LossSums::default();
    // Validation evaluates every pixel (no sampling).
    let loss = LossConfig { sample_stride: 1, ..cfg.loss };
    // The pairs at once, their sums taken in pair order.
    let per_pair = pairs
        .par_iter()
        .map(|(_, p)| pair_step(weights, p, &loss, &cfg.supervision, cpu, None))
        .collect::<Result<Vec<_>>>()?;
    for l in &per_pair {
        total += l.total(&cfg.supervision);
        agg.accumulate(&l.aggregated);
    }
    let n = agg.pixels.max(1) as f64;
    Ok((total / pairs.len().max(1) as f64, agg.delta125_expected as f64 / n, agg.delta125_wta as f64 / n))
}

const CSV_HEADER: &str = "step,lr,loss,loss_L,loss_L1,loss_L2,loss_L3,loss_L4,loss_L5,grad_norm,val_loss,val_delta125_expected,val_delta125_wta,pairs_per_s,elapsed_s";

fn csv_line(r: &Row) -> String {
    let mut cols = vec![r.step.to_string(), format!("{:.3e}", r.lr), format!("{:.6}", r.loss)];
    for k in 0..6 {
        cols.push(r.per_scale.get(k).map_or(String::new(), |v| format!("{v:.6}")));
    }
    cols.push(format!("{:.4}", r.grad_norm));
    match r.val {
        Some((l, d, w)) => cols.extend([format!("{l:.6}"), format!("{d:.5}"), format!("{w:.5}")]),
        None => cols.extend([String::new(), String::new(), String::new()]),
    }
    cols.push(format!("{:.3}", r.pairs_per_s));
    cols.push(format!("{:.1}", r.elapsed_s));
    cols.join(",")
}

/// `(step, loss, validation (loss, δ expected, δ WTA))` of one CSV row.
type CurveRow = (f64, f64, Option<(f64, f64, f64)>);

/// Reads `(step, loss, val_loss, val_delta_expected, val_delta_wta)` back from the CSV.
fn read_curves(path: &Path) -> Result<Vec<CurveRow>> {
    let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
    let mut v = Vec::new();
    for line in text.lines().skip(1) {
        let c: Vec<&str> = line.split(',').collect();
        if c.len() < 15 {
            continue;
        }
        let num = |s: &str| s.parse::<f64>().ok();
        let (Some(step), Some(loss)) = (num(c[0]), num(c[2])) else { continue };
        let val = match (num(c[10]), num(c[11]), num(c[12])) {
            (Some(a), Some(b), Some(d)) => Some((a, b, d)),
            _ => None,
        };
        v.push((step, loss, val));
    }
    Ok(v)
}

/// Writes `curves.png`: training loss (and a running mean), validation loss, validation δ<1.25.
fn plot_curves(csv: &Path, png: &Path) -> Result<()> {
    let rows = read_curves(csv)?;
    if rows.is_empty() {
        return Ok(());
    }
    let train: Vec<(f64, f64)> = rows.iter().map(|r| (r.0, r.1)).collect();
    let window = 50usize;
    let smooth: Vec<(f64, f64)> = (0..train.len())
        .map(|i| {
            let lo = i.saturating_sub(window - 1);
            let s: f64 = train[lo..=i].iter().map(|p| p.1).sum();
            (train[i].0, s / (i - lo + 1) as f64)
        })
        .collect();
    let vals: Vec<(f64, (f64, f64, f64))> = rows.iter().filter_map(|r| r.2.map(|v| (r.0, v))).collect();
    let series = |name: &str, pts: Vec<(f64, f64)>, colour| Series { name: name.into(), points: pts, colour };
    let loss_panel = Panel {
        title: "loss (sum over supervised scales)".into(),
        x_label: "step".into(),
        y_label: "loss".into(),
        series: vec![
            series("train", train, (180, 180, 220)),
            series(&format!("train, mean of {window}"), smooth, (30, 60, 200)),
            series("validation", vals.iter().map(|(s, v)| (*s, v.0)).collect(), (220, 60, 30)),
        ],
        markers: vec![],
        log_x: false,
    };
    let delta_panel = Panel {
        title: "validation δ<1.25 at L (single pair, no regulariser)".into(),
        x_label: "step".into(),
        y_label: "fraction of pixels".into(),
        series: vec![
            series("expected depth", vals.iter().map(|(s, v)| (*s, v.1)).collect(), (30, 140, 60)),
            series("winner-take-all", vals.iter().map(|(s, v)| (*s, v.2)).collect(), (140, 60, 160)),
        ],
        markers: vec![],
        log_x: false,
    };
    grid_of_plots_png(png, "densefeat training", &[vec![loss_panel, delta_panel]])
}

/// Standard deviation assumed for 8-bit image values when initialising (SPEC.md §13.4).
pub const IMAGE_STD: f32 = 64.0;

/// The training initialisation (SPEC.md §13.4): Xavier-uniform ([`NetworkWeights::xavier_uniform`])
/// with every block's first-convolution weights on the image channels divided by [`IMAGE_STD`],
/// which is Xavier for an input scaled to about unit spread (the network takes 0-255 values minus
/// the mean, with no other scaling, so plain Xavier starts with features ~64x too large and a
/// saturated softmax).
///
/// # Errors
/// [`Error::InvalidArgument`] for a bad configuration.
pub fn training_init(config: &NetworkConfig, seed: u64) -> Result<NetworkWeights> {
    let mut w = NetworkWeights::xavier_uniform(config, seed)?;
    let c = config.channels;
    for (k, b) in w.blocks.iter_mut().enumerate() {
        let first_image_channel = if k == 0 { 0 } else { c };
        b.conv1
            .weight
            .slice_mut(ndarray::s![.., first_image_channel.., .., ..])
            .mapv_inplace(|v| v / IMAGE_STD);
    }
    w.provenance = format!("training init (xavier-uniform, image-channel weights / {IMAGE_STD}) seed={seed}");
    Ok(w)
}

/// Paths of a run's outputs in `out`.
pub struct RunPaths {
    /// `checkpoint.safetensors` (weights + optimiser state, the latest).
    pub checkpoint: PathBuf,
    /// `weights.safetensors` (weights only, the latest).
    pub weights: PathBuf,
    /// `log.csv`.
    pub csv: PathBuf,
    /// `curves.png`.
    pub plot: PathBuf,
}

impl RunPaths {
    /// The files of a run in `out`.
    pub fn new(out: &Path) -> Self {
        RunPaths {
            checkpoint: out.join("checkpoint.safetensors"),
            weights: out.join("weights.safetensors"),
            csv: out.join("log.csv"),
            plot: out.join("curves.png"),
        }
    }
}

/// Trains. With `resume`, continues from that checkpoint (its configuration must match) up to
/// `cfg.steps`; `stop_after` ends early after that many steps in total (for tests and for
/// splitting a long run). `progress` hears the steps and the validation lines.
///
/// # Errors
/// Bad configuration, unreadable data, a checkpoint that does not match, write failures.
pub fn train(
    cfg: &TrainConfig,
    out: &Path,
    resume: Option<&Path>,
    stop_after: Option<usize>,
    progress: &mut dyn Progress,
) -> Result<NetworkWeights> {
    cfg.optim.validate()?;
    cfg.loss.validate()?;
    if cfg.batch == 0 || cfg.steps == 0 || cfg.val_every == 0 || cfg.ckpt_every == 0 {
        return Err(Error::invalid_argument(
            "train",
            "steps, batch, val_every and ckpt_every must be at least 1",
        ));
    }
    let paths = RunPaths::new(out);
    let cpu = CpuBackend::default();
    let fingerprint = cfg.fingerprint();
    let (mut step, mut weights, mut adam) = match resume {
        Some(p) => {
            let c = Checkpoint::load(p)?;
            if c.train_config != fingerprint {
                return Err(Error::bad_file(p, format!("was made with a different configuration:\n  checkpoint: {}\n  now:        {fingerprint}", c.train_config)));
            }
            (c.step, c.weights, c.adam)
        }
        None => {
            let w = match &cfg.init_weights {
                Some(p) => {
                    let w = NetworkWeights::load(p)?;
                    if w.config != cfg.network {
                        return Err(Error::bad_file(
                            p,
                            format!("holds the network {:?}, the run trains {:?}", w.config, cfg.network),
                        ));
                    }
                    w
                }
                None => training_init(&cfg.network, cfg.init_seed)?,
            };
            let a = AdamState::new(&w);
            (0, w, a)
        }
    };
    let data = DataSet::open(cfg.data.clone())?.with_cache_mb(cfg.frame_cache_mb);
    for line in data.describe() {
        eprintln!("data: {line}");
    }
    let val = data.val_pairs(cfg.val_per_source)?;
    eprintln!("validation: {} pairs", val.len());
    // The CSV keeps the rows up to the resumed step.
    let mut csv_text = String::from(CSV_HEADER);
    csv_text.push('\n');
    if resume.is_some() {
        if let Ok(old) = std::fs::read_to_string(&paths.csv) {
            for line in old.lines().skip(1) {
                if line.split(',').next().and_then(|s| s.parse::<usize>().ok()).is_some_and(|s| s <= step) {
                    csv_text.push_str(line);
                    csv_text.push('\n');
                }
            }
        }
    }
    // The log is kept in memory and written with the checkpoint, the weights and the plot as one
    // staged set (SPEC.md §14.2): the folder always holds a matching four, or what it held before.
    let last = stop_after.unwrap_or(cfg.steps).min(cfg.steps);
    progress.start(cfg.steps as u64, step as u64);
    let start = Instant::now();
    let mut smoothed: Option<f64> = None;
    while step < last {
        step += 1;
        let t0 = Instant::now();
        let (losses, grads) = batch_step(
            &weights,
            cfg.batch,
            |b| data.train_pair(cfg.seed, step, b),
            &cfg.loss,
            &cfg.supervision,
            &cpu,
        )?;
        let lr = cfg.optim.lr_at(step, cfg.steps);
        let grad_norm = adam_step(&cfg.optim, &mut adam, &mut weights, &grads, lr);
        let loss = losses.iter().map(|l| l.total(&cfg.supervision)).sum::<f64>() / cfg.batch as f64;
        if !loss.is_finite() {
            return Err(Error::invalid_argument(
                "train",
                format!("the loss became {loss} at step {step}; lower the learning rate"),
            ));
        }
        let mut per_scale = vec![losses.iter().map(|l| l.aggregated.mean()).sum::<f64>() / cfg.batch as f64];
        // Without deep supervision the block columns stay empty (they were not computed).
        if cfg.supervision.deep {
            for k in 0..cfg.network.blocks {
                per_scale.push(losses.iter().map(|l| l.blocks[k].mean()).sum::<f64>() / cfg.batch as f64);
            }
        }
        let pairs_per_s = cfg.batch as f64 / t0.elapsed().as_secs_f64();
        let val_now = step % cfg.val_every == 0 || step == cfg.steps;
        let val_res = if val_now { Some(validate(&weights, &val, cfg, &cpu)?) } else { None };
        let row = Row {
            step,
            lr,
            loss,
            per_scale,
            grad_norm,
            val: val_res,
            pairs_per_s,
            elapsed_s: start.elapsed().as_secs_f64(),
        };
        csv_text.push_str(&csv_line(&row));
        csv_text.push('\n');
        smoothed = Some(smoothed.map_or(loss, |s| 0.98 * s + 0.02 * loss));
        let mut msg = format!("loss {:.3}", smoothed.unwrap_or(loss));
        if let Some((vl, vd, vw)) = val_res {
            msg.push_str(&format!(" | val {vl:.3} δ<1.25 {vd:.3} (wta {vw:.3})"));
            progress.line(&format!(
                "step {step}: train {:.4}, val loss {vl:.4}, val δ<1.25 expected {vd:.4} wta {vw:.4}",
                smoothed.unwrap_or(loss)
            ));
        }
        progress.update(step as u64, &msg);
        if step % cfg.ckpt_every == 0 || step == last {
            let mut w = weights.clone();
            w.provenance = format!("densefeat train: step {step} of {}; {}", cfg.steps, fingerprint);
            let mut staging = Staging::new();
            let staged = RunPaths::new(&staging.dir(out)?);
            Checkpoint { step, weights: w.clone(), adam: adam.clone(), train_config: fingerprint.clone() }
                .save(&staged.checkpoint)?;
            w.save(&staged.weights)?;
            write_atomic(&staged.csv, csv_text.as_bytes())?;
            plot_curves(&staged.csv, &staged.plot)?;
            staging.commit()?;
        }
    }
    progress.finish();
    Ok(weights)
}
