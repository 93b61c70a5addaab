//! The paper's evaluation table (SPEC.md §11.5): each method on each keyframe, metrics averaged
//! over keyframes (the mean of per-keyframe metrics; every keyframe weighs the same).
//! Winner-take-all and TV of one feature kind come from the same cost volume.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use crate::error::{Error, Result};
use crate::eval::DepthMetrics;
use crate::mapping::features::FeatureExtractor;
use crate::mapping::keyframe::{
    reconstruct_with, DepthEstimate, KeyframeConfig, KeyframeResult, Regularizer, Stage, StageTimings,
};
use crate::mapping::FeatureKind;
use crate::sequence::Sequence;

/// A row of the table: features and regulariser.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Method {
    /// RGB, winner-take-all.
    RgbWta,
    /// RGB, DTAM Huber-TV.
    RgbTv,
    /// Learned features, winner-take-all.
    LearnedWta,
    /// Learned features, DTAM Huber-TV.
    LearnedTv,
    /// Block-1 features alone (SPEC.md §9a.1), winner-take-all.
    B1Wta,
    /// Block-1 features alone, DTAM Huber-TV.
    B1Tv,
    /// Dense SIFT (SPEC.md §9a.2), winner-take-all.
    DsiftWta,
    /// Dense SIFT, DTAM Huber-TV.
    DsiftTv,
    /// RGB, DTAM with the surface-normal prior (SPEC.md §10.2; needs `--normals`).
    RgbNormals,
    /// Learned features, DTAM with the surface-normal prior.
    LearnedNormals,
    /// Affine-warped 7x7 patches (SPEC.md §9a.5), winner-take-all.
    Patch7Wta,
    /// Affine-warped 7x7 patches, DTAM Huber-TV.
    Patch7Tv,
}

impl Method {
    /// The paper's four methods in table order.
    pub const ALL: [Method; 4] = [Method::RgbWta, Method::RgbTv, Method::LearnedWta, Method::LearnedTv];

    /// The default of `eval --methods` and what `demo` runs: the paper's four, then the learned
    /// features' default regulariser, the surface-normal prior (SPEC.md §10.1a).
    pub const DEFAULT: [Method; 5] =
        [Method::RgbWta, Method::RgbTv, Method::LearnedWta, Method::LearnedTv, Method::LearnedNormals];

    /// Every method: the paper's four, then the per-pixel descriptor baselines (SPEC.md §9a).
    pub const EVERY: [Method; 12] = [
        Method::RgbWta,
        Method::RgbTv,
        Method::LearnedWta,
        Method::LearnedTv,
        Method::B1Wta,
        Method::B1Tv,
        Method::DsiftWta,
        Method::DsiftTv,
        Method::Patch7Wta,
        Method::Patch7Tv,
        Method::RgbNormals,
        Method::LearnedNormals,
    ];

    /// `FEATURES-wta` or `FEATURES-tv`, FEATURES one of `rgb`, `learned`, `b1`, `dsift`, `patch7`.
    pub fn name(self) -> &'static str {
        match self {
            Method::RgbWta => "rgb-wta",
            Method::RgbTv => "rgb-tv",
            Method::LearnedWta => "learned-wta",
            Method::LearnedTv => "learned-tv",
            Method::B1Wta => "b1-wta",
            Method::B1Tv => "b1-tv",
            Method::DsiftWta => "dsift-wta",
            Method::DsiftTv => "dsift-tv",
            Method::Patch7Wta => "patch7-wta",
            Method::Patch7Tv => "patch7-tv",
            Method::RgbNormals => "rgb-normals",
            Method::LearnedNormals => "learned-normals",
        }
    }

    /// The feature kind it matches, network kinds with `weights` (`None`: the shipped ones).
    pub fn features(self, weights: Option<&Path>) -> FeatureKind {
        let w = weights.map(Path::to_path_buf);
        match self {
            Method::RgbWta | Method::RgbTv | Method::RgbNormals => FeatureKind::Rgb,
            Method::LearnedWta | Method::LearnedTv | Method::LearnedNormals => FeatureKind::Learned(w),
            Method::B1Wta | Method::B1Tv => FeatureKind::B1(w),
            Method::DsiftWta | Method::DsiftTv => FeatureKind::Dsift,
            Method::Patch7Wta | Method::Patch7Tv => FeatureKind::Patch7,
        }
    }

    /// The feature kind's short name (`rgb`, `learned`, `b1`, `dsift`, `patch7`).
    pub fn feature_name(self) -> &'static str {
        self.features(None).name()
    }

    /// Whether it uses the learned (aggregated) features.
    pub fn learned(self) -> bool {
        matches!(self, Method::LearnedWta | Method::LearnedTv | Method::LearnedNormals)
    }

    /// Whether it runs DTAM with the surface-normal prior.
    pub fn normals(self) -> bool {
        matches!(self, Method::RgbNormals | Method::LearnedNormals)
    }

    /// Whether it runs DTAM.
    pub fn tv(self) -> bool {
        matches!(self, Method::RgbTv | Method::LearnedTv | Method::B1Tv | Method::DsiftTv | Method::Patch7Tv)
    }

    /// This method's estimate in a reconstruction of its feature kind: the Huber-TV one, the
    /// normal-prior one or winner-take-all (`None` when that solve was not run).
    pub fn estimate(self, result: &KeyframeResult) -> Option<&DepthEstimate> {
        if self.tv() {
            result.tv.as_ref()
        } else if self.normals() {
            result.normals.as_ref()
        } else {
            Some(&result.wta)
        }
    }
}

