//! A whole sequence to a mesh (SPEC.md §16.8-16.9): keyframe selection, each keyframe
//! reconstructed ([`super::reconstruct`]) and written into its own folder (resumable), then TSDF
//! fusion of the keyframe depth maps (confidence-weighted) and of the ground-truth depth maps,
//! meshes, mesh-to-mesh metrics, pictures and `map.json`.
//!
//! Output folder `OUT`: `keyframes/kf_IIIII/` per keyframe (each committed whole through
//! [`Staging`]; `keyframe.json` names the configuration, and a re-run with the same configuration
//! skips the folder), then, committed together at the end, `mesh.ply`, `mesh_gt.ply` (with ground
//! truth), `mesh.png` and `map.json`.

use std::io::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

use nalgebra::Vector3;
use serde::Serialize;
use serde_json::json;

use super::feature_cache::FeatureCache;
use super::features::FeatureExtractor;
use super::keyframe::{depth_at_level, KeyframeConfig, Regularizer, Stage};
use super::keyframe_select::{keyframe_window, select_keyframes, KeyframeRule};
use super::output::{write_outputs_with, write_pfm};
use crate::error::{Error, Result};
use crate::fusion::consistency::{filter_depth, ConsistencyRule, ViewDepth};
use crate::fusion::grid::{voxel_count, Aabb, VoxelGrid, BYTES_PER_VOXEL};
use crate::fusion::ply::write_mesh_ply;
use crate::fusion::render::{render, tile, View};
use crate::fusion::{
    extract_mesh, fusion_weights, mesh_metrics, remove_small_components, ComponentReport, DepthObservation,
    FusionWeight, Mesh, MeshMetrics, Tsdf,
};
use crate::image::{is_valid_depth, load_rgb, save_rgb_png, DepthMap, RgbImage};
use crate::io::{write_atomic_with, Staging};
use crate::sequence::disparity::read_pfm;
use crate::sequence::Sequence;

/// `densefeat map`'s default pyramid level (SPEC.md §16.9): 1, half the input resolution, where
/// the shipped learned features are computed. Chosen on the validation scenes (2026-12-03, SUN3D
/// f0935 and render 200001): the same mean F-score at 5 cm as level 0 (0.269 vs 0.269) in a
/// third to a sixth of the time per keyframe (`docs/map/results.md`).
pub const MAP_LEVEL: u32 = 1;

/// Whether `densefeat map` refines each keyframe's depth photometrically by default (SPEC.md §10.3,
/// §16.9): yes. Chosen on the validation scenes (2026-12-06): mean F-score at 5 cm 0.381 without,
/// see `docs/map/results.md` for the figures with it.
pub const MAP_REFINE: bool = true;

/// `densefeat map`'s default DTAM `λ` for the learned features (SPEC.md §16.9): 10, below the depth
/// commands' 30 (§10.1a). Chosen on the validation scenes by the mean F-score at 5 cm over λ ∈ {3,
/// 10, 30, 100} (2026-12-05: 0.365 / **0.372** / 0.360 / 0.329; `docs/map/results.md`): a mesh at
/// 5 cm wants less smoothing than δ<1.25 does. The other kinds keep their §10.1a default.
pub const MAP_LAMBDA_LEARNED: f64 = 10.0;

/// `densefeat map`'s border taper (SPEC.md §10.1c, §16.9): 0 (off) for every kind. The depth
/// commands' learned default (32) ties on the validation meshes (mean F-score at 5 cm 0.372 with and
/// without, worse on 6 of 8 scenes; `docs/map/results.md`): the neighbouring keyframes already see
/// what one keyframe's border misses.
pub const MAP_BORDER_TAPER: f64 = 0.0;

/// `densefeat map`'s default truncation of the estimated depth's TSDF, in voxels (SPEC.md §16.9): 8
/// (0.32 m at the default 4 cm voxel), about one depth bin at 4 m, the error the keyframe depth
/// still has there. Chosen on the validation scenes against a fixed ground truth (2026-12-05:
/// mean F-score at 5 cm 0.361 / 0.367 / 0.372 / 0.379 / **0.381** / 0.381 / 0.381 for 2 / 3 / 4 / 6
/// / 8 / 10 / 12 voxels; `docs/map/results.md`).
pub const MAP_TRUNCATION_VOXELS: f64 = 8.0;

/// The truncation of the ground-truth TSDF, in voxels (SPEC.md §16.5): the ground-truth depth is
/// exact, so it keeps the 4 voxels the fusion had before, whatever `--truncation` is: the reference a
/// run is scored against does not move with the estimate's fusion settings.
pub const GT_TRUNCATION_VOXELS: f64 = 4.0;

