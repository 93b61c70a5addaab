//! One keyframe's dense reconstruction (SPEC.md §11): load the keyframe and a window of live frames,
//! extract features on the common level-`L` grid, stream the live frames into a cost volume,
//! take the winner-take-all depth and, with [`Regularizer::Tv`], regularise it with DTAM.
//!
//! Memory: only the keyframe's and one live frame's images and features are held at a time (plus,
//! in `map`, the features kept for the next keyframes by [`reconstruct_cached`], within what the
//! limit leaves); the volume's `[H_L, W_L, K]` sums, counts and the costs copy DTAM reads dominate
//! and are estimated up front ([`memory_estimate`]).

use std::borrow::Cow;
use std::sync::Arc;
use std::time::Instant;

use ndarray::Array2;
use rayon::prelude::*;
use serde::Serialize;

use crate::backend::Backend;
use crate::costvolume::{check_evidence_fraction, check_truncation, NO_TRUNCATION};
use crate::dtam::SlopeField;
use crate::dtam::{DtamParams, DtamProblem, DtamReport, DtamResult};
use crate::error::{Error, Result};
use crate::eval::{depth_metrics, DepthMetrics};
use crate::geometry::{relative_pose, InverseDepthBins, PinholeCamera};
use crate::image::{to_gray, DepthMap, RgbImage};
use crate::mapping::feature_cache::FeatureCache;
use crate::mapping::normals::{self, NormalsSource};
use crate::mapping::photometric::{self, PhotometricFit, PhotometricMode};
use crate::mapping::refine::{self, RefineParams, RefineReport, RefineView};
use crate::mapping::resample::downsample_to_at;
use crate::mapping::{FeatureExtractor, FeatureKind};
use crate::sequence::Sequence;

/// Which regulariser runs after winner-take-all.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub enum Regularizer {
    /// Winner-take-all only.
    None,
    /// Winner-take-all, then DTAM's Huber-TV solve initialised by it (SPEC.md §10).
    Tv,
    /// Winner-take-all, then DTAM with the surface-normal prior (SPEC.md §10.2); needs
    /// [`KeyframeConfig::normals`].
    Normals,
    /// Both solves on the same volume (what `eval` runs for `-tv` and `-normals` methods of one
    /// feature kind; not a `--regularizer` value).
    TvAndNormals,
    /// Winner-take-all, then DTAM with second-order TGV in place of Huber-TV (SPEC.md §10.4), of
    /// weight [`KeyframeConfig::tgv_beta`]; its result takes Huber-TV's place.
    Tgv,
}

impl Regularizer {
    /// Whether the Huber-TV solve runs (with [`Regularizer::Tgv`], TGV in its place).
    pub fn tv(self) -> bool {
        matches!(self, Regularizer::Tv | Regularizer::TvAndNormals | Regularizer::Tgv)
    }

    /// Whether the normal-prior solve runs.
    pub fn normals(self) -> bool {
        matches!(self, Regularizer::Normals | Regularizer::TvAndNormals)
    }

    /// The default regulariser of a feature kind in `reconstruct` and `demo` (SPEC.md §10.1a),
    /// chosen on the validation scenes like its `λ`: the learned features take the surface-normal
    /// prior when a normal source is available (`has_normals`), every other kind (and the learned
    /// features without normals) Huber-TV. `map` keeps Huber-TV (chosen there by mesh F-score).
    pub fn default_for(features: &FeatureKind, has_normals: bool) -> Self {
        match features {
            FeatureKind::Learned(_) if has_normals => Regularizer::Normals,
            _ => Regularizer::Tv,
        }
    }
}

impl std::str::FromStr for Regularizer {
    type Err = Error;

    /// `none`, `tv`, `normals` or `tgv`.
    fn from_str(s: &str) -> Result<Self> {
        match s {
            "none" => Ok(Regularizer::None),
            "tv" => Ok(Regularizer::Tv),
            "normals" => Ok(Regularizer::Normals),
            "tgv" => Ok(Regularizer::Tgv),
            _ => Err(Error::invalid_argument(
                "--regularizer",
                format!("{s:?}: expected none, tv, normals or tgv"),
            )),
        }
    }
}

/// Per-frame cost truncation `τ` per feature kind (SPEC.md §9.13): each live frame adds
/// `min(l1, τ)` to a cell, so a frame in which the reference pixel is occluded or specular adds at
/// most `τ` to the wrong hypothesis (OpenDTAM's L1T). In the feature's own cost units (the L1 over
/// its channels); [`NO_TRUNCATION`] is the plain L1.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Truncation {
    /// `τ` for RGB, grey levels summed over the three channels.
    pub rgb: f32,
    /// `τ` for learned features (any weights), L1 over their channels.
    pub learned: f32,
    /// `τ` for block-1 features (any weights), L1 over their channels (SPEC.md §9a.1).
    pub b1: f32,
    /// `τ` for dense SIFT, L1 over its 128 channels in the descriptor's units (SPEC.md §9a.2).
    pub dsift: f32,
    /// `τ` for 7x7 patches, L1 of the mean-removed patches in grey levels (SPEC.md §9a.5).
    pub patch7: f32,
}

