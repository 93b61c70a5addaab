//! One frame through the normal predictor and its loss, with gradients (SPEC.md §13.11); a batch
//! of frames at once with a fixed summation order; validation.

use ndarray::{Array2, Array3};
use rayon::prelude::*;

use crate::backend::CpuBackend;
use crate::error::Result;
use crate::geometry::PinholeCamera;
use crate::mapping::normals::{normals_at_level, normals_from_depth};
use crate::nn::PreparedNetwork;
use crate::normals_net::head::{head_backward, head_forward, normal_loss, NormalLossSums};
use crate::normals_net::{NormalNet, NormalNetWeights};
use crate::train::backprop::{backward_prepared, forward_with_tape_prepared};
use crate::train::step::TrainingPair;

/// One training frame: a crop, its depth and its camera.
#[derive(Clone, Debug)]
pub struct NormalSample {
    /// Image `[H, W, 3]`, 0-255.
    pub rgb: Array3<f32>,
    /// Depth `[H, W]`, metres, 0 invalid.
    pub depth: Array2<f32>,
    /// Camera of the crop.
    pub camera: PinholeCamera,
}

impl From<TrainingPair> for NormalSample {
    /// The pair's reference crop (its augmentation included); the live frame is not used.
    fn from(p: TrainingPair) -> Self {
        NormalSample { rgb: p.ref_rgb, depth: p.ref_depth, camera: p.ref_camera }
    }
}

impl NormalSample {
    /// Ground-truth normals at pyramid level `level`: [`normals_from_depth`] on the crop at level
    /// 0, then level-`level` pixel `j` = level-0 pixel `2^level j` ([`normals_at_level`]).
    pub fn gt_normals(&self, level: u32) -> Array3<f32> {
        normals_at_level(normals_from_depth(&self.depth, &self.camera).view(), level)
    }
}

/// The frame's loss with raw-norm floor `floor` ([`crate::normals_net::head::pixel_terms`]); with
/// `grads = Some((g, weight))`, adds the gradient of `weight · mean ℓ` to
/// `g`: the loss's gradient at the head's output, the head's backward into `g.head` and
/// `d_features`, then [`backward_prepared`] through the trunk into `g.trunk` (the trunk prepared
/// once for both passes).
///
/// # Errors
/// [`crate::Error::InvalidArgument`] for mismatched shapes.
pub fn sample_step(
    weights: &NormalNetWeights,
    sample: &NormalSample,
    cpu: &CpuBackend,
    grads: Option<(&mut NormalNetWeights, f64)>,
    floor: f64,
) -> Result<NormalLossSums> {
    let trunk = PreparedNetwork::new(&weights.trunk, cpu)?;
    sample_step_prepared(&trunk, weights, sample, cpu, grads, floor)
}

/// [`sample_step`] with the trunk already prepared (`trunk` of `weights.trunk`; a batch shares one).
fn sample_step_prepared(
    trunk: &PreparedNetwork,
    weights: &NormalNetWeights,
    sample: &NormalSample,
    cpu: &CpuBackend,
    grads: Option<(&mut NormalNetWeights, f64)>,
    floor: f64,
) -> Result<NormalLossSums> {
    let level = weights.trunk.config.block_level(0) as u32;
    let camera = sample.camera.at_level(level);
    let gt = sample.gt_normals(level);
    let (out, tape) = forward_with_tape_prepared(trunk, sample.rgb.view(), cpu)?;
    let features = &out.aggregated[0];
    let raw = head_forward(&weights.head, features.view())?;
    let weight = grads.as_ref().map_or(1.0, |g| g.1);
    let (sums, d_raw) = normal_loss(raw.view(), gt.view(), &camera, weight, floor)?;
    if let Some((g, _)) = grads {
        let (d_features, d_head) = head_backward(&weights.head, features.view(), d_raw.view())?;
        g.head.weight += &d_head.weight;
        g.head.bias += &d_head.bias;
        let d_blocks = vec![None; weights.trunk.config.blocks];
        backward_prepared(trunk, &weights.trunk, &tape, &d_blocks, Some(d_features.view()), &mut g.trunk)?;
    }
    Ok(sums)
}

/// One optimiser step's frames at once: frame `b` from `sample(b)`, each into its own zeroed
/// gradient with weight `1/batch`, the gradients added to zero in frame order (bit-identical for
/// any thread count). Returns each frame's sums and the batch gradient (of the mean over frames
/// of each frame's mean loss).
///
/// # Errors
/// As [`sample_step`] and `sample`.
pub fn normals_batch_step(
    weights: &NormalNetWeights,
    batch: usize,
    sample: impl Fn(usize) -> Result<NormalSample> + Sync,
    cpu: &CpuBackend,
    floor: f64,
) -> Result<(Vec<NormalLossSums>, NormalNetWeights)> {
    let weight = 1.0 / batch as f64;
    // One preparation of the trunk for every frame of the step.
    let trunk = PreparedNetwork::new(&weights.trunk, cpu)?;
    let per = (0..batch)
        .into_par_iter()
        .map(|b| {
            let s = sample(b)?;
            let mut g = weights.zeros_like();
            let l = sample_step_prepared(&trunk, weights, &s, cpu, Some((&mut g, weight)), floor)?;
            Ok((l, g))
        })
        .collect::<Result<Vec<_>>>()?;
    let mut grads = weights.zeros_like();
    let mut losses = Vec::with_capacity(batch);
    for (l, g) in per {
        grads.add_assign(&g);
        losses.push(l);
    }
    Ok((losses, grads))
}

/// Validation: the mean over frames of each frame's mean loss (of the unit predictions, no floor),
/// and the mean angular error
/// (degrees) over every valid pixel of every frame. The frames run at once, their sums are taken
/// in frame order.
///
/// # Errors
/// As [`NormalNet::head_normals`].
pub fn validate_normals(weights: &NormalNetWeights, samples: &[NormalSample]) -> Result<(f64, f64)> {
    let net = NormalNet::new(weights.clone())?;
    let level = net.level();
    let per = samples
        .par_iter()
        .map(|s| {
            let n = net.head_normals(s.rgb.view(), &s.camera)?;
            let (sums, _) =
                normal_loss(n.view(), s.gt_normals(level).view(), &s.camera.at_level(level), 1.0, 0.0)?;
            Ok(sums)
        })
        .collect::<Result<Vec<_>>>()?;
    let mut all = NormalLossSums::default();
    let mut loss = 0.0;
    for s in &per {
        loss += s.mean();
        all.accumulate(s);
    }
    Ok((loss / samples.len().max(1) as f64, all.mean_angle_deg()))
}