/// Everything [`map_sequence`] needs besides the sequence.
#[derive(Clone, Debug)]
pub struct MapConfig {
    /// Template for every keyframe (features, bins, range, DTAM, level, ...); `past` / `future`
    /// are the largest window, `keyframe` is ignored.
    pub keyframe: KeyframeConfig,
    /// Inclusive frame range `[first, last]`.
    pub frames: (usize, usize),
    /// Keyframe selection and windows.
    pub rule: KeyframeRule,
    /// Voxel size, metres.
    pub voxel: f64,
    /// Truncation `μ`, metres.
    pub truncation: f64,
    /// Depths beyond this (metres) are not fused.
    pub max_fusion_depth: f64,
    /// Estimated depth below this confidence is not fused (the mapper's `--min-confidence`).
    pub min_confidence: f32,
    /// F-score threshold `τ`, metres.
    pub fscore_threshold: f64,
    /// Estimate each keyframe's depth range ([`Sequence::estimate_depth_range`], `--depth-range
    /// auto`) instead of the template's `near`, `far`.
    pub auto_depth_range: bool,
    /// The multi-view check before fusion (SPEC.md §16.10; `min_views = 0`: off).
    pub consistency: ConsistencyRule,
    /// Keyframes on each side (in keyframe order) that each keyframe is checked against.
    pub consistency_neighbours: usize,
    /// Depth-discontinuity rule before fusion: largest depth ratio to a 3x3 neighbour (<= 1: off).
    pub edge_ratio: f64,
    /// Connected pieces of the estimated mesh with fewer triangles than this are removed
    /// (SPEC.md §16.3a; 0 keeps everything).
    pub min_component_triangles: usize,
    /// Per-pixel fusion weight (SPEC.md §16.2a).
    pub fusion_weight: FusionWeight,
    /// Budget of the features kept for the next keyframes, MiB (SPEC.md §16.12; 0: none).
    pub feature_cache_mb: usize,
}

/// One keyframe's plan.
#[derive(Clone, Debug, Serialize)]
pub struct PlannedKeyframe {
    /// Frame index.
    pub index: usize,
    /// Live frames before it.
    pub past: usize,
    /// Live frames after it.
    pub future: usize,
    /// Its estimated depth range `(near, far)` with `--depth-range auto`.
    pub depth_range: Option<(f64, f64)>,
}

/// The keyframes and windows of a run, and the memory bound of its fusion, known before any work.
#[derive(Clone, Debug, Serialize)]
pub struct MapPlan {
    /// Keyframes in order.
    pub keyframes: Vec<PlannedKeyframe>,
    /// The box around the keyframes' frusta up to `max_fusion_depth`: the fusion volume is inside.
    pub frusta: Aabb,
    /// Upper bound of the fusion volumes' bytes (estimate and ground truth).
    pub fusion_bytes_bound: u64,
}

/// Everything a run measured.
#[derive(Clone, Debug, Serialize)]
pub struct MapSummary {
    /// The plan.
    pub plan: MapPlan,
    /// Keyframes reused from an earlier run.
    pub resumed: Vec<usize>,
    /// Seconds per stage.
    pub timings: MapTimings,
    /// The estimated mesh's vertices and triangles.
    pub mesh: (usize, usize),
    /// Metrics against the fused ground truth, if the keyframes have depth.
    pub metrics: Option<MeshMetrics>,
    /// The same metrics for the ground-truth depth fused as the estimate is (filter, weights,
    /// truncation, small pieces): the upper bound of the fusion alone (SPEC.md §16.5).
    pub metrics_gt_depth: Option<MeshMetrics>,
    /// Keyframe pixels with valid, confident depth before and after the filter of SPEC.md §16.10.
    pub fused_pixels: (usize, usize),
    /// The small pieces removed from the estimated mesh (SPEC.md §16.3a).
    pub components: ComponentReport,
    /// Frames whose features came from the cache, and those extracted (SPEC.md §16.12).
    pub feature_cache: (usize, usize),
    /// Per keyframe, the median over its depth pixels of the largest angle under which its live
    /// cameras see the point, degrees (SPEC.md §16.11); `None` without depth or live frames.
    pub triangulation_deg: Vec<Option<f64>>,
}

/// Wall seconds per stage.
#[derive(Clone, Debug, Default, Serialize)]
pub struct MapTimings {
    /// Keyframe reconstruction and its files, per keyframe computed in this run.
    pub keyframes: Vec<(usize, f64)>,
    /// Reading keyframe depth back and fusing (both volumes).
    pub fusion: f64,
    /// Mesh extraction (both).
    pub mesh: f64,
    /// Mesh metrics.
    pub metrics: f64,
    /// Pictures and files.
    pub write: f64,
}