impl Truncation {
    /// The defaults (none for every kind), chosen on validation and training scenes (SPEC.md §9.13,
    /// §9a.3).
    pub const DEFAULT: Self = Self {
        rgb: DEFAULT_TRUNCATION_RGB,
        learned: DEFAULT_TRUNCATION_LEARNED,
        b1: DEFAULT_TRUNCATION_B1,
        dsift: DEFAULT_TRUNCATION_DSIFT,
        patch7: DEFAULT_TRUNCATION_PATCH7,
    };
    /// No truncation for any kind.
    pub const NONE: Self = Self {
        rgb: NO_TRUNCATION,
        learned: NO_TRUNCATION,
        b1: NO_TRUNCATION,
        dsift: NO_TRUNCATION,
        patch7: NO_TRUNCATION,
    };

    /// `τ` for `kind`.
    pub fn of(&self, kind: &FeatureKind) -> f32 {
        match kind {
            FeatureKind::Rgb => self.rgb,
            FeatureKind::Learned(_) => self.learned,
            FeatureKind::B1(_) => self.b1,
            FeatureKind::Dsift => self.dsift,
            FeatureKind::Patch7 => self.patch7,
        }
    }
}

/// Default RGB truncation: none (SPEC.md §9.13: it helped one real scene and hurt two others).
pub const DEFAULT_TRUNCATION_RGB: f32 = NO_TRUNCATION;
/// Default learned-feature truncation: none (SPEC.md §9.13: it lowered δ on the real validation
/// scene).
pub const DEFAULT_TRUNCATION_LEARNED: f32 = NO_TRUNCATION;
/// Default block-1 truncation: none, as for the learned features (SPEC.md §9a.3).
pub const DEFAULT_TRUNCATION_B1: f32 = NO_TRUNCATION;
/// Default dense-SIFT truncation: none (SPEC.md §9a.3).
pub const DEFAULT_TRUNCATION_DSIFT: f32 = NO_TRUNCATION;
/// Default 7x7-patch truncation: none (SPEC.md §9a.3).
pub const DEFAULT_TRUNCATION_PATCH7: f32 = NO_TRUNCATION;

/// Everything [`reconstruct`] needs.
#[derive(Clone, Debug)]
pub struct KeyframeConfig {
    /// Index of the keyframe in the sequence.
    pub keyframe: usize,
    /// Live frames before the keyframe (the paper: 30).
    pub past: usize,
    /// Live frames after the keyframe (the paper: 30).
    pub future: usize,
    /// What fills the cost volume.
    pub features: FeatureKind,
    /// Nearest depth hypothesis, metres.
    pub near: f64,
    /// Farthest depth hypothesis, metres.
    pub far: f64,
    /// Number of inverse-depth hypotheses `K`.
    pub bins: usize,
    /// Regulariser after winner-take-all.
    pub regularizer: Regularizer,
    /// Where the normal prior's normals come from (`--normals`; needed by [`Regularizer::Normals`]).
    pub normals: Option<NormalsSource>,
    /// DTAM parameters in the normalised units of [`DtamParams::normalised`] (used with
    /// [`Regularizer::Tv`]; the normal prior's solve takes them with [`KeyframeConfig::lambda_normals`]).
    pub dtam: DtamParams,
    /// `λ` of the normal prior's solve ([`Regularizer::Normals`]), which wants its own (SPEC.md
    /// §10.1a): every other DTAM parameter is [`KeyframeConfig::dtam`]'s.
    pub lambda_normals: f64,
    /// TGV's `β` ([`Regularizer::Tgv`], SPEC.md §10.4), in pixels at [`crate::dtam::REFERENCE_WIDTH`].
    pub tgv_beta: f64,
    /// Refuse to start when [`memory_estimate`] exceeds this many MiB.
    pub max_memory_mb: usize,
    /// Pyramid level of the output grid (0 = the input resolution).
    pub level: u32,
    /// Evidence minimum: a cell competes (in WTA and the a-search) only when at least this
    /// fraction of the frames that saw the pixel at all saw it (SPEC.md §9.10). 0 keeps every seen
    /// cell.
    pub min_evidence: f64,
    /// Extra `λ` values: DTAM also runs at each on the same volume ([`KeyframeResult::sweep`]).
    pub lambda_sweep: Vec<f64>,
    /// Where every op runs (network, cost volume, WTA, DTAM; SPEC.md §15).
    pub backend: Arc<dyn Backend>,
    /// Photometric calibration of the window before matching (SPEC.md §11.9).
    pub photometric: PhotometricMode,
    /// Per-frame cost truncation per feature kind (SPEC.md §9.13).
    pub truncation: Truncation,
    /// The border taper of the data term (SPEC.md §10.1c), in level-0 pixels: after winner-take-all
    /// each pixel's costs are scaled by [`crate::costvolume::border_weight`], so the regulariser fills a strip along the
    /// keyframe's border from the interior. 0: off; `None` (the default): the feature kind's
    /// [`FeatureKind::default_border_taper`].
    pub border_taper: Option<f64>,
    /// `c₀` of the normal prior's confidence weighting (SPEC.md §10.2): each pixel's slope is
    /// scaled by `clamp(conf / c₀, 0, 1)`. 0: off; `None` (the default): the feature kind's
    /// [`FeatureKind::default_prior_confidence`].
    pub prior_confidence: Option<f64>,
    /// `σ` (degrees) of the normal prior's normal edges (SPEC.md §10.2): DTAM's `g` is multiplied by
    /// `exp(−(a/σ)²)`, `a` the angle between a pixel's normal and its forward neighbours'. 0: off;
    /// `None` (the default): the feature kind's [`FeatureKind::default_prior_edges`].
    pub prior_edges: Option<f64>,
    /// Photometric sub-bin refinement of the regularised estimates (SPEC.md §10.3); `None`: off
    /// (the default; `map` turns it on, §16.9).
    pub refine: Option<RefineParams>,
}

