//! One training pair through the network and the deeply supervised loss (SPEC.md §13.2): both
//! images through the shared network, the loss at every block output `L1..Ln` and at the
//! aggregated features `L`, each on its own level's grid, and the gradients back to the weights.

use std::time::Instant;

use ndarray::{Array2, Array3, ArrayView2};

use crate::backend::CpuBackend;
use crate::error::{Error, Result};
use crate::geometry::{PinholeCamera, Pose, Warp};
use crate::nn::{ForwardOutput, NetworkWeights};
use crate::synth::rng::hash64;
use crate::train::backprop::{backward, forward_with_tape};
use crate::train::loss::{scale_loss, LossConfig, LossSums};

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
}

impl TrainingPair {
    /// Checks that the images, depth and cameras agree.
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] describing the mismatch.
    pub fn validate(&self) -> Result<()> {
        let (h, w, c) = self.ref_rgb.dim();
        let (hl, wl, cl) = self.live_rgb.dim();
        let ok = c == 3
            && cl == 3
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
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Supervision {
    /// Supervise every block's output (`L1..Ln`, the paper's deep supervision).
    pub deep: bool,
    /// Supervise the aggregated features (`L`).
    pub aggregated: bool,
}

impl Default for Supervision {
    fn default() -> Self {
        Supervision { deep: true, aggregated: true }
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
    /// The pair's objective: the sum over supervised scales of each scale's mean.
    pub fn total(&self, sup: &Supervision) -> f64 {
        let deep: f64 = if sup.deep { self.blocks.iter().map(LossSums::mean).sum() } else { 0.0 };
        deep + if sup.aggregated { self.aggregated.mean() } else { 0.0 }
    }
}

/// Ground truth at level `l`: the level-0 depth at `2^l j` (SPEC.md §2.6).
pub fn depth_at_level(depth: ArrayView2<f32>, level: usize) -> Array2<f32> {
    let (h, w) = depth.dim();
    let s = 1usize << level;
    Array2::from_shape_fn((h.div_ceil(s), w.div_ceil(s)), |(j, i)| depth[[j * s, i * s]])
}

/// One supervised scale: block index (`None` for `L`), level, reference and live maps.
type Scale<'a> = (Option<usize>, usize, &'a Array3<f32>, &'a Array3<f32>);

/// The scales of a forward output, in the fixed order `L1..Ln, L`: `(level, ref map, live map)`.
fn scales<'a>(
    weights: &NetworkWeights,
    sup: &Supervision,
    r: &'a ForwardOutput,
    l: &'a ForwardOutput,
) -> Vec<Scale<'a>> {
    let cfg = &weights.config;
    let mut v = Vec::new();
    if sup.deep {
        for k in 0..cfg.blocks {
            v.push((Some(k), cfg.block_level(k), &r.blocks[k], &l.blocks[k]));
        }
    }
    if sup.aggregated {
        v.push((None, cfg.block_level(0), &r.aggregated[0], &l.aggregated[0]));
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
    pair.validate()?;
    *times = StepTimes::default();
    let t = Instant::now();
    let (out_r, tape_r) = forward_with_tape(weights, pair.ref_rgb.view(), cpu)?;
    let (out_l, tape_l) = forward_with_tape(weights, pair.live_rgb.view(), cpu)?;
    times.forward = ms(t);
    let n = weights.config.blocks;
    let mut result = PairLoss { blocks: vec![LossSums::default(); n], aggregated: LossSums::default() };
    let mut d_ref: Vec<Option<Array3<f32>>> = vec![None; n];
    let mut d_live: Vec<Option<Array3<f32>>> = vec![None; n];
    let (mut d_ref_feat, mut d_live_feat) = (None, None);
    let finest = weights.config.block_level(0);
    for (index, (block, level, fr, fl)) in scales(weights, sup, &out_r, &out_l).into_iter().enumerate() {
        let t = Instant::now();
        let scale_cfg = scale_sampling(loss, finest, level, pair.sample_seed, index);
        let rc = pair.ref_camera.at_level(level as u32);
        let lc = pair.live_camera.at_level(level as u32);
        let warp = Warp::new(&rc, &lc, &pair.t_lr);
        let depth = depth_at_level(pair.ref_depth.view(), level);
        let s = scale_loss(&scale_cfg, fr.view(), fl.view(), depth.view(), &warp)?;
        let name = block.map_or_else(|| "L".to_string(), |k| format!("L{}", k + 1));
        times.losses.push((name, level, ms(t)));
        match block {
            Some(k) => {
                result.blocks[k] = s.sums;
                d_ref[k] = Some(s.d_ref);
                d_live[k] = Some(s.d_live);
            }
            None => {
                result.aggregated = s.sums;
                d_ref_feat = Some(s.d_ref);
                d_live_feat = Some(s.d_live);
            }
        }
    }
    let t = Instant::now();
    if let Some((g, scale)) = grads {
        let scaled = |d: &Option<Array3<f32>>| d.as_ref().map(|a| a * scale);
        let dr: Vec<Option<Array3<f32>>> = d_ref.iter().map(scaled).collect();
        let dl: Vec<Option<Array3<f32>>> = d_live.iter().map(scaled).collect();
        let dfr = scaled(&d_ref_feat);
        let dfl = scaled(&d_live_feat);
        backward(weights, &tape_r, &views(&dr), dfr.as_ref().map(|a| a.view()), g)?;
        backward(weights, &tape_l, &views(&dl), dfl.as_ref().map(|a| a.view()), g)?;
    }
    times.backward = ms(t);
    Ok(result)
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