impl MapConfig {
    /// The ground truth's truncation, metres ([`GT_TRUNCATION_VOXELS`] voxels).
    pub fn gt_truncation(&self) -> f64 {
        GT_TRUNCATION_VOXELS * self.voxel
    }

    /// How far the fusion volume reaches past the fused points: the wider of the two truncations.
    fn fusion_padding(&self) -> f64 {
        self.truncation.max(self.gt_truncation())
    }

    /// Check the fusion parameters.
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] naming the flag.
    pub fn validate(&self, seq: &Sequence) -> Result<()> {
        self.rule.validate()?;
        let pos = |flag: &str, v: f64| {
            if v.is_finite() && v > 0.0 {
                Ok(())
            } else {
                Err(Error::invalid_argument(flag, format!("{v}: must be a finite number > 0")))
            }
        };
        pos("--voxel-size", self.voxel)?;
        pos("--truncation", self.truncation)?;
        pos("--max-fusion-depth", self.max_fusion_depth)?;
        pos("--fscore-threshold", self.fscore_threshold)?;
        if self.consistency.min_views > 0 {
            pos("--consistency-depth", self.consistency.max_depth_error)?;
            pos("--consistency-px", self.consistency.max_reprojection_px)?;
            if self.consistency_neighbours == 0 {
                return Err(Error::invalid_argument(
                    "--consistency-neighbours",
                    "0 leaves no keyframe to confirm with: use --consistency-views 0 to turn the check off",
                ));
            }
        }
        if !self.edge_ratio.is_finite() || self.edge_ratio < 0.0 {
            return Err(Error::invalid_argument(
                "--edge-ratio",
                format!("{}: must be a finite number >= 0 (<= 1 turns the rule off)", self.edge_ratio),
            ));
        }
        if self.truncation < self.voxel {
            return Err(Error::invalid_argument(
                "--truncation",
                format!(
                    "{} m is less than --voxel-size {} m: the surface would fall between voxels",
                    self.truncation, self.voxel
                ),
            ));
        }
        let (a, b) = self.frames;
        if a > b || b >= seq.len() {
            return Err(Error::invalid_argument(
                "--frames",
                format!("{a}:{b}: need FIRST <= LAST < {} (the sequence's frame count)", seq.len()),
            ));
        }
        if a == b {
            return Err(Error::invalid_argument("--frames", format!("{a}:{b}: one frame has no live frame")));
        }
        Ok(())
    }

    /// Keyframes, windows and the fusion memory bound (SPEC.md §16.8-16.9).
    ///
    /// # Errors
    /// As [`MapConfig::validate`].
    pub fn plan(&self, seq: &Sequence) -> Result<MapPlan> {
        self.validate(seq)?;
        let poses: Vec<_> = seq.frames.iter().map(|f| f.pose).collect();
        let range: Vec<usize> = (self.frames.0..=self.frames.1).collect();
        let cam = seq.camera;
        let keys = select_keyframes(&cam, &poses, &range, &self.rule);
        let max = (self.keyframe.past, self.keyframe.future);
        let keyframes: Vec<PlannedKeyframe> = keys
            .iter()
            .map(|&k| {
                let (past, future) = keyframe_window(&cam, &poses, k, self.frames, max, &self.rule);
                let depth_range = if self.auto_depth_range { Some(auto_range(seq, k)?) } else { None };
                Ok(PlannedKeyframe { index: k, past, future, depth_range })
            })
            .collect::<Result<_>>()?;
        // Each keyframe's frustum in its own camera.
        let mut frusta = Aabb::empty();
        for &k in &keys {
            let b = Aabb::of_frusta(&seq.frame_camera(k), &[poses[k]], self.max_fusion_depth);
            frusta.add(b.min);
            frusta.add(b.max);
        }
        let frusta = frusta.padded(self.fusion_padding());
        let volumes = if seq.frames[keys[0]].depth.is_some() { 2 } else { 1 };
        let fusion_bytes_bound =
            voxel_count(&frusta, self.voxel).saturating_mul(BYTES_PER_VOXEL).saturating_mul(volumes);
        Ok(MapPlan { keyframes, frusta, fusion_bytes_bound })
    }

    /// The configuration of keyframe `k`.
    fn keyframe_config(&self, k: &PlannedKeyframe) -> KeyframeConfig {
        let (near, far) = k.depth_range.unwrap_or((self.keyframe.near, self.keyframe.far));
        KeyframeConfig {
            keyframe: k.index,
            past: k.past,
            future: k.future,
            near,
            far,
            ..self.keyframe.clone()
        }
    }

    /// What makes a keyframe folder reusable: every setting that changes its files.
    fn fingerprint(&self, seq: &Sequence, k: &PlannedKeyframe) -> String {
        let c = self.keyframe_config(k);
        let taper = c.border_taper_px();
        format!(
            "sequence={} keyframe={} window={},{} features={:?} near={} far={} bins={} regularizer={:?} \
             normals={:?} dtam={:?} lambda_normals={} level={} min_evidence={} min_confidence={} backend={}",
            seq.root.canonicalize().unwrap_or(seq.root.clone()).display(),
            c.keyframe,
            c.past,
            c.future,
            c.features,
            c.near,
            c.far,
            c.bins,
            c.regularizer,
            c.normals,
            c.dtam,
            c.lambda_normals,
            c.level,
            c.min_evidence,
            self.min_confidence,
            c.backend.name()
        ) + &if taper > 0.0 { format!(" border_taper={taper}") } else { String::new() }
            + &match c.prior_confidence_c0() {
                c0 if c0 > 0.0 && c.regularizer.normals() => format!(" prior_confidence={c0}"),
                _ => String::new(),
            }
            + &match c.prior_edges_deg() {
                sigma if sigma > 0.0 && c.regularizer.normals() => format!(" prior_edges={sigma}"),
                _ => String::new(),
            }
            + &c.refine.map_or(String::new(), |p| format!(" refine={p:?}"))
            + &if c.regularizer == Regularizer::Tgv {
                format!(" tgv_beta={}", c.tgv_beta)
            } else {
                String::new()
            }
    }
}

