//! One training pair through the network and the deeply supervised loss (SPEC.md §13.2): both
//! images through the shared network, the loss at every block output `L1..Ln` and at the
//! aggregated features `L`, each on its own level's grid, and the gradients back to the weights.

use std::time::Instant;

use ndarray::{Array2, Array3, ArrayView2, ArrayView3};
use rayon::prelude::*;

use crate::backend::CpuBackend;
use crate::error::{Error, Result};
use crate::geometry::{PinholeCamera, Pose, Warp};
use crate::nn::{ForwardOutput, NetworkWeights, PreparedNetwork};
use crate::train::backprop::{backward_prepared, forward_with_tape_prepared, Tape};
use crate::train::loss::{scale_loss_multi, LiveView, LossConfig, LossSums};
use crate::util::rng::hash64;

/// A reference and a live frame, cropped, with the reference's ground-truth depth.
#[derive(Clone, Debug)]
pub struct TrainingPair {
    /// Reference image `[H, W, 3]`, 0-255.
    pub ref_rgb: Array3<f32>,
    /// Live image `[H', W', 3]`, 0-255.
    pub live_rgb: Array3<f32>,
    /// Reference depth `[H, W]`, metres, 0 invalid.
    pub ref_depth: Array2<f32>,
    /// Reference camera (of the crop).
    pub ref_camera: PinholeCamera,
    /// Live camera (of the crop).
    pub live_camera: PinholeCamera,
    /// `T_lr`: reference camera to live camera.
    pub t_lr: Pose,
    /// Seed of the loss's pixel sampling for this pair (SPEC.md §13.1a; drawn with the pair).
    pub sample_seed: u64,
    /// Further live frames of the reference (the multi-frame loss, SPEC.md §13.1b); empty for a
    /// pair.
    pub more_lives: Vec<ExtraLive>,
}

/// A further live frame of a training tuple (SPEC.md §13.1b), cropped like the first.
#[derive(Clone, Debug)]
pub struct ExtraLive {
    /// Image `[H', W', 3]`, 0-255.
    pub rgb: Array3<f32>,
    /// Its camera (of the crop).
    pub camera: PinholeCamera,
    /// `T_lr`: reference camera to this camera.
    pub t_lr: Pose,
}

impl TrainingPair {
    /// Checks that the images, depth and cameras agree.
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] describing the mismatch.
    pub fn validate(&self) -> Result<()> {
        let (h, w, c) = self.ref_rgb.dim();
        let (hl, wl, cl) = self.live_rgb.dim();
        let extra_ok = self.more_lives.iter().all(|e| {
            let (he, we, ce) = e.rgb.dim();
            ce == 3 && (e.camera.height, e.camera.width) == (he, we)
        });
        let ok = c == 3
            && cl == 3
            && extra_ok
            && self.ref_depth.dim() == (h, w)
            && (self.ref_camera.height, self.ref_camera.width) == (h, w)
            && (self.live_camera.height, self.live_camera.width) == (hl, wl);
        if ok {
            Ok(())
        } else {
            Err(Error::invalid_argument(
                "training pair",
                format!(
                    "reference {:?}, live {:?}, depth {:?}, cameras {}x{} and {}x{} disagree",
                    self.ref_rgb.shape(),
                    self.live_rgb.shape(),
                    self.ref_depth.shape(),
                    self.ref_camera.width,
                    self.ref_camera.height,
                    self.live_camera.width,
                    self.live_camera.height
                ),
            ))
        }
    }
}

/// Which outputs are supervised and how much each scale counts.
#[derive(Clone, Copy, PartialEq)]
pub struct Supervision {
    /// Supervise every block's output (`L1..Ln`, the paper's deep supervision).
    pub deep: bool,
    /// Supervise the aggregated features (`L`).
    pub aggregated: bool,
    /// Weight of each block scale's mean in the objective (`--deep-weight`, SPEC.md §13.2); `L`
    /// keeps weight 1. 1 is the paper's; ignored without `deep`.
    pub deep_weight: f32,
}

impl Default for Supervision {
    fn default() -> Self {
        Supervision { deep: true, aggregated: true, deep_weight: 1.0 }
    }
}

impl Supervision {
    /// `L` alone (`--supervision final`).
    pub const FINAL: Supervision = Supervision { deep: false, aggregated: true, deep_weight: 1.0 };

