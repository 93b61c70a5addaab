//! Flags shared by `reconstruct`, `eval`, `demo` and `map`: window, depth range, bins, every DTAM
//! parameter and the memory limit; and the progress bar.

use std::path::Path;
use std::time::Duration;

use clap::Args;
use indicatif::{ProgressBar, ProgressStyle};

use super::backend_flag::BackendFlag;
use densefeat::costvolume::NO_TRUNCATION;
use densefeat::dtam::{DtamParams, MAPPING_DEFAULTS};
use densefeat::error::{Error, Result};
use densefeat::mapping::keyframe::{
    KeyframeConfig, Regularizer, Stage, DEFAULT_BINS, DEFAULT_MAX_MEMORY_MB, DEFAULT_MIN_EVIDENCE,
};
use densefeat::mapping::normals::NormalsSource;
use densefeat::mapping::output::DEFAULT_MIN_CONFIDENCE;
use densefeat::mapping::photometric::PhotometricMode;
use densefeat::mapping::refine::{RefineParams, REFINE_DEFAULTS};
use densefeat::mapping::{FeatureKind, KeyframeResult, Truncation};
use densefeat::sequence::{open_with, OpenOptions, Sequence};

/// Mapping flags (SPEC.md §10, §11).
#[derive(Debug, Clone, Args)]
pub struct MappingArgs {
    /// Live frames before and after the keyframe, `P,F` (clamped to the sequence).
    #[arg(long, default_value = "30,30", value_parser = parse_pair_usize)]
    pub window: (usize, usize),
    /// Depth range of the hypotheses, metres, `NEAR,FAR`; or `auto`: per keyframe from the
    /// sequence's sparse points (COLMAP) or ground-truth depth (SPEC.md §4a).
    #[arg(long, default_value = "0.4,10", value_parser = parse_depth_range)]
    pub depth_range: DepthRange,
    /// Metres per unit of the sequence's poses (and depths): required for sequences without a
    /// metric scale (COLMAP, transforms.json without depth); `--scale 1` keeps their units.
    #[arg(long)]
    pub scale: Option<f64>,
    /// Number of inverse-depth hypotheses.
    #[arg(long, default_value_t = DEFAULT_BINS)]
    pub bins: usize,
    /// Pyramid level of the output depth: 0 = the input resolution, 1 = half, ... [default: 0;
    /// `map`: 1, the learned features' own grid]
    #[arg(long)]
    pub level: Option<u32>,
    /// Evidence minimum: a cost-volume cell competes only when at least this fraction of the frames
    /// that saw the pixel saw it (0 = any seen cell).
    #[arg(long, default_value_t = DEFAULT_MIN_EVIDENCE)]
    pub min_evidence: f64,
    /// Mask output depth and point clouds where the confidence is below this (0 = keep all);
    /// metrics are reported at this threshold and at full coverage.
    #[arg(long, default_value_t = DEFAULT_MIN_CONFIDENCE)]
    pub min_confidence: f32,
    /// Normals of the surface-normal prior (`--regularizer normals`, eval's `-normals` methods,
    /// SPEC.md §10.2): `gt` (from the keyframe's ground-truth depth) or a folder of `NNNNN.npy`
    /// (keyframe index) or `<frame name>.npy` files, `[H, W, 3]` f32 camera-frame unit normals at
    /// the input resolution; or `learned`: the built-in predictor (SPEC.md §13.11; the default: the
    /// shipped weights, or `--normal-weights FILE`).
    #[arg(long)]
    pub normals: Option<NormalsSource>,
    /// Weights of the built-in normal predictor for `--normals learned` (a `normalnet.safetensors`
    /// written by `densefeat train-normals`); default: the shipped `fixtures/weights/normalnet.safetensors`.
    #[arg(long)]
    pub normal_weights: Option<std::path::PathBuf>,
    /// Border taper of the data term, in pixels of the input resolution (SPEC.md §10.1c): the
    /// costs of a keyframe pixel closer than this to the image edge are weighted down linearly
    /// (to 5 % on the edge) before DTAM, so the regulariser fills that strip from the interior.
    /// 0: off; default: per feature type, chosen on validation (the learned features 32, the
    /// others 0).
    #[arg(long)]
    pub border_taper: Option<f64>,
    /// The normal prior's confidence weighting (`--regularizer normals`, SPEC.md §10.2): each
    /// pixel's predicted slope is scaled by clamp(confidence / C0, 0, 1), so where the cost volume
    /// cannot anchor the depth the prior is plain smoothness. 0: off (the paper's form); default:
    /// per feature type, chosen on validation (RGB 1.2, the others 0).
    #[arg(long)]
    pub prior_confidence: Option<f64>,
    /// The normal prior's normal edges (`--regularizer normals`, SPEC.md §10.2), a scale in
    /// degrees: where a pixel's normal turns from its neighbours' by an angle a (a crease, or one
    /// surface in front of another), the prior's coupling there is weighted by exp(-(a/SIGMA)^2), as
    /// DTAM's edge weight does at an image edge. Normals from `--normals DIR` should all face the
    /// camera (a flipped normal reads as an edge). 0: off (the paper's form); default: per feature
    /// type, chosen on validation (the learned features 30, the others 0).
    #[arg(long, value_name = "SIGMA")]
    pub prior_edges: Option<f64>,
    /// Photometric sub-bin refinement of the regularised depth (SPEC.md §10.3): `on` or `off`
    /// [default: off; `map`: on, chosen on validation meshes, §16.9]
    #[arg(long, value_parser = parse_on_off)]
    pub refine: Option<bool>,
    /// The refinement leaves a pixel alone when the grey variance of its 7x7 keyframe window is at
    /// most this (grey levels², 0..=255): there the window is the camera's noise, not texture
    /// (SPEC.md §10.3). Needs the refinement on. [default: 9, chosen on validation meshes]
    #[arg(long, value_parser = parse_non_negative)]
    pub refine_min_variance: Option<f64>,
    /// TGV's `β` (`--regularizer tgv`, SPEC.md §10.4): in pixels at 640 px width, the length over
    /// which a change of slope costs what a jump of the same size does (large: Huber-TV).
    /// [default: 16, the better of 4 and 16 on validation depth and meshes; no command defaults to TGV]
    #[arg(long)]
    pub tgv_beta: Option<f64>,
    /// DTAM `λ` on the normalised cost at 640 px width (data term weighted by 1/(λ s), SPEC §10.1);
    /// default: per feature type, chosen on validation (SPEC §10.1a: rgb 300, learned 30, others 100;
    /// the normal prior's solve: rgb 300, learned 100; `map`'s learned features 10, §16.9).
    #[arg(long)]
    pub lambda: Option<f64>,
    /// Huber threshold ε, 1/m.
    #[arg(long, default_value_t = MAPPING_DEFAULTS.epsilon)]
    pub epsilon: f64,
    /// Edge weight α of `g = exp(-α ‖∇I‖^β)`.
    #[arg(long, default_value_t = MAPPING_DEFAULTS.alpha)]
    pub alpha: f64,
    /// Edge weight exponent β.
    #[arg(long, default_value_t = MAPPING_DEFAULTS.beta)]
    pub beta: f64,
    /// First coupling weight θ.
    #[arg(long, default_value_t = MAPPING_DEFAULTS.theta_start)]
    pub theta_start: f64,
    /// Last coupling weight θ.
    #[arg(long, default_value_t = MAPPING_DEFAULTS.theta_end)]
    pub theta_end: f64,
    /// Length of DTAM's θ schedule (iterations from θ start to θ end).
    #[arg(long, default_value_t = MAPPING_DEFAULTS.iterations)]
    pub iterations: usize,
    /// Primal-dual steps per a-search.
    #[arg(long, default_value_t = MAPPING_DEFAULTS.steps_per_search)]
    pub steps_per_search: usize,
    /// Most DTAM iterations (convergence usually stops it earlier).
    #[arg(long, default_value_t = MAPPING_DEFAULTS.max_iterations)]
    pub max_iterations: usize,
    /// DTAM convergence: relative change of energy and d-a gap per iteration.
    #[arg(long, default_value_t = MAPPING_DEFAULTS.tolerance)]
    pub tolerance: f64,
    /// Photometric calibration before matching: none, or affine (per-frame gain and offset of each
    /// live frame relative to the keyframe, fitted from a coarse first pass), SPEC.md §11.9.
    #[arg(long, default_value = "none")]
    pub photometric: PhotometricMode,
    /// Per-frame truncation of the RGB cost (each live frame adds at most this to a cell; grey levels
    /// summed over R, G, B; e.g. 100), or `none` for the plain L1 (SPEC.md §9.13).
    #[arg(long, default_value = "none", value_parser = parse_truncation)]
    pub truncate_rgb: f32,
    /// Per-frame truncation of the learned-feature cost (L1 over the channels), or `none`.
    #[arg(long, default_value = "none", value_parser = parse_truncation)]
    pub truncate_learned: f32,
    /// Per-frame truncation of the block-1 feature cost (`--features b1`; L1 over the channels), or
    /// `none` (SPEC.md §9a.3).
    #[arg(long, default_value = "none", value_parser = parse_truncation)]
    pub truncate_b1: f32,
    /// Per-frame truncation of the dense-SIFT cost (`--features dsift`; L1 over the 128 channels in
    /// the descriptor's units, 512 per unit length), or `none` (SPEC.md §9a.3).
    #[arg(long, default_value = "none", value_parser = parse_truncation)]
    pub truncate_dsift: f32,
    /// Per-frame truncation of the 7x7-patch cost (`--features patch7`; L1 of the mean-removed
    /// patches, grey levels), or `none` (SPEC.md §9a.5).
    #[arg(long, default_value = "none", value_parser = parse_truncation)]
    pub truncate_patch7: f32,
    /// Refuse to run when the estimated memory exceeds this many MiB.
    #[arg(long, default_value_t = DEFAULT_MAX_MEMORY_MB)]
    pub max_memory_mb: usize,
    /// Where the ops run.
    #[command(flatten)]
    pub backend: BackendFlag,
}