/// Name of a keyframe's folder under `OUT/keyframes/`.
pub fn keyframe_dir(out: &Path, index: usize) -> PathBuf {
    out.join("keyframes").join(format!("kf_{index:05}"))
}

/// The estimate's file name in a keyframe folder.
fn depth_file(cfg: &MapConfig) -> &'static str {
    match cfg.keyframe.regularizer {
        Regularizer::Tv => "depth_tv.pfm",
        Regularizer::Tgv => "depth_tgv.pfm",
        Regularizer::Normals | Regularizer::TvAndNormals => "depth_normals.pfm",
        Regularizer::None => "depth_wta.pfm",
    }
}

/// Whether `dir` holds a complete keyframe made with `fingerprint`.
fn is_complete(dir: &Path, fingerprint: &str, depth_name: &str) -> bool {
    let Ok(text) = std::fs::read_to_string(dir.join("keyframe.json")) else { return false };
    let Ok(doc) = serde_json::from_str::<serde_json::Value>(&text) else { return false };
    doc["config"].as_str() == Some(fingerprint)
        && ["keyframe.png", "confidence.pfm", depth_name].iter().all(|f| dir.join(f).is_file())
}

/// Run the whole job (module docs). `progress(done, total, message)` is called as work completes.
///
/// # Errors
/// Bad configuration, reading and writing errors, naming the flag or file. Keyframe folders
/// committed before an error stay (they are complete); the final files appear together or not at all.
pub fn map_sequence(
    seq: &Sequence,
    cfg: &MapConfig,
    out: &Path,
    mut progress: impl FnMut(usize, usize, &str),
) -> Result<MapSummary> {
    let plan = cfg.plan(seq)?;
    let n = plan.keyframes.len();
    let mut timings = MapTimings::default();
    let mut resumed = Vec::new();
    // One extractor for every computed keyframe (the weights read and the network built once per
    // run), made when the first keyframe needs it.
    let mut extractor: Option<FeatureExtractor> = None;
    // Frames' features for the next keyframes (SPEC.md §16.12), dropped before the fusion.
    let mut cache = FeatureCache::new(cfg.feature_cache_mb as u64 * 1024 * 1024);
    for (i, k) in plan.keyframes.iter().enumerate() {
        let dir = keyframe_dir(out, k.index);
        let fp = cfg.fingerprint(seq, k);
        if is_complete(&dir, &fp, depth_file(cfg)) {
            resumed.push(k.index);
            progress(i + 1, n, &format!("keyframe {} (already done)", k.index));
            continue;
        }
        let t = Instant::now();
        let kcfg = cfg.keyframe_config(k);
        // Every keyframe shares the run's features, level and backend (`keyframe_config`).
        let ex = match &extractor {
            Some(e) => e,
            None => extractor.insert(FeatureExtractor::new(
                kcfg.features.clone(),
                kcfg.level,
                kcfg.backend.clone(),
            )?),
        };
        let r = super::keyframe::reconstruct_cached(seq, &kcfg, ex, &mut cache, |s: Stage, d, tot| {
            progress(i, n, &format!("keyframe {}: {s} {d}/{tot}", k.index))
        })?;
        let mut staging = Staging::new();
        let stage = staging.dir(&dir)?;
        write_outputs_with(&r, &stage, cfg.min_confidence)?;
        write_pfm(&stage.join("confidence.pfm"), r.confidence.view())?;
        let seconds = t.elapsed().as_secs_f64();
        let doc = json!({
            "config": fp,
            "keyframe": k.index,
            "window": [k.past, k.future],
            "live_frames": r.live_frames,
            "stage_timings_s": r.timings,
            "refined": r.refined,
            "seconds": seconds,
        });
        write_text(&stage.join("keyframe.json"), &serde_json::to_string_pretty(&doc).expect("plain data"))?;
        staging.commit()?;
        timings.keyframes.push((k.index, seconds));
        progress(i + 1, n, &format!("keyframe {} done ({seconds:.1} s)", k.index));
    }

    let feature_cache = cache.hits_and_misses();
    drop(cache);
    progress(n, n, "fusion");
    let t = Instant::now();
    let mut maps = load_keyframes(seq, cfg, &plan, out)?;
    // How much parallax each keyframe's confident depth had (SPEC.md §16.11), before the filter.
    let triangulation_deg: Vec<Option<f64>> = plan
        .keyframes
        .iter()
        .zip(&maps)
        .map(|(k, m)| {
            let live = cfg.keyframe_config(k).live_frames(seq.len())?;
            let centres: Vec<Vector3<f64>> =
                live.iter().map(|&j| seq.frames[j].pose.translation.vector).collect();
            let confident = confident_depth(m, cfg.min_confidence);
            Ok(super::parallax::median_triangulation_angle(&confident, &m.camera, &m.pose, &centres))
        })
        .collect::<Result<_>>()?;
    // Depth that agrees with its neighbours (SPEC.md §16.10): confidence first (as before), then
    // the multi-view check against the nearest keyframes and the discontinuity rule.
    let fused_pixels_before: usize = maps.iter().map(|m| valid_confident(m, cfg.min_confidence)).sum();
    let views: Vec<ViewDepth<'_>> = maps.iter().map(view_of).collect();
    let filtered = filter_keyframes(cfg, &views);
    for (m, d) in maps.iter_mut().zip(filtered) {
        m.depth = d;
    }
    let fused_pixels_after: usize = maps.iter().map(|m| valid_confident(m, cfg.min_confidence)).sum();
    let fused_pixels = (fused_pixels_before, fused_pixels_after);
    if fused_pixels_before > 0 && fused_pixels_after == 0 {
        return Err(Error::invalid_argument(
            "--consistency-views",
            format!(
                "the depth filter kept none of the keyframes' {fused_pixels_before} fusable pixels (no \
                 neighbouring keyframe confirmed any, or --edge-ratio {} removed the rest): the keyframe \
                 depths disagree everywhere; --consistency-views 0 --edge-ratio 0 fuses them unfiltered",
                cfg.edge_ratio
            ),
        ));
    }
    let mut bounds = Aabb::empty();
    for m in &maps {
        add_points(&mut bounds, &m.depth, m, cfg.max_fusion_depth);
        if let Some(gt) = &m.gt {
            add_points(&mut bounds, gt, m, cfg.max_fusion_depth);
        }
    }
    let bounds = bounds.padded(cfg.fusion_padding()).intersect(&plan.frusta);
    let grid = VoxelGrid::covering(&bounds, cfg.voxel)?;
    let has_gt = maps.iter().all(|m| m.gt.is_some());
    let mut est = Tsdf::new(grid, cfg.truncation)?;
    let mut gt_volume = if has_gt { Some(Tsdf::new(grid, cfg.gt_truncation())?) } else { None };
    for m in &maps {
        let capped = cap(&m.depth, cfg.max_fusion_depth);
        let weights = fusion_weights(capped.view(), Some(m.confidence.view()), &m.camera, cfg.fusion_weight);
        est.integrate(&DepthObservation {
            depth: capped.view(),
            weight: Some(weights.view()),
            colour: Some(m.colour.view()),
            camera: m.camera,
            pose: m.pose,
        })?;
        if let (Some(v), Some(gt)) = (gt_volume.as_mut(), &m.gt) {
            let capped = cap(gt, cfg.max_fusion_depth);
            v.integrate(&DepthObservation {
                depth: capped.view(),
                weight: None,
                colour: Some(m.colour.view()),
                camera: m.camera,
                pose: m.pose,
            })?;
        }
    }
    timings.fusion = t.elapsed().as_secs_f64();
    progress(n, n, "mesh");
    let t = Instant::now();
    let (mesh, components) = remove_small_components(&extract_mesh(&est), cfg.min_component_triangles);
    let gt_mesh = gt_volume.as_ref().map(extract_mesh);
    timings.mesh = t.elapsed().as_secs_f64();
    let t = Instant::now();
    let metrics = gt_mesh.as_ref().map(|g| mesh_metrics(&mesh, g, cfg.fscore_threshold));
    timings.metrics = t.elapsed().as_secs_f64();
    // The upper bound of the fusion alone (SPEC.md §16.5): the ground-truth depth through the
    // estimate's filter, weights, truncation and piece removal, scored as the estimate is. The
    // estimate's volume goes first, so no more than two volumes are ever held.
    let observed = est.observed();
    drop(est);
    let t = Instant::now();
    let metrics_gt_depth = match &gt_mesh {
        Some(g) if has_gt => Some(fusion_bound(cfg, &maps, grid, g)?),
        _ => None,
    };
    timings.fusion += t.elapsed().as_secs_f64();

    progress(n, n, "writing");
    let t = Instant::now();
    let mut staging = Staging::new();
    let mesh_path = staging.file(&out.join("mesh.ply"))?;
    write_mesh_ply(&mesh_path, &mesh, "densefeat map: fused keyframe depth, world frame, metres")?;
    if let Some(g) = &gt_mesh {
        let p = staging.file(&out.join("mesh_gt.ply"))?;
        write_mesh_ply(&p, g, "densefeat map: fused ground-truth depth, world frame, metres")?;
    }
    let picture = pictures(&mesh, gt_mesh.as_ref(), &maps);
    save_rgb_png(&staging.file(&out.join("mesh.png"))?, &picture)?;
    timings.write = t.elapsed().as_secs_f64();
    let summary = MapSummary {
        plan,
        resumed,
        timings,
        mesh: (mesh.vertices.len(), mesh.triangles.len()),
        metrics,
        metrics_gt_depth,
        fused_pixels,
        components,
        triangulation_deg,
        feature_cache,
    };
    let doc = map_json(seq, cfg, &summary, &grid, &mesh, gt_mesh.as_ref(), observed, gt_volume.as_ref());
    write_text(
        &staging.file(&out.join("map.json"))?,
        &serde_json::to_string_pretty(&doc).expect("plain data"),
    )?;
    staging.commit()?;
    Ok(summary)
}

