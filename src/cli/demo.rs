//! `densefeat demo`: reconstruct a keyframe of the shipped synthetic fixture with RGB and learned
//! features, winner-take-all, TV and (the learned features' default) the surface-normal prior; print
//! the table and write the pictures.

use std::path::{Path, PathBuf};

use clap::Args;

use densefeat::error::Result;
use densefeat::mapping::evaluate::{EvalOptions, Method};
use densefeat::mapping::keyframe::Regularizer;
use densefeat::mapping::FeatureKind;
use densefeat::synth::{write_scene, Scene};

use super::eval::{print_table, run_eval};
use super::mapping_args::MappingArgs;

/// The shipped fixture, in the source tree.
pub const FIXTURE: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/fixtures/synthetic/room_s1");

/// Arguments of `densefeat demo` (all optional).
#[derive(Debug, Clone, Args)]
pub struct DemoArgs {
    /// Sequence folder. Default: the shipped fixture `fixtures/synthetic/room_s1`; a binary run away
    /// from its source tree renders the same fixture (synthetic seed 1) into a temporary folder.
    #[arg(long)]
    pub sequence: Option<PathBuf>,
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
    let rendered;
    let sequence = match &args.sequence {
        Some(path) => path.clone(),
        None if Path::new(FIXTURE).is_dir() => PathBuf::from(FIXTURE),
        None => {
            rendered = RenderedFixture::new()?;
            rendered.0.clone()
        }
    };
    let seq = args.mapping.open_sequence(&sequence)?;
    let cfg = args.mapping.config(&seq, args.keyframe, FeatureKind::Rgb, Regularizer::Tv)?;
    println!(
        "demo: {} ({} frames), keyframe {}, window {},{}, {} bins over {}..{} m",
        sequence.display(),
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
    let mut staging = densefeat::io::Staging::new();
    let out = staging.dir(&args.out)?;
    let table =
        run_eval(&seq, &args.mapping, &[args.keyframe], &Method::DEFAULT, &out, (true, true), || {
            EvalOptions {
                min_confidence: args.mapping.min_confidence,
                lambda_per_kind: args.mapping.lambda.is_none(),
                ..EvalOptions::default()
            }
        })?;
    staging.commit()?;
    print_table(&table, &args.out);
    let out = args.out.canonicalize().unwrap_or(args.out.clone());
    println!(
        "pictures: {}/kf_{:05}_{{rgb,learned}}/ (depth_*_color.png, cloud_*.ply, keyframe.png)",
        out.display(),
        args.keyframe
    );
    println!(
        "figure: {}/figure_kf{:05}.png (every method's depth beside the ground truth)",
        out.display(),
        args.keyframe
    );
    Ok(())
}

/// The fixture rendered into a fresh temporary folder, removed again when dropped.
struct RenderedFixture(PathBuf);

impl RenderedFixture {
    fn new() -> Result<Self> {
        let dir = std::env::temp_dir().join(format!("densefeat-demo-room_s1-{}", std::process::id()));
        let guard = Self(dir);
        let _ = std::fs::remove_dir_all(&guard.0);
        std::fs::create_dir_all(&guard.0).map_err(|e| densefeat::error::Error::io(&guard.0, e))?;
        eprintln!(
            "demo: {FIXTURE} is not here; rendering the same fixture (synthetic seed 1) into {}",
            guard.0.display()
        );
        write_scene(&Scene::generate(&densefeat::synth::demo_fixture_config())?, &guard.0, |_, _| {})?;
        Ok(guard)
    }
}

impl Drop for RenderedFixture {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}