    /// These scales with the block scales weighted `w` (`--deep-weight W`, SPEC.md §13.2): finite and
    /// in (0, 1], and only with deep supervision unless it is 1.
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] naming `--deep-weight` for a bad value or a weight without block scales.
    pub fn with_deep_weight(self, w: f64) -> Result<Self> {
        if !(w > 0.0 && w <= 1.0) {
            return Err(Error::invalid_argument(
                "--deep-weight",
                format!("{w}: expected a number in (0, 1]"),
            ));
        }
        if w != 1.0 && !self.deep {
            return Err(Error::invalid_argument(
                "--deep-weight",
                format!("{w} weighs the block scales, which --supervision final does not supervise"),
            ));
        }
        Ok(Supervision { deep_weight: w as f32, ..self })
    }
}

/// The derived form, with `deep_weight` only when it is not 1 (so the paper's configuration keeps
/// the checkpoint fingerprint it had before the field existed, SPEC.md §13.6).
impl std::fmt::Debug for Supervision {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let mut d = f.debug_struct("Supervision");
        d.field("deep", &self.deep).field("aggregated", &self.aggregated);
        if self.deep_weight != 1.0 {
            d.field("deep_weight", &self.deep_weight);
        }
        d.finish()
    }
}

/// `--supervision`: `deep` (the paper's: `L1..Ln` and `L`) or `final` (`L` alone; SPEC.md §13.2).
impl std::str::FromStr for Supervision {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        match s {
            "deep" => Ok(Supervision::default()),
            "final" => Ok(Supervision::FINAL),
            _ => Err(Error::invalid_argument("--supervision", format!("{s:?}: expected deep or final"))),
        }
    }
}

/// Loss sums of one pair: `blocks[k]` for `L_{k+1}`, `aggregated` for `L`.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PairLoss {
    /// Per block output (empty entries when deep supervision is off).
    pub blocks: Vec<LossSums>,
    /// The aggregated features.
    pub aggregated: LossSums,
}

impl PairLoss {
    /// The pair's objective: the sum over supervised scales of each scale's mean, each block
    /// scale's weighted by `sup.deep_weight` (1: the paper's plain sum, the same bits).
    pub fn total(&self, sup: &Supervision) -> f64 {
        let w = f64::from(sup.deep_weight);
        let deep: f64 = if sup.deep { self.blocks.iter().map(|s| s.mean() * w).sum() } else { 0.0 };
        deep + if sup.aggregated { self.aggregated.mean() } else { 0.0 }
    }
}

/// Ground truth at level `l`: the level-0 depth at `2^l j` (SPEC.md §2.6).
pub fn depth_at_level(depth: ArrayView2<f32>, level: usize) -> Array2<f32> {
    let (h, w) = depth.dim();
    let s = 1usize << level;
    Array2::from_shape_fn((h.div_ceil(s), w.div_ceil(s)), |(j, i)| depth[[j * s, i * s]])
}

/// The supervised scales in the fixed order `L1..Ln, L`: block index (`None` for `L`) and level.
fn scales(weights: &NetworkWeights, sup: &Supervision) -> Vec<(Option<usize>, usize)> {
    let cfg = &weights.config;
    let mut v = Vec::new();
    if sup.deep {
        for k in 0..cfg.blocks {
            v.push((Some(k), cfg.block_level(k)));
        }
    }
    if sup.aggregated {
        v.push((None, cfg.block_level(0)));
    }
    v
}

/// Wall-clock milliseconds of the stages of one [`pair_step_timed`] call (for `bench train`).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct StepTimes {
    /// Both forwards with tape.
    pub forward: f64,
    /// Each supervised scale's loss, in the order `L1..Ln, L`: (name, level, ms).
    pub losses: Vec<(String, usize, f64)>,
    /// Scaling the gradients and both backwards.
    pub backward: f64,
}

/// Milliseconds since `t`.
fn ms(t: Instant) -> f64 {
    t.elapsed().as_secs_f64() * 1e3
}

/// Forward, loss and (when `grads` is given) backward of one pair; gradients are added to
/// `grads` scaled by `grad_scale` (e.g. `1 / batch`). Deterministic for any thread count.
///
/// # Errors
/// [`Error::InvalidArgument`] for an inconsistent pair or weights.
pub fn pair_step(
    weights: &NetworkWeights,
    pair: &TrainingPair,
    loss: &LossConfig,
    sup: &Supervision,
    cpu: &CpuBackend,
    grads: Option<(&mut NetworkWeights, f32)>,
) -> Result<PairLoss> {
    pair_step_timed(weights, pair, loss, sup, cpu, grads, &mut StepTimes::default())
}