/// Default of [`KeyframeConfig::bins`].
pub const DEFAULT_BINS: usize = 128;

/// Default of [`KeyframeConfig::min_evidence`] (chosen on validation scenes, SPEC.md §9.10).
pub const DEFAULT_MIN_EVIDENCE: f64 = 0.25;

/// Default of [`KeyframeConfig::max_memory_mb`].
pub const DEFAULT_MAX_MEMORY_MB: usize = crate::memory::DEFAULT_MAX_MEMORY_MB;

impl KeyframeConfig {
    /// The paper's window (30, 30), RGB, [`DEFAULT_BINS`] bins over `[near, far]`, level 0, TV with
    /// default parameters.
    pub fn new(keyframe: usize, near: f64, far: f64) -> Self {
        Self {
            keyframe,
            past: 30,
            future: 30,
            features: FeatureKind::Rgb,
            near,
            far,
            bins: DEFAULT_BINS,
            regularizer: Regularizer::Tv,
            normals: None,
            dtam: crate::dtam::MAPPING_DEFAULTS,
            lambda_normals: crate::dtam::MAPPING_DEFAULTS.lambda,
            tgv_beta: crate::dtam::tgv::DEFAULT_BETA,
            max_memory_mb: DEFAULT_MAX_MEMORY_MB,
            level: 0,
            min_evidence: DEFAULT_MIN_EVIDENCE,
            lambda_sweep: Vec::new(),
            backend: crate::backend::default_backend(),
            photometric: PhotometricMode::None,
            truncation: Truncation::DEFAULT,
            border_taper: None,
            prior_confidence: None,
            prior_edges: None,
            refine: None,
        }
    }

    /// The live frames of the window `[keyframe - past, keyframe + future]` clamped to the
    /// sequence, keyframe excluded, in index order.
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] if the keyframe is out of range or no live frame remains.
    pub fn live_frames(&self, len: usize) -> Result<Vec<usize>> {
        if self.keyframe >= len {
            return Err(Error::invalid_argument(
                "keyframe",
                format!("{} is out of range: the sequence has {len} frames", self.keyframe),
            ));
        }
        let first = self.keyframe.saturating_sub(self.past);
        let last = self.keyframe.saturating_add(self.future).min(len - 1);
        let live: Vec<usize> = (first..=last).filter(|&i| i != self.keyframe).collect();
        if live.is_empty() {
            return Err(Error::invalid_argument(
                "window",
                format!(
                    "{},{} around keyframe {} of a {len}-frame sequence leaves no live frame",
                    self.past, self.future, self.keyframe
                ),
            ));
        }
        Ok(live)
    }

    /// The border taper `R` in effect (SPEC.md §10.1c), in level-0 pixels: [`KeyframeConfig::border_taper`],
    /// else the feature kind's default.
    pub fn border_taper_px(&self) -> f64 {
        self.border_taper.unwrap_or_else(|| self.features.default_border_taper())
    }

    /// The normal prior's confidence weighting `c₀` in effect (SPEC.md §10.2):
    /// [`KeyframeConfig::prior_confidence`], else the feature kind's default.
    pub fn prior_confidence_c0(&self) -> f64 {
        self.prior_confidence.unwrap_or_else(|| self.features.default_prior_confidence())
    }

    /// The normal prior's normal-edge scale `σ` in effect (SPEC.md §10.2), in degrees:
    /// [`KeyframeConfig::prior_edges`], else the feature kind's default.
    pub fn prior_edges_deg(&self) -> f64 {
        self.prior_edges.unwrap_or_else(|| self.features.default_prior_edges())
    }

    fn validate(&self) -> Result<InverseDepthBins> {
        if self.bins < 2 {
            return Err(Error::invalid_argument("bins", format!("{}: need at least 2", self.bins)));
        }
        if let Some(p) = &self.refine {
            p.validate()?;
        }
        if self.regularizer != Regularizer::None {
            self.dtam.validate()?;
        }
        if self.regularizer.normals() {
            DtamParams { lambda: self.lambda_normals, ..self.dtam }.validate()?;
        }
        if self.regularizer == Regularizer::Tgv {
            crate::dtam::tgv::check_beta(self.tgv_beta)?;
        }
        if self.regularizer.normals() && self.normals.is_none() {
            return Err(Error::invalid_argument(
                "--regularizer normals",
                "needs --normals learned (the built-in predictor: the command line's default), --normals \
                 gt (from the keyframe's ground-truth depth) or --normals DIR (NNNNN.npy normal maps)",
            ));
        }
        check_evidence_fraction(self.min_evidence)?;
        if self.level > 8 {
            return Err(Error::invalid_argument("level", format!("{}: at most 8", self.level)));
        }
        if let Some(r) = self.border_taper.filter(|r| !(*r >= 0.0 && r.is_finite())) {
            return Err(Error::invalid_argument(
                "border-taper",
                format!("{r}: must be a finite number of pixels >= 0"),
            ));
        }
        if let Some(c0) = self.prior_confidence {
            crate::dtam::normal_prior::check_prior_confidence(c0)?;
        }
        if let Some(sigma) = self.prior_edges {
            crate::dtam::normal_prior::check_prior_edges(sigma)?;
        }
        check_truncation("truncate-rgb", self.truncation.rgb)?;
        check_truncation("truncate-learned", self.truncation.learned)?;
        check_truncation("truncate-b1", self.truncation.b1)?;
        check_truncation("truncate-dsift", self.truncation.dsift)?;
        check_truncation("truncate-patch7", self.truncation.patch7)?;
        if let Some(l) = self.lambda_sweep.iter().find(|l| !(**l > 0.0 && l.is_finite())) {
            return Err(Error::invalid_argument("lambda-sweep", format!("λ = {l}: must be positive")));
        }
        InverseDepthBins::from_depth_range(self.near, self.far, self.bins)
    }
}