/// The ground-truth depth of every keyframe through the estimate's fusion (§16.10 filter among the
/// ground-truth maps, §16.2a weights without a confidence, `--truncation`, `--max-fusion-depth`,
/// `--min-component`), scored against the reference mesh `gt` (SPEC.md §16.5).
fn fusion_bound(cfg: &MapConfig, maps: &[KeyframeMaps], grid: VoxelGrid, gt: &Mesh) -> Result<MeshMetrics> {
    let views: Vec<ViewDepth<'_>> = maps
        .iter()
        .filter_map(|m| m.gt.as_ref().map(|d| ViewDepth { depth: d.view(), camera: m.camera, pose: m.pose }))
        .collect();
    let mut volume = Tsdf::new(grid, cfg.truncation)?;
    for (m, filtered) in maps.iter().zip(filter_keyframes(cfg, &views)) {
        let depth = cap(&filtered, cfg.max_fusion_depth);
        let weights = fusion_weights(depth.view(), None, &m.camera, cfg.fusion_weight);
        volume.integrate(&DepthObservation {
            depth: depth.view(),
            weight: Some(weights.view()),
            colour: None,
            camera: m.camera,
            pose: m.pose,
        })?;
    }
    let (mesh, _) = remove_small_components(&extract_mesh(&volume), cfg.min_component_triangles);
    Ok(mesh_metrics(&mesh, gt, cfg.fscore_threshold))
}