impl std::str::FromStr for Method {
    type Err = Error;

    fn from_str(s: &str) -> Result<Self> {
        Method::EVERY.into_iter().find(|m| m.name() == s).ok_or_else(|| {
            let names: Vec<&str> = Method::EVERY.iter().map(|m| m.name()).collect();
            Error::invalid_argument("--methods", format!("{s:?}: expected one of {}", names.join(", ")))
        })
    }
}

impl std::fmt::Display for Method {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// One method's averaged result.
#[derive(Clone, Debug)]
pub struct EvalRow {
    /// The method.
    pub method: Method,
    /// Metrics averaged over keyframes (`count` summed, every other field the mean), full coverage.
    pub metrics: DepthMetrics,
    /// The same with pixels below [`EvalOptions::min_confidence`] masked.
    pub confident: DepthMetrics,
    /// Mean wall time per keyframe and stage of the run that produced it (TV zero for WTA rows,
    /// whose volume is shared with the TV row).
    pub timings: StageTimings,
}

/// The evaluation: averaged rows and every per-keyframe result.
#[derive(Clone, Debug)]
pub struct EvalTable {
    /// One row per requested method, in the requested order.
    pub rows: Vec<EvalRow>,
    /// `(keyframe, method, metrics)` for every run.
    pub per_keyframe: Vec<(usize, Method, DepthMetrics)>,
    /// `(method, λ, metrics averaged over keyframes)` for every TV method (or normal-prior method of a
    /// kind without a TV method) and [`EvalOptions::lambda_sweep`] value.
    pub sweep: Vec<(Method, f64, DepthMetrics)>,
    /// The confidence threshold of [`EvalRow::confident`].
    pub min_confidence: f32,
    /// `(method, threshold, metrics averaged over keyframes)` for [`EvalOptions::confidence_sweep`].
    pub confidence_sweep: Vec<(Method, f32, DepthMetrics)>,
    /// `(keyframe, error)`: the built-in normal predictor's angular error against the ground
    /// truth's normals, per keyframe, when `--normals learned` ran (SPEC.md §13.11).
    pub normals_error: Vec<(usize, crate::mapping::normals::NormalsError)>,
}

/// Settings [`evaluate`] adds to a base [`KeyframeConfig`].
#[derive(Clone, Debug, Default)]
pub struct EvalOptions {
    /// Weights of the learned and block-1 features (`None`: the shipped ones).
    pub weights: Option<PathBuf>,
    /// `λ` for the learned features' DTAM (`None`: the base config's, or the kind's default with
    /// [`EvalOptions::lambda_per_kind`]).
    pub lambda_learned: Option<f64>,
    /// Each feature kind runs DTAM with its own default `λ` ([`FeatureKind::default_lambda`],
    /// SPEC.md §10.1a) instead of the base config's (what `--lambda` left unset means).
    pub lambda_per_kind: bool,
    /// Extra `λ` values at which every TV method also runs, on the same volumes.
    pub lambda_sweep: Vec<f64>,
    /// Confidence threshold of the masked metrics.
    pub min_confidence: f32,
    /// Extra confidence thresholds: every method's metrics at each ([`EvalTable::confidence_sweep`]).
    pub confidence_sweep: Vec<f32>,
    /// Per-keyframe `(near, far)` depth ranges, in the order of the keyframes (`--depth-range auto`
    /// estimates one per keyframe); empty: every keyframe uses the base config's range.
    pub depth_ranges: Vec<(f64, f64)>,
}

/// Run `methods` on every keyframe. `base` gives the window, range, bins, DTAM parameters and
/// memory limit (its keyframe, features and regulariser are replaced). `on_result` sees each
/// reconstruction (to print or write it); `progress(keyframe, stage, done, total)`.
///
/// # Errors
/// [`Error::InvalidArgument`] for no keyframe or method, [`EvalOptions::depth_ranges`] that is
/// neither empty nor one range per keyframe, a keyframe without ground truth; any [`reconstruct_with`]
/// error.
pub fn evaluate(
    seq: &Sequence,
    base: &KeyframeConfig,
    keyframes: &[usize],
    methods: &[Method],
    options: &EvalOptions,
    mut on_result: impl FnMut(&KeyframeResult) -> Result<()>,
    mut progress: impl FnMut(usize, Stage, usize, usize),
) -> Result<EvalTable> {
    if keyframes.is_empty() || methods.is_empty() {
        return Err(Error::invalid_argument("evaluation", "need at least one keyframe and one method"));
    }
    if !options.depth_ranges.is_empty() && options.depth_ranges.len() != keyframes.len() {
        return Err(Error::invalid_argument(
            "evaluation",
            format!("{} depth ranges for {} keyframes", options.depth_ranges.len(), keyframes.len()),
        ));
    }
    let mut per_keyframe = Vec::new();
    let mut normals_error = Vec::new();
    let mut per_keyframe_conf: Vec<(Method, DepthMetrics)> = Vec::new();
    let mut sweep_per_kf: Vec<(Method, f64, DepthMetrics)> = Vec::new();
    let mut conf_per_kf: Vec<(Method, f32, DepthMetrics)> = Vec::new();
    let mut timing_sums: Vec<StageTimings> = vec![StageTimings::default(); methods.len()];
    // One volume per keyframe and feature kind, kinds in this order.
    for kind in ["rgb", "learned", "b1", "dsift", "patch7"] {
        let wanted: Vec<usize> = (0..methods.len()).filter(|&i| methods[i].feature_name() == kind).collect();
        let Some(&first) = wanted.first() else { continue };
        let mut cfg = base.clone();
        cfg.features = methods[first].features(options.weights.as_deref());
        if options.lambda_per_kind {
            cfg.dtam.lambda = cfg.features.default_lambda();
            cfg.lambda_normals = cfg.features.default_lambda_normals();
        }
        if methods[first].learned() {
            if let Some(l) = options.lambda_learned {
                cfg.dtam.lambda = l;
                cfg.lambda_normals = l;
            }
        }
        let tv = wanted.iter().any(|&i| methods[i].tv());
        let normals = wanted.iter().any(|&i| methods[i].normals());
        cfg.regularizer = match (tv, normals) {
            (true, true) => Regularizer::TvAndNormals,
            (true, false) => Regularizer::Tv,
            (false, true) => Regularizer::Normals,
            (false, false) => Regularizer::None,
        };
        // The λ sweep runs the kind's Huber-TV solve where a -tv method is asked for, else its
        // normal prior (`reconstruct` does that), and is attributed to that method (SPEC.md §10.2).
        cfg.lambda_sweep = if tv || normals { options.lambda_sweep.clone() } else { Vec::new() };
        // One extractor per feature kind for every keyframe (the weights read once).
        let extractor = FeatureExtractor::new(cfg.features.clone(), cfg.level, cfg.backend.clone())?;
        for (j, &k) in keyframes.iter().enumerate() {
            cfg.keyframe = k;
            if let Some(&(near, far)) = options.depth_ranges.get(j) {
                (cfg.near, cfg.far) = (near, far);
            }
            let result = reconstruct_with(seq, &cfg, &extractor, |s, d, t| progress(k, s, d, t))?;
            if let Some(e) = result.normals_error {
                // Every kind runs the same predictor on the same keyframe: recorded once.
                if !normals_error.iter().any(|(kk, _)| *kk == k) {
                    normals_error.push((k, e));
                }
            }
            for &i in &wanted {
                let m = methods[i];
                let Some(estimate) = m.estimate(&result) else {
                    unreachable!("the regulariser was chosen to run every asked method")
                };
                per_keyframe.push((k, m, result.metrics(estimate)?));
                per_keyframe_conf.push((m, result.metrics_at(estimate, options.min_confidence)?));
                for &c in &options.confidence_sweep {
                    // A threshold that masks every pixel has no metrics: skipped for that keyframe.
                    if let Ok(d) = result.metrics_at(estimate, c) {
                        conf_per_kf.push((m, c, d));
                    }
                }
                if m.tv() || (m.normals() && !tv) {
                    for (l, e) in &result.sweep {
                        sweep_per_kf.push((m, *l, result.metrics(e)?));
                    }
                }
                // Each method's time: the shared stages and its own regulariser.
                let mut t = result.timings;
                if !m.tv() {
                    t.tv = 0.0;
                }
                if !m.normals() {
                    t.normals = 0.0;
                }
                add_timings(&mut timing_sums[i], &t);
            }
            on_result(&result)?;
        }
    }
    let n = keyframes.len() as f64;
    let rows = methods
        .iter()
        .zip(&timing_sums)
        .map(|(&m, t)| {
            let ms: Vec<DepthMetrics> =
                per_keyframe.iter().filter(|(_, pm, _)| *pm == m).map(|(_, _, d)| *d).collect();
            let timings = StageTimings {
                load: t.load / n,
                features: t.features / n,
                cost_volume: t.cost_volume / n,
                wta: t.wta / n,
                tv: t.tv / n,
                normals: t.normals / n,
                photometric: t.photometric / n,
                refine: t.refine / n,
            };
            let cs: Vec<DepthMetrics> =
                per_keyframe_conf.iter().filter(|(pm, _)| *pm == m).map(|(_, d)| *d).collect();
            EvalRow { method: m, metrics: mean_metrics(&ms), confident: mean_metrics(&cs), timings }
        })
        .collect();
    let mut sweep = Vec::new();
    for &m in methods.iter().filter(|m| m.tv() || m.normals()) {
        for &l in &options.lambda_sweep {
            let ms: Vec<DepthMetrics> =
                sweep_per_kf.iter().filter(|(pm, pl, _)| *pm == m && *pl == l).map(|(_, _, d)| *d).collect();
            if !ms.is_empty() {
                sweep.push((m, l, mean_metrics(&ms)));
            }
        }
    }
    let mut confidence_sweep = Vec::new();
    for &m in methods {
        for &c in &options.confidence_sweep {
            let ms: Vec<DepthMetrics> =
                conf_per_kf.iter().filter(|(pm, pc, _)| *pm == m && *pc == c).map(|(_, _, d)| *d).collect();
            if !ms.is_empty() {
                confidence_sweep.push((m, c, mean_metrics(&ms)));
            }
        }
    }
    Ok(EvalTable {
        rows,
        per_keyframe,
        sweep,
        min_confidence: options.min_confidence,
        confidence_sweep,
        normals_error,
    })
}

fn add_timings(sum: &mut StageTimings, t: &StageTimings) {
    sum.load += t.load;
    sum.features += t.features;
    sum.cost_volume += t.cost_volume;
    sum.wta += t.wta;
    sum.tv += t.tv;
    sum.normals += t.normals;
    sum.photometric += t.photometric;
    sum.refine += t.refine;
}

/// Mean of per-keyframe metrics (`count` summed).
///
/// # Panics
/// If `ms` is empty.
pub fn mean_metrics(ms: &[DepthMetrics]) -> DepthMetrics {
    assert!(!ms.is_empty(), "mean of no metrics");
    let n = ms.len() as f64;
    let mean = |f: fn(&DepthMetrics) -> f64| ms.iter().map(f).sum::<f64>() / n;
    DepthMetrics {
        rms: mean(|m| m.rms),
        log_rms: mean(|m| m.log_rms),
        abs_rel: mean(|m| m.abs_rel),
        sq_rel: mean(|m| m.sq_rel),
        delta_1_1: mean(|m| m.delta_1_1),
        delta_1_25: mean(|m| m.delta_1_25),
        delta_1_25_2: mean(|m| m.delta_1_25_2),
        delta_1_25_3: mean(|m| m.delta_1_25_3),
        count: ms.iter().map(|m| m.count).sum(),
        coverage: mean(|m| m.coverage),
    }
}

const COLUMNS: [&str; 10] =
    ["method", "rms", "log", "abs rel", "sq rel", "δ<1.1", "δ<1.25", "δ<1.25²", "δ<1.25³", "coverage"];

fn cells(name: &str, m: &DepthMetrics) -> [String; 10] {
    [
        name.to_string(),
        format!("{:.4}", m.rms),
        format!("{:.4}", m.log_rms),
        format!("{:.4}", m.abs_rel),
        format!("{:.4}", m.sq_rel),
        format!("{:.4}", m.delta_1_1),
        format!("{:.4}", m.delta_1_25),
        format!("{:.4}", m.delta_1_25_2),
        format!("{:.4}", m.delta_1_25_3),
        format!("{:.4}", m.coverage),
    ]
}

impl EvalTable {
    /// The table as Markdown (the paper's columns plus coverage): full coverage, then (when the
    /// threshold is positive) the rows at the confidence threshold, named `METHOD@c`.
    pub fn markdown(&self) -> String {
        let mut s = format!("| {} |\n|{}\n", COLUMNS.join(" | "), "---|".repeat(COLUMNS.len()));
        for (name, m) in self.named_rows() {
            let _ = writeln!(s, "| {} |", cells(&name, &m).join(" | "));
        }
        s.push_str(&self.normals_error_markdown());
        s
    }

