//! `densefeat map`: a whole sequence to a mesh (SPEC.md §16.8-16.10).

use std::path::PathBuf;

use clap::Args;

use densefeat::error::Result;
use densefeat::fusion::consistency::ConsistencyRule;
use densefeat::fusion::FusionWeight;
use densefeat::mapping::keyframe::Regularizer;
use densefeat::mapping::keyframe_select::KeyframeRule;
use densefeat::mapping::sequence_map::{map_sequence, MapConfig, MAP_TRUNCATION_VOXELS};
use densefeat::mapping::FeatureKind;

use super::mapping_args::{progress_bar, DepthRange, MappingArgs};
use super::validate::{flag, mapping_preflight};

/// Arguments of `densefeat map`.
#[derive(Debug, Clone, Args)]
pub struct MapArgs {
    /// Sequence folder (any format `densefeat inspect` reads).
    #[arg(long)]
    pub sequence: PathBuf,
    /// Frames to map, `FIRST:LAST` (inclusive; default: all).
    #[arg(long)]
    pub frames: Option<String>,
    /// `learned` (shipped weights), `learned=WEIGHTS.safetensors`, `rgb`, `b1` / `b1=WEIGHTS` (block 1
    /// of the network alone), `dsift` (dense SIFT) or `patch7` (affine-warped 7x7 patches), SPEC.md §9a.
    #[arg(long, default_value = "learned")]
    pub features: FeatureKind,
    /// `tv` (DTAM), `tgv` (DTAM with second-order TGV, SPEC.md §10.4), `normals` (DTAM with the
    /// surface-normal prior, SPEC.md §10.2, with `--normals`' or the built-in predictor's normals)
    /// or `none` (winner-take-all). Unlike `reconstruct`, `tv`
    /// for every feature type: chosen by mesh F-score on validation (docs/map/results.md).
    #[arg(long, default_value = "tv")]
    pub regularizer: Regularizer,
    /// A frame this far (metres) from the last keyframe becomes a keyframe.
    #[arg(long, default_value_t = KeyframeRule::default().baseline)]
    pub kf_baseline: f64,
    /// A frame whose view overlap with the last keyframe falls below this becomes a keyframe.
    #[arg(long, default_value_t = KeyframeRule::default().overlap)]
    pub kf_overlap: f64,
    /// Depth (metres) at which view overlaps are measured.
    #[arg(long, default_value_t = KeyframeRule::default().nominal_depth)]
    pub kf_depth: f64,
    /// Live frames need at least this view overlap with their keyframe (at most --window P,F).
    #[arg(long, default_value_t = KeyframeRule::default().window_overlap)]
    pub window_overlap: f64,
    /// TSDF voxel size, metres.
    #[arg(long, default_value_t = 0.04)]
    pub voxel_size: f64,
    /// TSDF truncation of the estimated depth, metres (default: 8 voxels; the ground truth keeps 4).
    #[arg(long)]
    pub truncation: Option<f64>,
    /// Depths beyond this (metres) are not fused.
    #[arg(long, default_value_t = 5.0)]
    pub max_fusion_depth: f64,
    /// Keep a keyframe's depth only where this many neighbouring keyframes confirm it (SPEC.md
    /// §16.10: reproject, compare depth and reprojection distance); 0 turns the check off.
    #[arg(long, default_value_t = 1)]
    pub consistency_views: usize,
    /// Largest relative depth difference of a confirmation.
    #[arg(long, default_value_t = 0.05)]
    pub consistency_depth: f64,
    /// Largest round-trip reprojection distance of a confirmation, pixels.
    #[arg(long, default_value_t = 2.0)]
    pub consistency_px: f64,
    /// Keyframes on each side a keyframe is checked against.
    #[arg(long, default_value_t = 4)]
    pub consistency_neighbours: usize,
    /// Drop depth next to a discontinuity: a 3x3 neighbour more than this factor nearer or
    /// farther (no surface bridged across an occlusion edge); <= 1 turns it off.
    #[arg(long, default_value_t = 1.1)]
    pub edge_ratio: f64,
    /// Per-pixel fusion weight: `confidence`, `angle` (times the view angle's cosine) or
    /// `angle-distance` (also over the squared depth).
    #[arg(long, default_value = "angle-distance", value_parser = FusionWeight::parse)]
    pub fusion_weight: FusionWeight,
    /// Remove connected pieces of the estimated mesh with fewer triangles than this (0 keeps
    /// everything).
    #[arg(long, default_value_t = 0)]
    pub min_component: usize,
    /// Distance threshold of precision, recall and F-score, metres.
    #[arg(long, default_value_t = 0.05)]
    pub fscore_threshold: f64,
    /// Keep frames' features for the next keyframes, at most this many MiB (and within what
    /// --max-memory-mb leaves beside each keyframe); 0 extracts every frame for every keyframe.
    /// Results are the same bits either way (SPEC.md §16.12).
    #[arg(long, default_value_t = densefeat::mapping::feature_cache::DEFAULT_FEATURE_CACHE_MB)]
    pub feature_cache_mb: usize,
    /// Mapping flags (window, depth range, bins, DTAM, memory limit).
    #[command(flatten)]
    pub mapping: MappingArgs,
    /// Output folder (re-running into it skips keyframes already done with the same settings).
    #[arg(long)]
    pub out: PathBuf,
}