/// Bytes [`reconstruct`] needs for a `height x width` grid with `bins` hypotheses and `channels`
/// feature channels: `H·W·K·(4 + 4 + 2)` (f32 sums, the f32 costs copy DTAM reads, u16 counts),
/// `H·W·⌈K/8⌉·4` (DTAM's block minima, SPEC.md §10.1) plus two feature maps `2·H·W·C·4` (keyframe
/// and the live frame being added): [`crate::memory::cost_volume_bytes`].
pub fn memory_estimate(height: usize, width: usize, bins: usize, channels: usize) -> u64 {
    crate::memory::cost_volume_bytes(height, width, bins, channels)
}

/// A depth estimate on the level-`L` grid.
///
/// [`KeyframeResult::confidence`] applies to both estimates of a keyframe.
#[derive(Clone, Debug)]
pub struct DepthEstimate {
    /// Inverse depth, 1/m.
    pub inverse_depth: Array2<f32>,
    /// Depth, metres; 0 where invalid (SPEC.md §2.2).
    pub depth: Array2<f32>,
}

/// Wall time of each stage, seconds. Loading and feature extraction are summed over frames.
#[derive(Clone, Copy, Debug, Default, Serialize)]
pub struct StageTimings {
    /// Reading and decoding images and depth.
    pub load: f64,
    /// Feature extraction (network forward or tent downsampling).
    pub features: f64,
    /// Adding the live frames to the cost volume.
    pub cost_volume: f64,
    /// Winner-take-all.
    pub wta: f64,
    /// DTAM's Huber-TV solve (0 without it).
    pub tv: f64,
    /// The surface-normal prior: the keyframe's normals (prediction or file) and its DTAM solve
    /// (0 without it).
    pub normals: f64,
    /// Photometric calibration (0 without it).
    pub photometric: f64,
    /// The photometric sub-bin refinement (0 without it; its frames are read by the cost-volume loop).
    pub refine: f64,
}

impl StageTimings {
    /// Sum of the stages.
    pub fn total(&self) -> f64 {
        self.load
            + self.features
            + self.cost_volume
            + self.wta
            + self.tv
            + self.normals
            + self.photometric
            + self.refine
    }
}

/// Stages reported to the progress callback.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Stage {
    /// Loading the keyframe and extracting its features.
    Keyframe,
    /// Loading, extracting and adding live frames (`done` of `total` frames).
    CostVolume,
    /// Winner-take-all.
    Wta,
    /// DTAM.
    Tv,
}

impl std::fmt::Display for Stage {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Stage::Keyframe => "keyframe",
            Stage::CostVolume => "cost volume",
            Stage::Wta => "winner-take-all",
            Stage::Tv => "DTAM",
        })
    }
}