/// [`pair_step`], also recording where the time goes in `times`.
///
/// # Errors
/// As [`pair_step`].
pub fn pair_step_timed(
    weights: &NetworkWeights,
    pair: &TrainingPair,
    loss: &LossConfig,
    sup: &Supervision,
    cpu: &CpuBackend,
    grads: Option<(&mut NetworkWeights, f32)>,
    times: &mut StepTimes,
) -> Result<PairLoss> {
    let net = PreparedNetwork::new(weights, cpu)?;
    pair_step_prepared(weights, &net, pair, loss, sup, cpu, grads, times)
}

/// [`pair_step_timed`] on `weights`' layers already prepared by the CPU backend (`net`): a batch
/// prepares them once for all its pairs, so every layer is packed once per optimiser step
/// (SPEC.md §7.9, §13.6).
///
/// # Errors
/// As [`pair_step`].
#[allow(clippy::too_many_arguments)]
fn pair_step_prepared(
    weights: &NetworkWeights,
    net: &PreparedNetwork,
    pair: &TrainingPair,
    loss: &LossConfig,
    sup: &Supervision,
    cpu: &CpuBackend,
    grads: Option<(&mut NetworkWeights, f32)>,
    times: &mut StepTimes,
) -> Result<PairLoss> {
    pair.validate()?;
    *times = StepTimes::default();
    let t = Instant::now();
    // Live frames in order: the pair's own, then the further ones.
    let mut live_images = vec![(pair.live_rgb.view(), pair.live_camera, pair.t_lr)];
    live_images.extend(pair.more_lives.iter().map(|e| (e.rgb.view(), e.camera, e.t_lr)));
    // Every image's forward at once (each is deterministic on its own, so the bits do not depend
    // on how they interleave), reference first.
    let images: Vec<ArrayView3<f32>> =
        std::iter::once(pair.ref_rgb.view()).chain(live_images.iter().map(|(img, _, _)| *img)).collect();
    let mut outs = images
        .par_iter()
        .map(|img| forward_with_tape_prepared(net, *img, cpu))
        .collect::<Result<Vec<_>>>()?;
    let live_out = outs.split_off(1);
    let Some((out_r, tape_r)) = outs.pop() else { unreachable!("the reference's forward") };
    times.forward = ms(t);
    let n = weights.config.blocks;
    let n_live = live_images.len();
    let mut result = PairLoss { blocks: vec![LossSums::default(); n], aggregated: LossSums::default() };
    // Gradients per image (reference first, then the live frames) and per scale: blocks, then L.
    let mut d_blocks: Vec<Vec<Option<Array3<f32>>>> = vec![vec![None; n]; n_live + 1];
    let mut d_feat: Vec<Option<Array3<f32>>> = vec![None; n_live + 1];
    let finest = weights.config.block_level(0);
    for (index, (block, level)) in scales(weights, sup).into_iter().enumerate() {
        let t = Instant::now();
        let scale_cfg = scale_sampling(loss, finest, level, pair.sample_seed, index);
        let rc = pair.ref_camera.at_level(level as u32);
        let warps: Vec<Warp> = live_images
            .iter()
            .map(|(_, cam, t_lr)| Warp::new(&rc, &cam.at_level(level as u32), t_lr))
            .collect();
        let views: Vec<LiveView<'_, f32>> = live_out
            .iter()
            .zip(&warps)
            .map(|((o, _), warp)| LiveView { features: scale_map(o, block), warp })
            .collect();
        let depth = depth_at_level(pair.ref_depth.view(), level);
        let fr = scale_map(&out_r, block);
        let s = scale_loss_multi(&scale_cfg, fr, &views, depth.view())?;
        let name = block.map_or_else(|| "L".to_string(), |k| format!("L{}", k + 1));
        times.losses.push((name, level, ms(t)));
        let grads_of_images = std::iter::once(s.d_ref).chain(s.d_lives);
        match block {
            Some(k) => {
                result.blocks[k] = s.sums;
                for (d, g) in d_blocks.iter_mut().zip(grads_of_images) {
                    d[k] = Some(g);
                }
            }
            None => {
                result.aggregated = s.sums;
                for (d, g) in d_feat.iter_mut().zip(grads_of_images) {
                    *d = Some(g);
                }
            }
        }
    }
    let t = Instant::now();
    if let Some((g, scale)) = grads {
        // Block scales carry the deep weight (`scale * 1.0` is `scale`: the paper's bits).
        let block_scale = scale * sup.deep_weight;
        let scaled = |d: &Option<Array3<f32>>| d.as_ref().map(|a| a * scale);
        let scaled_block = |d: &Option<Array3<f32>>| d.as_ref().map(|a| a * block_scale);
        let tapes: Vec<&Tape> =
            std::iter::once(&tape_r).chain(live_out.iter().map(|(_, tape)| tape)).collect();
        // Every image's backward at once, each into its own zeroed gradients, then added to `g`
        // in image order: each parameter receives one `+=` per image, so the bits are those of
        // running them one after another into `g`.
        let per_image = tapes
            .par_iter()
            .zip(&d_blocks)
            .zip(&d_feat)
            .map(|((tape, db), df)| {
                let dr: Vec<Option<Array3<f32>>> = db.iter().map(scaled_block).collect();
                let dfr = scaled(df);
                let mut gi = weights.zeros_like();
                backward_prepared(net, weights, tape, &views(&dr), dfr.as_ref().map(|a| a.view()), &mut gi)?;
                Ok(gi)
            })
            .collect::<Result<Vec<_>>>()?;
        for gi in &per_image {
            g.add_assign(gi);
        }
    }
    times.backward = ms(t);
    Ok(result)
}