/// Parse `FIRST:LAST`.
fn parse_frames(text: &str) -> Result<(usize, usize)> {
    let bad = || flag("frames", format!("{text:?}: expected FIRST:LAST (non-negative integers)"));
    let (a, b) = text.split_once(':').ok_or_else(bad)?;
    Ok((a.trim().parse().map_err(|_| bad())?, b.trim().parse().map_err(|_| bad())?))
}

/// Below this share of confident keyframe pixels kept by the depth filter, `map` warns that the mesh
/// will be fragmentary (every validation scene keeps more: the real room a third, the renders 65-90 %).
const LOW_CONFIRMED_SHARE: f64 = 0.25;

/// Runs the command.
///
/// # Errors
/// Bad arguments, reading or writing errors.
pub fn run(mut args: MapArgs) -> Result<()> {
    // `map` works on the learned features' own grid unless told otherwise (SPEC.md §16.9).
    args.mapping.level.get_or_insert(densefeat::mapping::sequence_map::MAP_LEVEL);
    // ... and refines its depth photometrically (SPEC.md §10.3, §16.9).
    args.mapping.refine.get_or_insert(densefeat::mapping::sequence_map::MAP_REFINE);
    let frames = args.frames.as_deref().map(parse_frames).transpose()?;
    let seq = args.mapping.open_sequence(&args.sequence)?;
    let mut keyframe =
        args.mapping.config(&seq, frames.map_or(0, |f| f.0), args.features.clone(), args.regularizer)?;
    // A mesh at 5 cm wants less smoothing than depth at δ<1.25 (SPEC.md §16.9).
    if args.mapping.lambda.is_none() && matches!(args.features, FeatureKind::Learned(_)) {
        keyframe.dtam.lambda = densefeat::mapping::sequence_map::MAP_LAMBDA_LEARNED;
    }
    keyframe.border_taper.get_or_insert(densefeat::mapping::sequence_map::MAP_BORDER_TAPER);
    let cfg = MapConfig {
        keyframe,
        frames: frames.unwrap_or((0, seq.len().saturating_sub(1))),
        rule: KeyframeRule {
            baseline: args.kf_baseline,
            overlap: args.kf_overlap,
            nominal_depth: args.kf_depth,
            window_overlap: args.window_overlap,
        },
        voxel: args.voxel_size,
        truncation: args.truncation.unwrap_or(MAP_TRUNCATION_VOXELS * args.voxel_size),
        max_fusion_depth: args.max_fusion_depth,
        min_confidence: args.mapping.min_confidence,
        fscore_threshold: args.fscore_threshold,
        auto_depth_range: args.mapping.depth_range == DepthRange::Auto,
        consistency: ConsistencyRule {
            min_views: args.consistency_views,
            max_depth_error: args.consistency_depth,
            max_reprojection_px: args.consistency_px,
        },
        consistency_neighbours: args.consistency_neighbours,
        edge_ratio: args.edge_ratio,
        min_component_triangles: args.min_component,
        fusion_weight: args.fusion_weight,
        feature_cache_mb: args.feature_cache_mb,
    };
    let plan = cfg.plan(&seq)?;
    let keys: Vec<usize> = plan.keyframes.iter().map(|k| k.index).collect();
    // Every keyframe's window must leave a live frame.
    for k in &plan.keyframes {
        let mut c = cfg.keyframe.clone();
        (c.keyframe, c.past, c.future) = (k.index, k.past, k.future);
        c.live_frames(seq.len()).map_err(|e| flag("frames", e.to_string()))?;
    }
    mapping_preflight(&seq, &cfg.keyframe, &keys[..1], std::slice::from_ref(&args.features), "map")?;
    densefeat::memory::check(
        cfg.keyframe.max_memory_mb,
        "the TSDF volumes (bounded by the keyframes' frusta)",
        plan.fusion_bytes_bound,
        "use a larger --voxel-size or a smaller --max-fusion-depth",
    )?;
    println!(
        "map: {} frames {}..={}, {} keyframes {:?}; fusion volume at most {} MiB",
        args.sequence.display(),
        cfg.frames.0,
        cfg.frames.1,
        keys.len(),
        keys,
        plan.fusion_bytes_bound.div_ceil(1 << 20)
    );
    let bar = progress_bar();
    let result = map_sequence(&seq, &cfg, &args.out, |done, total, msg| {
        bar.set_length(total as u64);
        bar.set_position(done as u64);
        bar.set_message(msg.to_string());
    });
    bar.finish_and_clear();
    let s = result?;
    let t = &s.timings;
    let computed: Vec<f64> = t.keyframes.iter().map(|k| k.1).collect();
    // (An empty f64 sum is -0.0: say 0 when nothing was computed.)
    let mean = if computed.is_empty() { 0.0 } else { computed.iter().sum::<f64>() / computed.len() as f64 };
    println!(
        "keyframes: {} computed ({:.1} s each on average), {} reused; fusion {:.2} s, mesh {:.2} s, \
         metrics {:.2} s, writing {:.2} s",
        computed.len(),
        mean,
        s.resumed.len(),
        t.fusion,
        t.mesh,
        t.metrics,
        t.write
    );
    let (hits, misses) = s.feature_cache;
    if hits > 0 {
        println!(
            "features: {hits} of {} frames taken from the cache of earlier keyframes (--feature-cache-mb {})",
            hits + misses,
            args.feature_cache_mb
        );
    }
    let (before, after) = s.fused_pixels;
    if args.consistency_views > 0 && before > 0 {
        let share = after as f64 / before as f64;
        println!(
            "depth filter (SPEC.md §16.10): {after} of {before} confident keyframe pixels kept ({:.0} %)",
            100.0 * share
        );
        // A quarter: below every validation scene (the real room keeps a third, the renders 65-90 %).
        if share < LOW_CONFIRMED_SHARE {
            println!(
                "warning: most keyframe depth is not confirmed by the neighbouring keyframes, so the mesh will be \
                 fragmentary: the depth maps disagree (fast motion or blur, poses that disagree with the images, \
                 or too little baseline); `python3 tools/map/pose_depth_consistency.py SEQ` checks the poses of an \
                 RGB-D capture"
            );
        }
    }
    if let Some(median) = densefeat::mapping::parallax::median_over_keyframes(&s.triangulation_deg) {
        let (lo, hi) = s
            .triangulation_deg
            .iter()
            .flatten()
            .fold((f64::INFINITY, 0.0f64), |(lo, hi), &a| (lo.min(a), hi.max(a)));
        println!(
            "parallax (SPEC.md §16.11): median triangulation angle {median:.2}° over the keyframes \
             ({lo:.2}-{hi:.2}° per keyframe)"
        );
        if median < densefeat::mapping::parallax::MIN_TRIANGULATION_DEG {
            println!(
                "warning: the camera mostly turns instead of moving: its live frames see the keyframes' points \
                 under {median:.2}° (under {}°), too little parallax to triangulate depth to a few per cent, so \
                 the mesh will be inaccurate and sparse; film while moving the camera sideways (10-30 cm \
                 between views of the same surface)",
                densefeat::mapping::parallax::MIN_TRIANGULATION_DEG
            );
        }
    }
    println!("mesh: {} vertices, {} triangles", s.mesh.0, s.mesh.1);
    if s.components.removed_components > 0 {
        println!(
            "removed {} of {} connected pieces ({} triangles) below --min-component {}",
            s.components.removed_components,
            s.components.components,
            s.components.removed_triangles,
            args.min_component
        );
    }
    if let Some(m) = &s.metrics {
        println!(
            "against the fused ground truth: accuracy {:.4} m, completeness {:.4} m, precision {:.4}, \
             recall {:.4}, F-score {:.4} at {} m",
            m.accuracy, m.completeness, m.precision, m.recall, m.fscore, m.threshold
        );
        let at: Vec<String> = m
            .standard
            .iter()
            .map(|t| {
                format!(
                    "{:.0} cm {:.4} (P {:.4}, R {:.4})",
                    t.threshold * 100.0,
                    t.fscore,
                    t.precision,
                    t.recall
                )
            })
            .collect();
        println!("F-score at {}", at.join(", "));
    }
    if let Some(b) = &s.metrics_gt_depth {
        println!(
            "the ground-truth depth fused as the estimate is (the fusion's upper bound): precision {:.4}, \
             recall {:.4}, F-score {:.4} at {} m",
            b.precision, b.recall, b.fscore, b.threshold
        );
    }
    let gt = if s.metrics.is_some() { ", mesh_gt.ply (the fused ground truth)" } else { "" };
    println!("wrote mesh.ply, mesh.png, map.json{gt} to {}", args.out.display());
    Ok(())
}