/// What [`reconstruct`] returns; every map is on the level-`L` grid.
#[derive(Clone, Debug)]
pub struct KeyframeResult {
    /// The keyframe's index.
    pub keyframe: usize,
    /// Indices of the live frames used.
    pub live_frames: Vec<usize>,
    /// Feature name (`rgb`, `learned`, `b1`, `dsift` or `patch7`).
    pub features: &'static str,
    /// Pyramid level of the grid.
    pub level: u32,
    /// The level-`L` camera (SPEC.md §2.6).
    pub camera: PinholeCamera,
    /// The hypotheses.
    pub bins: InverseDepthBins,
    /// The keyframe's colour at level `L` (tent-downsampled), `[H_L, W_L, 3]`, 0-255.
    pub colour: RgbImage,
    /// Pixels with at least one seen hypothesis; both estimates are 0 elsewhere.
    pub valid: Array2<bool>,
    /// Winner-take-all.
    pub wta: DepthEstimate,
    /// DTAM's Huber-TV result, with [`Regularizer::Tv`] (or `TvAndNormals`); TGV's with
    /// [`Regularizer::Tgv`] ([`KeyframeResult::tgv`]).
    pub tv: Option<DepthEstimate>,
    /// Whether [`KeyframeResult::tv`] is TGV's result (SPEC.md §10.4).
    pub tgv: bool,
    /// DTAM's result with the normal prior, with [`Regularizer::Normals`] (or `TvAndNormals`).
    pub normals: Option<DepthEstimate>,
    /// Ground truth at level `L` (level-0 depth at pixels `2^L j`), if the keyframe has depth.
    pub gt_depth: Option<DepthMap>,
    /// Wall time per stage.
    pub timings: StageTimings,
    /// DTAM's report: the Huber-TV solve's, else the normal-prior solve's.
    pub dtam: Option<DtamReport>,
    /// The normal-prior solve's report and the pixels whose prior fell back to TV (no normal or
    /// grazing; SPEC.md §10.2).
    pub normals_dtam: Option<(DtamReport, usize)>,
    /// With `--normals learned` and ground-truth depth: the predicted normals' angular error
    /// against [`normals::normals_from_depth`]'s at level 0 (SPEC.md §13.11).
    pub normals_error: Option<normals::NormalsError>,
    /// Per-pixel confidence in `[0, 1]` (SPEC.md §9.12).
    pub confidence: Array2<f32>,
    /// The cost scale `s` of the volume (SPEC.md §9.11); DTAM weights the data term by `1/(λ s)`.
    pub cost_scale: f64,
    /// DTAM at each [`KeyframeConfig::lambda_sweep`] value, in that order.
    pub sweep: Vec<(f64, DepthEstimate)>,
    /// [`memory_estimate`] of this run plus the refinement's [`refine::memory_bytes`] when it runs, bytes.
    pub memory_estimate: u64,
    /// The photometric fit used (the identity without calibration).
    pub photometric: PhotometricFit,
    /// The per-frame truncation `τ` the volume was built with ([`NO_TRUNCATION`] for none).
    pub truncation: f32,
    /// What the photometric refinement did (SPEC.md §10.3), when it ran: the report of the last
    /// estimate it refined (`tv`, then `normals`).
    pub refined: Option<RefineReport>,
}

impl KeyframeResult {
    /// The name of [`KeyframeResult::tv`]'s estimate in file names and reports: `tv` or `tgv`.
    pub fn tv_name(&self) -> &'static str {
        if self.tgv {
            "tgv"
        } else {
            "tv"
        }
    }

    /// The regularised estimate if there is one, else winner-take-all.
    pub fn best(&self) -> &DepthEstimate {
        self.regularised().unwrap_or(&self.wta)
    }

    /// The normal-prior estimate if there is one, else the Huber-TV one.
    pub fn regularised(&self) -> Option<&DepthEstimate> {
        self.normals.as_ref().or(self.tv.as_ref())
    }

    /// Metrics of an estimate against the ground truth.
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] if the keyframe has no ground truth, or no pixel is valid in both.
    pub fn metrics(&self, estimate: &DepthEstimate) -> Result<DepthMetrics> {
        let gt = self.gt_depth.as_ref().ok_or_else(|| {
            Error::invalid_argument(
                "evaluation",
                format!("keyframe {} has no ground-truth depth to evaluate against", self.keyframe),
            )
        })?;
        depth_metrics(estimate.depth.view(), gt.view())
    }

    /// [`KeyframeResult::metrics`] of the estimate with pixels below `min_confidence` masked out
    /// (coverage then counts them as missing).
    ///
    /// # Errors
    /// As [`KeyframeResult::metrics`].
    pub fn metrics_at(&self, estimate: &DepthEstimate, min_confidence: f32) -> Result<DepthMetrics> {
        self.metrics(&self.masked(estimate, min_confidence))
    }

    /// The estimate with depth 0 where the confidence is below `min_confidence`.
    pub fn masked(&self, estimate: &DepthEstimate, min_confidence: f32) -> DepthEstimate {
        let mut e = estimate.clone();
        ndarray::Zip::from(&mut e.depth).and(&self.confidence).for_each(|z, &c| {
            if c < min_confidence {
                *z = 0.0;
            }
        });
        e
    }
}

/// The level-`level` ground truth: level-0 depth at pixels `2^level j` (SPEC.md §2.6).
pub fn depth_at_level(depth: &DepthMap, level: u32) -> DepthMap {
    let (h, w) = depth.dim();
    let s = 1usize << level;
    Array2::from_shape_fn((h.div_ceil(s), w.div_ceil(s)), |(y, x)| depth[[y * s, x * s]])
}