/// Each keyframe's depth filtered against its `--consistency-neighbours` nearest keyframes on each
/// side and by the discontinuity rule (SPEC.md §16.10).
fn filter_keyframes(cfg: &MapConfig, views: &[ViewDepth<'_>]) -> Vec<DepthMap> {
    (0..views.len())
        .map(|i| {
            let lo = i.saturating_sub(cfg.consistency_neighbours);
            let hi = (i + cfg.consistency_neighbours + 1).min(views.len());
            let others: Vec<ViewDepth<'_>> = (lo..hi).filter(|&j| j != i).map(|j| views[j]).collect();
            filter_depth(&views[i], &others, &cfg.consistency, cfg.edge_ratio)
        })
        .collect()
}

/// A keyframe's depth, camera and pose for the filter of SPEC.md §16.10.
fn view_of(m: &KeyframeMaps) -> ViewDepth<'_> {
    ViewDepth { depth: m.depth.view(), camera: m.camera, pose: m.pose }
}

/// The keyframe's depth where it is valid and confident (0 elsewhere).
fn confident_depth(m: &KeyframeMaps, min: f32) -> DepthMap {
    let mut d = m.depth.clone();
    ndarray::Zip::from(&mut d).and(&m.confidence).for_each(|z, &c| {
        if !fusable(*z, c, min) {
            *z = 0.0;
        }
    });
    d
}

