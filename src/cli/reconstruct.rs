//! `densefeat reconstruct`: one keyframe's depth from a window of live frames (SPEC.md §11).

use std::path::PathBuf;

use clap::Args;

use densefeat::error::Result;
use densefeat::eval::DepthMetrics;
use densefeat::io::Staging;
use densefeat::mapping::{reconstruct, write_outputs_with, FeatureKind, Regularizer};

use super::mapping_args::{progress_bar, show_stage, summary, MappingArgs};
use super::validate::mapping_preflight;

/// Arguments of `densefeat reconstruct`.
#[derive(Debug, Clone, Args)]
pub struct ReconstructArgs {
    /// Sequence folder (any format `densefeat inspect` reads).
    #[arg(long)]
    pub sequence: PathBuf,
    /// Keyframe index.
    #[arg(long)]
    pub keyframe: usize,
    /// `rgb`, `learned` (shipped weights), `learned=WEIGHTS.safetensors`, `b1` / `b1=WEIGHTS` (block 1
    /// of the network alone), `dsift` (dense SIFT) or `patch7` (affine-warped 7x7 patches), SPEC.md §9a.
    #[arg(long, default_value = "rgb")]
    pub features: FeatureKind,
    /// `none` (winner-take-all), `tv` (DTAM, initialised by winner-take-all), `tgv` (DTAM with
    /// second-order TGV in place of Huber-TV, SPEC.md §10.4) or `normals` (DTAM with
    /// the surface-normal prior, SPEC.md §10.2, with `--normals`' or the built-in predictor's
    /// normals). [default: per feature type, chosen on validation (SPEC.md §10.1a): `normals` for
    /// the learned features, `tv` for the others]
    #[arg(long)]
    pub regularizer: Option<Regularizer>,
    /// Mapping flags.
    #[command(flatten)]
    pub mapping: MappingArgs,
    /// Output folder.
    #[arg(long)]
    pub out: PathBuf,
}

/// Runs the command.
///
/// # Errors
/// Bad arguments, reading or writing errors.
pub fn run(args: ReconstructArgs) -> Result<()> {
    let seq = args.mapping.open_sequence(&args.sequence)?;
    let regularizer = match args.regularizer {
        Some(r) => r,
        None => Regularizer::default_for(&args.features, args.mapping.normals_source()?.is_some()),
    };
    let cfg = args.mapping.config(&seq, args.keyframe, args.features.clone(), regularizer)?;
    mapping_preflight(&seq, &cfg, &[args.keyframe], std::slice::from_ref(&args.features), "reconstruct")?;
    let mut staging = Staging::new();
    let out = staging.dir(&args.out)?;
    let bar = progress_bar();
    let result = reconstruct(&seq, &cfg, |s, d, t| show_stage(&bar, "", s, d, t));
    bar.finish_and_clear();
    let result = result?;
    println!("{}", summary(&result));
    if result.gt_depth.is_some() {
        println!("metrics (level-{} ground truth):", result.level);
        println!("  wta: {}", metrics_line(&result.metrics(&result.wta)?));
        if let Some(tv) = &result.tv {
            println!("  {}:  {}", result.tv_name(), metrics_line(&result.metrics(tv)?));
        }
        if let Some(n) = &result.normals {
            println!("  normals: {}", metrics_line(&result.metrics(n)?));
        }
        if let Some(e) = &result.normals_error {
            println!(
                "  predicted normals (--normals learned) against the ground truth's: mean {:.2}°, median {:.2}° over {} pixels",
                e.mean_deg, e.median_deg, e.pixels
            );
        }
        let c = args.mapping.min_confidence;
        if c > 0.0 {
            println!("metrics at confidence >= {c}:");
            println!("  wta: {}", metrics_line(&result.metrics_at(&result.wta, c)?));
            if let Some(tv) = &result.tv {
                println!("  {}:  {}", result.tv_name(), metrics_line(&result.metrics_at(tv, c)?));
            }
            if let Some(n) = &result.normals {
                println!("  normals: {}", metrics_line(&result.metrics_at(n, c)?));
            }
        }
    }
    let t = std::time::Instant::now();
    let files = write_outputs_with(&result, &out, args.mapping.min_confidence)?;
    staging.commit()?;
    // Writing is outside the keyframe's stage times (metrics.json is written with them).
    println!("wrote {} files to {} in {:.2} s", files.len(), args.out.display(), t.elapsed().as_secs_f64());
    Ok(())
}

fn metrics_line(m: &DepthMetrics) -> String {
    format!(
        "rms {:.4} m, log {:.4}, abs rel {:.4}, sq rel {:.4}, δ<1.1 {:.4}, δ<1.25 {:.4}, δ<1.25² {:.4}, \
         δ<1.25³ {:.4} ({} px, coverage {:.3})",
        m.rms,
        m.log_rms,
        m.abs_rel,
        m.sq_rel,
        m.delta_1_1,
        m.delta_1_25,
        m.delta_1_25_2,
        m.delta_1_25_3,
        m.count,
        m.coverage
    )
}