/// `--depth-range`: fixed, or estimated per keyframe.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum DepthRange {
    /// `NEAR,FAR` metres.
    Fixed(f64, f64),
    /// `auto`: [`Sequence::estimate_depth_range`] of the keyframe.
    Auto,
}

/// Parses `NEAR,FAR` or `auto`.
///
/// # Errors
/// A message for clap.
pub fn parse_depth_range(s: &str) -> std::result::Result<DepthRange, String> {
    if s.trim().eq_ignore_ascii_case("auto") {
        return Ok(DepthRange::Auto);
    }
    let (a, b) = super::validate::pair(s).map_err(|e| format!("{e} (or `auto`)"))?;
    Ok(DepthRange::Fixed(a, b))
}

/// `keyframe`'s range: the fixed one, or estimated (an error naming `--depth-range` when the frame
/// has neither sparse points nor ground-truth depth).
///
/// # Errors
/// As described; frame loading errors.
pub fn resolve_depth_range(range: DepthRange, seq: &Sequence, keyframe: usize) -> Result<(f64, f64)> {
    match range {
        DepthRange::Fixed(a, b) => Ok((a, b)),
        DepthRange::Auto => seq.estimate_depth_range(keyframe)?.ok_or_else(|| {
            Error::invalid_argument(
                "--depth-range",
                format!(
                    "auto: keyframe {keyframe} has neither sparse points nor ground-truth depth to estimate \
                     a range from; give NEAR,FAR"
                ),
            )
        }),
    }
}

