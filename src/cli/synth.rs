//! `densefeat synth`: render a synthetic posed RGB-D sequence into a DeepVideoMVS-layout folder.

use std::io::Write;
use std::path::PathBuf;

use clap::Args;

use crate::error::{Error, Result};
use crate::synth::{write_scene, Scene, SceneConfig};

/// Arguments of `densefeat synth`.
#[derive(Debug, Clone, Args)]
pub struct SynthArgs {
    /// Scene seed: fixes the room, objects, textures, camera path and photometric drift.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Number of frames to render.
    #[arg(long, default_value_t = 40)]
    pub frames: usize,
    /// Image size as WIDTHxHEIGHT.
    #[arg(long, default_value = "320x240")]
    pub size: String,
    /// Output folder (created if missing; existing frames are overwritten).
    #[arg(long)]
    pub out: PathBuf,
    /// Do not print progress on stderr.
    #[arg(long)]
    pub quiet: bool,
}

/// Parse `WIDTHxHEIGHT` (e.g. `320x240`) into `(width, height)`, each in `1..=8192`.
///
/// # Errors
/// [`Error::InvalidArgument`] naming `--size` when the text is not two positive integers joined by `x`.
pub fn parse_size(text: &str) -> Result<(usize, usize)> {
    super::validate::size("size", text)
}

/// Render the sequence the arguments describe.
///
/// # Errors
/// [`Error::InvalidArgument`] for a bad size or frame count; [`Error::Io`] on a write failure.
pub fn run(args: SynthArgs) -> Result<()> {
    let (width, height) = parse_size(&args.size)?;
    if args.frames == 0 {
        return Err(Error::invalid_argument("--frames", "0: must be at least 1"));
    }
    let cfg = SceneConfig { seed: args.seed, width, height, frames: args.frames, ..SceneConfig::default() };
    let scene = Scene::generate(&cfg)?;
    let start = std::time::Instant::now();
    let quiet = args.quiet;
    if !quiet {
        for line in scene.summary() {
            eprintln!("synth: {line}");
        }
    }
    let mut staging = crate::io::Staging::new();
    let out = staging.dir(&args.out)?;
    write_scene(&scene, &out, |done, total| {
        if !quiet {
            eprint!("\rsynth: {done}/{total} frames");
            let _ = std::io::stderr().flush();
        }
    })?;
    staging.commit()?;
    if !quiet {
        eprintln!(
            "\rsynth: wrote {} frames of {width}x{height} to {} in {:.1} s",
            cfg.frames,
            args.out.display(),
            start.elapsed().as_secs_f64()
        );
    }
    Ok(())
}