/// Reconstruct one keyframe. `progress(stage, done, total)` is called as work completes.
///
/// # Errors
/// [`Error::InvalidArgument`] for a keyframe out of range, a window with no live frame,
/// `near >= far`, fewer than 2 bins, bad DTAM parameters, or a memory estimate above
/// `max_memory_mb`; loading and shape errors naming the file.
pub fn reconstruct(
    seq: &Sequence,
    cfg: &KeyframeConfig,
    progress: impl FnMut(Stage, usize, usize),
) -> Result<KeyframeResult> {
    cfg.validate()?;
    let extractor = FeatureExtractor::new(cfg.features.clone(), cfg.level, cfg.backend.clone())?;
    reconstruct_with(seq, cfg, &extractor, progress)
}

/// [`reconstruct`] with a feature extractor built once for many keyframes (`map`, `eval`): it must
/// extract `cfg.features` on `cfg.level`'s grid, so the weights are read and the network built once
/// per run instead of once per keyframe. The same bits as [`reconstruct`].
///
/// # Errors
/// As [`reconstruct`]; [`Error::InvalidArgument`] if the extractor's kind or level is not the
/// configuration's.
pub fn reconstruct_with(
    seq: &Sequence,
    cfg: &KeyframeConfig,
    extractor: &FeatureExtractor,
    progress: impl FnMut(Stage, usize, usize),
) -> Result<KeyframeResult> {
    reconstruct_cached(seq, cfg, extractor, &mut FeatureCache::new(0), progress)
}