/// Open `path` with `scale` (`--scale`), refusing a sequence without a metric scale when `scale` is
/// `None` (SPEC.md §4a).
///
/// # Errors
/// Opening errors; [`Error::InvalidArgument`] naming `--scale`.
pub fn open_metric(path: &Path, scale: Option<f64>) -> Result<Sequence> {
    let seq = open_with(path, &OpenOptions { scale, ..OpenOptions::default() })?;
    if !seq.metric {
        return Err(Error::invalid_argument(
            "--scale",
            format!(
                "{} ({}) has no metric scale: pass --scale METRES_PER_UNIT (--scale 1 keeps the model's \
                 units, and then --depth-range, --voxel-size and the other lengths are in those units)",
                path.display(),
                seq.format
            ),
        ));
    }
    Ok(seq)
}

impl MappingArgs {
    /// Open `path` with `--scale`, refusing a sequence without a metric scale when `--scale` is
    /// absent (SPEC.md §4a).
    ///
    /// # Errors
    /// Opening errors; [`Error::InvalidArgument`] naming `--scale`.
    pub fn open_sequence(&self, path: &Path) -> Result<Sequence> {
        open_metric(path, self.scale)
    }

    /// `--normals` with `--normal-weights` applied: `learned` takes the file; without `--normals`,
    /// `learned` (the shipped predictor; none in a build without one).
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] naming `--normal-weights` when it is given without
    /// `--normals learned`, or names no file.
    pub fn normals_source(&self) -> Result<Option<NormalsSource>> {
        match (&self.normals, &self.normal_weights) {
            (Some(NormalsSource::Learned(_)), Some(p)) => {
                if !p.is_file() {
                    return Err(Error::invalid_argument(
                        "--normal-weights",
                        format!("{}: no such file", p.display()),
                    ));
                }
                Ok(Some(NormalsSource::Learned(Some(p.clone()))))
            }
            (_, Some(_)) => Err(Error::invalid_argument(
                "--normal-weights",
                "is the built-in predictor's weights: it needs --normals learned",
            )),
            (Some(n), None) => Ok(Some(n.clone())),
            (None, None) => {
                Ok(densefeat::normals_net::SHIPPED_NORMAL_WEIGHTS.map(|_| NormalsSource::Learned(None)))
            }
        }
    }

    /// The refinement's parameters: none unless `--refine on` (or a command's default turned it
    /// on), [`REFINE_DEFAULTS`] with `--refine-min-variance` applied.
    ///
    /// # Errors
    /// `--refine-min-variance` with the refinement off.
    pub fn refine_params(&self) -> Result<Option<RefineParams>> {
        match (self.refine.unwrap_or(false), self.refine_min_variance) {
            (false, Some(_)) => Err(Error::invalid_argument(
                "--refine-min-variance",
                "sets the refinement's variance floor: it needs --refine on",
            )),
            (false, None) => Ok(None),
            (true, v) => Ok(Some(RefineParams {
                min_variance: v.unwrap_or(REFINE_DEFAULTS.min_variance),
                ..REFINE_DEFAULTS
            })),
        }
    }

    /// A configuration for `keyframe` of `seq` with these flags (`--depth-range auto` resolved at
    /// `keyframe`).
    ///
    /// # Errors
    /// `--backend` names a backend this build does not have; `--depth-range auto` cannot be
    /// estimated at `keyframe`; [`MappingArgs::normals_source`]'s errors.
    pub fn config(
        &self,
        seq: &Sequence,
        keyframe: usize,
        features: FeatureKind,
        regularizer: Regularizer,
    ) -> Result<KeyframeConfig> {
        if self.tgv_beta.is_some() && regularizer != Regularizer::Tgv {
            return Err(Error::invalid_argument(
                "--tgv-beta",
                "sets TGV's second-order weight: it needs --regularizer tgv (reconstruct, map; eval and demo \
                 have no TGV rows)",
            ));
        }
        if let Some(b) = self.tgv_beta {
            densefeat::dtam::tgv::check_beta(b)?;
        }
        let depth_range = resolve_depth_range(self.depth_range, seq, keyframe)?;
        let (lambda, lambda_normals) = (features.default_lambda(), features.default_lambda_normals());
        Ok(KeyframeConfig {
            keyframe,
            past: self.window.0,
            future: self.window.1,
            features,
            near: depth_range.0,
            far: depth_range.1,
            bins: self.bins,
            regularizer,
            normals: self.normals_source()?,
            dtam: DtamParams {
                lambda: self.lambda.unwrap_or(lambda),
                epsilon: self.epsilon,
                alpha: self.alpha,
                beta: self.beta,
                theta_start: self.theta_start,
                theta_end: self.theta_end,
                iterations: self.iterations,
                steps_per_search: self.steps_per_search,
                max_iterations: self.max_iterations,
                tolerance: self.tolerance,
            },
            lambda_normals: self.lambda.unwrap_or(lambda_normals),
            tgv_beta: self.tgv_beta.unwrap_or(densefeat::dtam::tgv::DEFAULT_BETA),
            max_memory_mb: self.max_memory_mb,
            level: self.level.unwrap_or(0),
            min_evidence: self.min_evidence,
            lambda_sweep: Vec::new(),
            border_taper: self.border_taper,
            prior_confidence: self.prior_confidence,
            prior_edges: self.prior_edges,
            refine: self.refine_params()?,
            backend: self.backend.resolve()?,
            photometric: self.photometric,
            truncation: Truncation {
                rgb: self.truncate_rgb,
                learned: self.truncate_learned,
                b1: self.truncate_b1,
                dsift: self.truncate_dsift,
                patch7: self.truncate_patch7,
            },
        })
    }
}