    /// The normal predictor's angular error per keyframe as Markdown (empty without
    /// `--normals learned`): mean and median degrees, pixels, and the mean over keyframes.
    pub fn normals_error_markdown(&self) -> String {
        if self.normals_error.is_empty() {
            return String::new();
        }
        let mut s = String::from(
            "\nBuilt-in normal predictor (`--normals learned`) against the normals of the ground-truth depth (level 0):\n\n| keyframe | mean angular error (°) | median angular error (°) | pixels |\n|---|---|---|---|\n",
        );
        for (k, e) in &self.normals_error {
            let _ = writeln!(s, "| {k} | {:.2} | {:.2} | {} |", e.mean_deg, e.median_deg, e.pixels);
        }
        let n = self.normals_error.len() as f64;
        let mean = |f: fn(&crate::mapping::normals::NormalsError) -> f64| {
            self.normals_error.iter().map(|(_, e)| f(e)).sum::<f64>() / n
        };
        let _ = writeln!(
            s,
            "| mean over keyframes | {:.2} | {:.2} | |",
            mean(|e| e.mean_deg),
            mean(|e| e.median_deg)
        );
        s
    }

    fn named_rows(&self) -> Vec<(String, DepthMetrics)> {
        let mut v: Vec<(String, DepthMetrics)> =
            self.rows.iter().map(|r| (r.method.name().to_string(), r.metrics)).collect();
        if self.min_confidence > 0.0 {
            for r in &self.rows {
                v.push((format!("{}@{}", r.method.name(), self.min_confidence), r.confident));
            }
        }
        v
    }

    /// The table as CSV (ASCII column names).
    pub fn csv(&self) -> String {
        let mut s = String::from(
            "method,rms,log_rms,abs_rel,sq_rel,delta_1.1,delta_1.25,delta_1.25^2,delta_1.25^3,coverage\n",
        );
        for (name, m) in self.named_rows() {
            let _ = writeln!(s, "{}", cells(&name, &m).join(","));
        }
        s
    }

    /// Mean wall time per keyframe by stage, as Markdown, one row per method.
    pub fn timings_markdown(&self) -> String {
        let mut s = String::from(
            "| method | load s | photometric s | features s | cost volume s | WTA s | TV s | normals s | total s |\n|---|---|---|---|---|---|---|---|---|\n",
        );
        for r in &self.rows {
            let t = &r.timings;
            let _ = writeln!(
                s,
                "| {} | {:.3} | {:.3} | {:.3} | {:.3} | {:.3} | {:.3} | {:.3} | {:.3} |",
                r.method,
                t.load,
                t.photometric,
                t.features,
                t.cost_volume,
                t.wta,
                t.tv,
                t.normals,
                t.total()
            );
        }
        s
    }
}