/// Pixels of a keyframe with valid depth and confidence at least `min` (what fusion integrates).
fn valid_confident(m: &KeyframeMaps, min: f32) -> usize {
    m.depth.iter().zip(m.confidence.iter()).filter(|(&d, &c)| fusable(d, c, min)).count()
}

/// Whether a keyframe pixel of depth `z` and confidence `c` is fused at `--min-confidence` `min`.
#[inline]
fn fusable(z: f32, c: f32, min: f32) -> bool {
    is_valid_depth(z) && c >= min
}

/// One keyframe read back for fusion.
struct KeyframeMaps {
    depth: DepthMap,
    confidence: DepthMap,
    colour: RgbImage,
    gt: Option<DepthMap>,
    camera: crate::geometry::PinholeCamera,
    pose: crate::geometry::Pose,
}

fn load_keyframes(seq: &Sequence, cfg: &MapConfig, plan: &MapPlan, out: &Path) -> Result<Vec<KeyframeMaps>> {
    plan.keyframes
        .iter()
        .map(|k| {
            let camera = seq.frame_camera(k.index).at_level(cfg.keyframe.level);
            let dir = keyframe_dir(out, k.index);
            let depth = read_pfm(&dir.join(depth_file(cfg)))?;
            let confidence = read_pfm(&dir.join("confidence.pfm"))?;
            let colour = load_rgb(&dir.join("keyframe.png"))?;
            let frame = &seq.frames[k.index];
            let gt = match &frame.depth {
                Some(_) => seq.load_frame(k.index)?.depth.map(|d| depth_at_level(&d, cfg.keyframe.level)),
                None => None,
            };
            Ok(KeyframeMaps { depth, confidence, colour, gt, camera, pose: frame.pose })
        })
        .collect()
}

fn cap(depth: &DepthMap, max: f64) -> DepthMap {
    depth.mapv(|z| if is_valid_depth(z) && (z as f64) <= max { z } else { 0.0 })
}

fn add_points(b: &mut Aabb, depth: &DepthMap, m: &KeyframeMaps, max: f64) {
    for ((y, x), &z) in depth.indexed_iter() {
        if is_valid_depth(z) && (z as f64) <= max {
            let p = m.pose * nalgebra::Point3::from(m.camera.ray(x as f64, y as f64) * z as f64);
            b.add([p.x, p.y, p.z]);
        }
    }
}

/// `mesh.png`: rows = (estimate, ground truth), columns = (the middle keyframe's camera, an oblique
/// view from above).
fn pictures(mesh: &Mesh, gt: Option<&Mesh>, maps: &[KeyframeMaps]) -> RgbImage {
    let up = -maps.iter().map(|m| m.pose.rotation * Vector3::y()).sum::<Vector3<f64>>();
    let forward = maps.iter().map(|m| m.pose.rotation * Vector3::z()).sum::<Vector3<f64>>();
    let mid = &maps[maps.len() / 2];
    let scale = 480.0 / mid.camera.width as f64;
    let c = mid.camera;
    let cam = crate::geometry::PinholeCamera {
        fx: c.fx * scale,
        fy: c.fy * scale,
        cx: (c.cx + 0.5) * scale - 0.5,
        cy: (c.cy + 0.5) * scale - 0.5,
        width: 480,
        height: ((c.height as f64 * scale).round() as usize).max(1),
    };
    let pinhole = View::Pinhole { camera: cam, pose: mid.pose };
    let oblique = View::oblique(gt.unwrap_or(mesh), up, forward, 50.0, (480, 360));
    let mut rows = vec![vec![render(mesh, &pinhole), render(mesh, &oblique)]];
    if let Some(g) = gt {
        rows.push(vec![render(g, &pinhole), render(g, &oblique)]);
    }
    tile(&rows)
}