/// Parses `on` / `off`.
///
/// # Errors
/// A message for clap.
pub fn parse_on_off(s: &str) -> std::result::Result<bool, String> {
    match s.trim().to_ascii_lowercase().as_str() {
        "on" => Ok(true),
        "off" => Ok(false),
        _ => Err(format!("{s:?}: expected `on` or `off`")),
    }
}

/// Parses a finite number `>= 0`.
///
/// # Errors
/// A message for clap.
pub fn parse_non_negative(s: &str) -> std::result::Result<f64, String> {
    match s.trim().parse::<f64>() {
        Ok(v) if v >= 0.0 && v.is_finite() => Ok(v),
        _ => Err(format!("{s:?}: expected a number >= 0")),
    }
}

/// Parses a per-frame truncation: a positive number, or `none` ([`NO_TRUNCATION`]).
///
/// # Errors
/// A message for clap.
pub fn parse_truncation(s: &str) -> std::result::Result<f32, String> {
    if s.trim().eq_ignore_ascii_case("none") {
        return Ok(NO_TRUNCATION);
    }
    match s.trim().parse::<f32>() {
        Ok(t) if t > 0.0 && t.is_finite() => Ok(t),
        _ => Err(format!("{s:?}: expected a positive number or `none`")),
    }
}

/// Parses `P,F`.
///
/// # Errors
/// A message for clap.
pub fn parse_pair_usize(s: &str) -> std::result::Result<(usize, usize), String> {
    super::validate::pair(s)
}