/// One optimiser step's gradients (SPEC.md §13.6): the `batch` pairs `pair(0..batch)` (made and
/// run at once, each into its own gradients scaled by `1 / batch`), then the pairs' gradients
/// added to zero in pair order. Every pair's gradients are deterministic on their own and the sum
/// has a fixed order, so the result is bit-identical for any thread count.
///
/// # Errors
/// The first error of `pair` or [`pair_step`], in pair order.
pub fn batch_step(
    weights: &NetworkWeights,
    batch: usize,
    pair: impl Fn(usize) -> Result<TrainingPair> + Sync,
    loss: &LossConfig,
    sup: &Supervision,
    cpu: &CpuBackend,
) -> Result<(Vec<PairLoss>, NetworkWeights)> {
    let scale = 1.0 / batch as f32;
    let net = PreparedNetwork::new(weights, cpu)?;
    let per_pair = (0..batch)
        .into_par_iter()
        .map(|b| {
            let p = pair(b)?;
            let mut g = weights.zeros_like();
            let mut times = StepTimes::default();
            let l = pair_step_prepared(weights, &net, &p, loss, sup, cpu, Some((&mut g, scale)), &mut times)?;
            Ok((l, g))
        })
        .collect::<Result<Vec<_>>>()?;
    let mut grads = weights.zeros_like();
    let mut losses = Vec::with_capacity(batch);
    for (l, g) in per_pair {
        grads.add_assign(&g);
        losses.push(l);
    }
    Ok((losses, grads))
}

/// The map a scale supervises: block `k`'s output, or the aggregated features (`None`).
fn scale_map(o: &ForwardOutput, block: Option<usize>) -> ArrayView3<'_, f32> {
    match block {
        Some(k) => o.blocks[k].view(),
        None => o.aggregated[0].view(),
    }
}

/// The loss configuration of one scale (SPEC.md §13.1a): `loss.sample_stride` at the finest
/// supervised level, halved per coarser level (at least 1), so every scale evaluates about the
/// same number of pixels; the offsets' seed mixes the pair's seed and the scale's index.
pub fn scale_sampling(
    loss: &LossConfig,
    finest: usize,
    level: usize,
    pair_seed: u64,
    index: usize,
) -> LossConfig {
    let stride = (loss.sample_stride >> level.saturating_sub(finest)).max(1);
    LossConfig {
        sample_stride: stride,
        sample_seed: hash64(pair_seed, index as u64, 0x7361_6d70, 0),
        ..*loss
    }
}

/// Views of optional gradients.
fn views(v: &[Option<Array3<f32>>]) -> Vec<Option<ndarray::ArrayView3<'_, f32>>> {
    v.iter().map(|o| o.as_ref().map(|a| a.view())).collect()
}