#[allow(clippy::too_many_arguments)]
fn map_json(
    seq: &Sequence,
    cfg: &MapConfig,
    s: &MapSummary,
    grid: &VoxelGrid,
    mesh: &Mesh,
    gt_mesh: Option<&Mesh>,
    observed: usize,
    gt_volume: Option<&Tsdf>,
) -> serde_json::Value {
    let computed: Vec<f64> = s.timings.keyframes.iter().map(|k| k.1).collect();
    let per_kf =
        if computed.is_empty() { None } else { Some(computed.iter().sum::<f64>() / computed.len() as f64) };
    json!({
        "sequence": seq.root.display().to_string(),
        "frames": [cfg.frames.0, cfg.frames.1],
        "keyframe_rule": cfg.rule,
        "keyframes": s.plan.keyframes,
        "resumed_keyframes": s.resumed,
        "mapping": {
            "features": format!("{:?}", cfg.keyframe.features),
            "regularizer": cfg.keyframe.regularizer,
            "lambda": cfg.keyframe.dtam.lambda,
            "tgv_beta": (cfg.keyframe.regularizer == Regularizer::Tgv).then_some(cfg.keyframe.tgv_beta),
            "border_taper_px": cfg.keyframe.border_taper_px(),
            "prior_confidence": cfg.keyframe.regularizer.normals().then_some(cfg.keyframe.prior_confidence_c0()),
            "prior_edges_deg": cfg.keyframe.regularizer.normals().then_some(cfg.keyframe.prior_edges_deg()),
            "bins": cfg.keyframe.bins,
            "depth_range_m": [cfg.keyframe.near, cfg.keyframe.far],
            "depth_range_auto": cfg.auto_depth_range,
            "level": cfg.keyframe.level,
            "min_confidence": cfg.min_confidence,
            "refine": cfg.keyframe.refine,
        },
        "fusion": {
            "voxel_m": cfg.voxel,
            "truncation_m": cfg.truncation,
            "gt_truncation_m": cfg.gt_truncation(),
            "max_fusion_depth_m": cfg.max_fusion_depth,
            "consistency": {
                "min_views": cfg.consistency.min_views,
                "max_depth_error": cfg.consistency.max_depth_error,
                "max_reprojection_px": cfg.consistency.max_reprojection_px,
                "neighbours": cfg.consistency_neighbours,
                "edge_ratio": cfg.edge_ratio,
                "fused_pixels_before_after": [s.fused_pixels.0, s.fused_pixels.1],
            },
            "min_component_triangles": cfg.min_component_triangles,
            "fusion_weight": cfg.fusion_weight,
            "components": s.components,
            "grid": grid,
            "volume_bytes": grid.bytes() * if gt_volume.is_some() { 2 } else { 1 },
            "volume_bytes_bound": s.plan.fusion_bytes_bound,
            "observed_voxels": observed,
            "observed_voxels_gt": gt_volume.map(Tsdf::observed),
        },
        "feature_cache": {
            "budget_mb": cfg.feature_cache_mb,
            "hits": s.feature_cache.0,
            "misses": s.feature_cache.1,
        },
        "triangulation_deg": {
            "per_keyframe": s.triangulation_deg,
            "median": super::parallax::median_over_keyframes(&s.triangulation_deg),
            "warn_below": super::parallax::MIN_TRIANGULATION_DEG,
        },
        "mesh": { "vertices": mesh.vertices.len(), "triangles": mesh.triangles.len(), "edges": mesh.edge_report() },
        "mesh_gt": gt_mesh.map(|g| json!({
            "vertices": g.vertices.len(), "triangles": g.triangles.len(), "edges": g.edge_report()
        })),
        "metrics": s.metrics,
        "metrics_gt_depth": s.metrics_gt_depth,
        "timings_s": s.timings,
        "seconds_per_keyframe": per_kf,
    })
}

fn write_text(path: &Path, text: &str) -> Result<()> {
    write_atomic_with(path, |w| w.write_all(text.as_bytes()))
}

/// Keyframe `k`'s estimated range, or an error naming `--depth-range`.
fn auto_range(seq: &Sequence, k: usize) -> Result<(f64, f64)> {
    seq.estimate_depth_range(k)?.ok_or_else(|| {
        Error::invalid_argument(
            "--depth-range",
            format!("auto: keyframe {k} has neither sparse points nor ground-truth depth; give NEAR,FAR"),
        )
    })
}