/// Parses `START:STEP:END` (END inclusive) into keyframe indices.
///
/// # Errors
/// [`Error::InvalidArgument`] for a malformed range, a zero step or `END < START`.
pub fn parse_keyframes(s: &str) -> Result<Vec<usize>> {
    let bad = |what: &str| Error::invalid_argument("--keyframes", format!("{s:?}: {what}"));
    let parts: Vec<&str> = s.split(':').collect();
    let nums: Vec<usize> = parts
        .iter()
        .map(|p| p.trim().parse::<usize>())
        .collect::<std::result::Result<_, _>>()
        .map_err(|_| bad("expected START:STEP:END (non-negative integers)"))?;
    let [start, step, end] = nums[..] else {
        return Err(bad("expected START:STEP:END"));
    };
    if step == 0 || end < start {
        return Err(bad("need STEP > 0 and END >= START"));
    }
    Ok((start..=end).step_by(step).collect())
}

/// A progress bar on stderr (hidden when stderr is not a terminal).
pub fn progress_bar() -> ProgressBar {
    let bar = ProgressBar::new(1);
    bar.set_style(
        ProgressStyle::with_template("{spinner} [{elapsed_precise}] {msg:32} {bar:30} {pos}/{len}")
            .expect("valid template"),
    );
    bar.enable_steady_tick(Duration::from_millis(200));
    bar
}

/// Update `bar` for a stage event.
pub fn show_stage(bar: &ProgressBar, prefix: &str, stage: Stage, done: usize, total: usize) {
    bar.set_message(format!("{prefix}{stage}"));
    bar.set_length(total as u64);
    bar.set_position(done as u64);
}

/// One line of timings and the DTAM summary.
pub fn summary(r: &KeyframeResult) -> String {
    let t = &r.timings;
    let mut s = format!(
        "keyframe {} ({}, {} live frames, {}x{} level {}): load {:.2} s, features {:.2} s, cost volume {:.2} s, \
         WTA {:.2} s, TV {:.2} s, normal prior {:.2} s, total {:.2} s",
        r.keyframe,
        r.features,
        r.live_frames.len(),
        r.camera.width,
        r.camera.height,
        r.level,
        t.load,
        t.features,
        t.cost_volume,
        t.wta,
        t.tv,
        t.normals,
        t.total()
    );
    if let Some(d) = &r.dtam {
        s += &format!(
            "\n  DTAM: {} iterations ({}), energy {:.4e} -> {:.4e}, d-a gap {:.2e} 1/m, cost scale {:.4}",
            d.iterations,
            if d.converged { "converged" } else { "hit --max-iterations" },
            d.energy.first().copied().unwrap_or(f64::NAN),
            d.energy.last().copied().unwrap_or(f64::NAN),
            d.gap.last().copied().unwrap_or(f64::NAN),
            r.cost_scale
        );
    }
    s
}
