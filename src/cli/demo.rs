//! `densefeat demo`: reconstruct a keyframe of the shipped synthetic fixture with RGB and learned
//! features, winner-take-all and TV; print the table and write the pictures.

use std::path::PathBuf;

use clap::Args;

use crate::error::Result;
use crate::mapping::evaluate::{EvalOptions, Method};
use crate::mapping::keyframe::Regularizer;
use crate::mapping::FeatureKind;

use super::eval::{print_table, run_eval};
use super::mapping_args::MappingArgs;

/// The shipped fixture, in the source tree.
pub const FIXTURE: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/fixtures/synthetic/room_s1");

/// Arguments of `densefeat demo` (all optional).
#[derive(Debug, Clone, Args)]
pub struct DemoArgs {
    /// Sequence folder.
    #[arg(long, default_value = FIXTURE)]
    pub sequence: PathBuf,
    /// Keyframe index.
    #[arg(long, default_value_t = 20)]
    pub keyframe: usize,
    /// Output folder.
    #[arg(long, default_value = "demo_out")]
    pub out: PathBuf,
    /// Mapping flags (the demo's window defaults to 30,30, clamped to the fixture's 40 frames).
    #[command(flatten)]
    pub mapping: MappingArgs,
}

/// Runs the command.
///
/// # Errors
/// Reading or writing errors.
pub fn run(args: DemoArgs) -> Result<()> {
    let seq = args.mapping.open_sequence(&args.sequence)?;
    let cfg = args.mapping.config(&seq, args.keyframe, FeatureKind::Rgb, Regularizer::Tv)?;
    println!(
        "demo: {} ({} frames), keyframe {}, window {},{}, {} bins over {}..{} m",
        args.sequence.display(),
        seq.len(),
        args.keyframe,
        args.mapping.window.0,
        args.mapping.window.1,
        args.mapping.bins,
        cfg.near,
        cfg.far
    );
    let kinds = [FeatureKind::Rgb, FeatureKind::Learned(None)];
    super::validate::mapping_preflight(&seq, &cfg, &[args.keyframe], &kinds, "demo")?;
    let mut staging = crate::io::Staging::new();
    let out = staging.dir(&args.out)?;
    let table = run_eval(&seq, &args.mapping, &[args.keyframe], &Method::ALL, &out, true, || EvalOptions {
        min_confidence: args.mapping.min_confidence,
        ..EvalOptions::default()
    })?;
    staging.commit()?;
    print_table(&table, &args.out);
    let out = args.out.canonicalize().unwrap_or(args.out.clone());
    println!(
        "pictures: {}/kf_{:05}_{{rgb,learned}}/ (depth_*_color.png, cloud_*.ply, keyframe.png)",
        out.display(),
        args.keyframe
    );
    Ok(())
}