/// [`reconstruct_with`] taking frames' features from `cache` and leaving its own there for the next
/// keyframes (`map`, SPEC.md §16.12): the cache is sized to what `max_memory_mb` leaves beside this
/// keyframe's own work. The same bits as [`reconstruct`].
///
/// # Errors
/// As [`reconstruct_with`].
pub fn reconstruct_cached(
    seq: &Sequence,
    cfg: &KeyframeConfig,
    extractor: &FeatureExtractor,
    cache: &mut FeatureCache,
    mut progress: impl FnMut(Stage, usize, usize),
) -> Result<KeyframeResult> {
    let bins = cfg.validate()?;
    let live = cfg.live_frames(seq.len())?;
    let level = cfg.level;
    if extractor.kind() != &cfg.features || extractor.level() != level {
        return Err(Error::invalid_argument(
            "features",
            format!(
                "the extractor makes {} features at level {}, the configuration asks for {} at level {level}",
                extractor.name(),
                extractor.level(),
                cfg.features.name()
            ),
        ));
    }
    // The keyframe's camera; each live frame is warped into its own (SPEC.md §9.1).
    let key_camera = seq.frame_camera(cfg.keyframe); // in range: `live_frames` checked it
    let camera = key_camera.at_level(level);
    let backend = cfg.backend.as_ref();
    let mut timings = StageTimings::default();
    progress(Stage::Keyframe, 0, 1);
    let t = Instant::now();
    let key = seq.load_frame(cfg.keyframe)?;
    timings.load += t.elapsed().as_secs_f64();
    let t = Instant::now();
    // The normals before any heavy work: a bad file is reported at once.
    let (slope, normals_error) = match (&cfg.normals, cfg.regularizer.normals()) {
        (Some(source), true) => {
            let n0 = normals::keyframe_normals_level0(
                source,
                seq,
                cfg.keyframe,
                key.rgb.view(),
                key.depth.as_ref(),
                &key_camera,
            )?;
            // The predictor's angular error against the ground truth's normals (SPEC.md §13.11).
            let error = match (source, key.depth.as_ref()) {
                (NormalsSource::Learned(_), Some(d)) => normals::normals_error(n0.view(), d, &key_camera),
                _ => None,
            };
            let n = normals::normals_at_level(n0.view(), level);
            (
                Some(SlopeField::new(n.view(), &camera)?.with_normal_edges(n.view(), cfg.prior_edges_deg())?),
                error,
            )
        }
        _ => (None, None),
    };
    timings.normals += t.elapsed().as_secs_f64();
    let t = Instant::now();
    let (key_features, key_was_cached) = match cache.get(cfg.keyframe) {
        Some(f) => (f.clone(), true),
        None => (extractor.extract(&key.rgb)?.data, false),
    };
    timings.features += t.elapsed().as_secs_f64();
    let channels = key_features.dim().2;
    // The refinement (SPEC.md §10.3) runs while the volume is still held: its images and planes count
    // too (the live frames at the keyframe's size).
    let refine_bytes = cfg
        .refine
        .as_ref()
        .map_or(0, |p| refine::memory_bytes(key_camera.height, key_camera.width, p.frames.min(live.len())));
    let estimate = memory_estimate(camera.height, camera.width, cfg.bins, channels) + refine_bytes;
    let limit = cfg.max_memory_mb as u64 * 1024 * 1024;
    if estimate > limit {
        let refine_note = if refine_bytes > 0 {
            format!(
                " (the photometric refinement's {} MiB included; --refine off drops it)",
                refine_bytes.div_ceil(1024 * 1024)
            )
        } else {
            String::new()
        };
        return Err(Error::invalid_argument(
            "max-memory-mb",
            format!(
                "the cost volume {}x{}x{} with {channels} feature channels needs about {} MiB{refine_note}, over \
                 the limit of {} MiB: use fewer --bins, a coarser --level, or raise --max-memory-mb",
                camera.height,
                camera.width,
                cfg.bins,
                estimate.div_ceil(1024 * 1024),
                cfg.max_memory_mb
            ),
        ));
    }
    // What the limit leaves beside this keyframe's work holds the features of frames for the next.
    cache.fit(4 * key_features.len() as u64, limit - estimate);
    if !key_was_cached {
        cache.offer(cfg.keyframe, &key_features);
    }
    let photo = if cfg.photometric == PhotometricMode::None {
        PhotometricFit::identity(live.len())
    } else {
        let t = Instant::now();
        // After the memory check: each live frame is loaded and reduced to the coarse level at
        // once (only the coarse images are kept; the volume loop loads them again).
        let lc = photometric::coarse_level(&key_camera, level);
        let coarse = |rgb: &RgbImage| downsample_to_at(rgb.view(), lc, backend.cpu_level());
        let all = live
            .par_iter()
            .map(|&m| seq.load_frame_rgb(m).and_then(|f| Ok((coarse(&f.rgb)?, f.pose, f.camera))))
            .collect::<Result<Vec<_>>>()?;
        let fit = photometric::fit((&coarse(&key.rgb)?, &key.pose), &all, &key_camera, &bins, lc)?;
        timings.photometric = t.elapsed().as_secs_f64();
        fit
    };
    let colour = downsample_to_at(key.rgb.view(), level, backend.cpu_level())?;
    let gt_depth = key.depth.as_ref().map(|d| depth_at_level(d, level));
    progress(Stage::Keyframe, 1, 1);

    let truncation = cfg.truncation.of(&cfg.features);
    let mut cv = extractor.volume(key_features, camera, bins, truncation)?;
    // Frames are decoded a few at a time in parallel (decoding is exact, so this changes no bits)
    // and added in window order.
    let batch = rayon::current_num_threads().clamp(1, 8);
    let mut loaded = std::collections::VecDeque::new();
    // The refinement's live frames (SPEC.md §10.3) are kept from this loop as grey images with their
    // camera and `T_nr`, so no frame is read twice.
    let refine_frames = match &cfg.refine {
        Some(p) if cfg.regularizer != Regularizer::None => refine::select_frames(&live, p.frames),
        _ => Vec::new(),
    };
    let mut refine_inputs = Vec::with_capacity(refine_frames.len());
    for (i, &n) in live.iter().enumerate() {
        if loaded.is_empty() {
            let t = Instant::now();
            let next = &live[i..live.len().min(i + batch)];
            let frames: Vec<Result<_>> = next.par_iter().map(|&m| seq.load_frame_rgb(m)).collect();
            for f in frames {
                loaded.push_back(f?);
            }
            timings.load += t.elapsed().as_secs_f64();
        }
        let frame = loaded.pop_front().expect("a batch was just loaded");
        debug_assert_eq!(frame.index, n);
        if refine_frames.binary_search(&n).is_ok() {
            refine_inputs.push((
                to_gray(&frame.rgb).mapv(f64::from),
                frame.camera,
                relative_pose(&key.pose, &frame.pose),
            ));
        }
        let t = Instant::now();
        // A frame corrected for this keyframe's exposure has features of its own; an uncorrected
        // one has the same features for every keyframe, so they are cached.
        let f = match photo.correct_live(i, &frame.rgb) {
            Cow::Owned(corrected) => extractor.extract(&corrected)?.data,
            Cow::Borrowed(_) => match cache.get(n) {
                Some(f) => f.clone(),
                None => {
                    let f = extractor.extract(&frame.rgb)?.data;
                    cache.offer(n, &f);
                    f
                }
            },
        };
        timings.features += t.elapsed().as_secs_f64();
        let t = Instant::now();
        cv.add_frame_seen_by(
            &extractor.upload(f)?,
            &frame.camera.at_level(level),
            &relative_pose(&key.pose, &frame.pose),
        )?;
        timings.cost_volume += t.elapsed().as_secs_f64();
        progress(Stage::CostVolume, i + 1, live.len());
    }

    progress(Stage::Wta, 0, 1);
    let t = Instant::now();
    // The volume stays where the backend built it (SPEC.md §15.6): only per-pixel maps come back.
    let mut volume = cv.finish_resident()?;
    volume.filter_evidence(cfg.min_evidence)?;
    let (conf, scale) = volume.confidence_and_scale()?;
    let w = volume.winner_take_all(&bins)?;
    // The border taper (SPEC.md §10.1c) after WTA: it weights the regulariser's data term only.
    if cfg.regularizer != Regularizer::None {
        volume.taper_border(cfg.border_taper_px() / f64::from(1u32 << level))?;
    }
    timings.wta = t.elapsed().as_secs_f64();
    progress(Stage::Wta, 1, 1);
    let wta = DepthEstimate { inverse_depth: w.inverse_depth.clone(), depth: w.depth.clone() };
    // The normal prior's confidence weighting (SPEC.md §10.2): the slope where the volume anchors it.
    let slope =
        slope.map(|q| q.weighted_by_confidence(conf.view(), cfg.prior_confidence_c0())).transpose()?;

    let (mut tv, mut dtam, mut sweep) = (None, None, Vec::new());
    let (mut normals_estimate, mut normals_dtam) = (None, None);
    if cfg.regularizer != Regularizer::None {
        let solves = usize::from(cfg.regularizer.tv()) + usize::from(cfg.regularizer.normals());
        let total = solves + cfg.lambda_sweep.len();
        progress(Stage::Tv, 0, total);
        let t = Instant::now();
        let grey = to_gray(&colour);
        // One solve at `lambda`: Huber-TV (TGV with `Regularizer::Tgv`), or the normal prior with
        // `slope` (which only `Regularizer::Normals` / `TvAndNormals` pass, never with TGV).
        let second_order = (cfg.regularizer == Regularizer::Tgv)
            .then(|| crate::dtam::tgv::normalised_beta(cfg.tgv_beta, camera.width));
        let run = |lambda: f64, slope: Option<&SlopeField>| -> Result<(DepthEstimate, DtamReport)> {
            let params = DtamParams { lambda, ..cfg.dtam }.normalised(
                scale,
                camera.width,
                bins.rho_max - bins.rho_min,
            );
            let problem = DtamProblem {
                slope,
                second_order,
                ..DtamProblem::resident(&bins, grey.view(), w.inverse_depth.view(), &params)
            };
            let (res, report) = volume.dtam_solve(&problem)?;
            Ok((tv_estimate(res, &w.valid), report))
        };
        if cfg.regularizer.tv() {
            let (e, report) = run(cfg.dtam.lambda, None)?;
            (tv, dtam) = (Some(e), Some(report));
        }
        timings.tv = t.elapsed().as_secs_f64();
        let t = Instant::now();
        if let Some(q) = slope.as_ref().filter(|_| cfg.regularizer.normals()) {
            let (e, report) = run(cfg.lambda_normals, Some(q))?;
            if dtam.is_none() {
                dtam = Some(report.clone());
            }
            (normals_estimate, normals_dtam) = (Some(e), Some((report, q.fallback)));
        }
        timings.normals += t.elapsed().as_secs_f64();
        // The λ sweep runs the Huber-TV solve where it runs, else the normal prior.
        let sweep_slope = if cfg.regularizer.tv() { None } else { slope.as_ref() };
        for (i, &l) in cfg.lambda_sweep.iter().enumerate() {
            progress(Stage::Tv, solves + i, total);
            sweep.push((l, run(l, sweep_slope)?.0));
        }
        progress(Stage::Tv, total, total);
    }
    let mut refined = None;
    if let Some(p) = cfg.refine.as_ref().filter(|_| tv.is_some() || normals_estimate.is_some()) {
        let t = Instant::now();
        let views: Vec<RefineView> = refine_inputs
            .iter()
            .map(|(grey, camera, pose)| RefineView { grey: grey.view(), camera: *camera, pose: *pose })
            .collect();
        let key_grey = to_gray(&key.rgb).mapv(f64::from);
        for e in [tv.as_mut(), normals_estimate.as_mut()].into_iter().flatten() {
            let (inverse_depth, depth, report) = refine::refine_estimate(
                e.inverse_depth.view(),
                e.depth.view(),
                level,
                key_grey.view(),
                &key_camera,
                &views,
                &bins,
                p,
            )?;
            *e = DepthEstimate { inverse_depth, depth };
            refined = Some(report);
        }
        timings.refine = t.elapsed().as_secs_f64();
    }

    Ok(KeyframeResult {
        keyframe: cfg.keyframe,
        live_frames: live,
        features: extractor.name(),
        level,
        camera,
        bins,
        colour,
        valid: w.valid,
        wta,
        tv,
        tgv: cfg.regularizer == Regularizer::Tgv,
        normals: normals_estimate,
        gt_depth,
        timings,
        dtam,
        normals_dtam,
        normals_error,
        confidence: conf,
        cost_scale: scale,
        sweep,
        memory_estimate: estimate,
        photometric: photo,
        truncation,
        refined,
    })
}

/// DTAM's `d` as an estimate: depth `1/d` where the pixel had a seen hypothesis and `d > 0`.
fn tv_estimate(res: DtamResult, valid: &Array2<bool>) -> DepthEstimate {
    let inverse_depth = res.inverse_depth;
    let depth = Array2::from_shape_fn(inverse_depth.dim(), |(y, x)| {
        let rho = inverse_depth[[y, x]];
        if valid[[y, x]] && rho > 0.0 {
            1.0 / rho
        } else {
            0.0
        }
    });
    DepthEstimate { inverse_depth, depth }
}
