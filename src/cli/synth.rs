//! `densefeat synth`: render a synthetic posed RGB-D sequence into a DeepVideoMVS-layout folder.

use std::io::Write;
use std::path::PathBuf;

use clap::Args;

use densefeat::error::{Error, Result};
use densefeat::synth::{write_scene, Motion, Scene, SceneConfig, Style};

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
    /// Scene style: `classic` (procedural textures, fixed intrinsics; the fixture's style) or
    /// `real` (photo textures, furniture, random intrinsics, realistic sensor with blur and JPEG).
    #[arg(long, default_value = "classic")]
    pub style: String,
    /// Camera motion: `handheld` (a walk with up to half a metre of translation) or `turn` (turning
    /// on the spot: a tenth of the translation, three times the panning; rotation-dominant, weak
    /// parallax, as TUM fr1/rpy).
    #[arg(long, default_value = "handheld")]
    pub motion: String,
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
    let style: Style = args.style.parse()?;
    let motion: Motion = args.motion.parse()?;
    let cfg = SceneConfig {
        seed: args.seed,
        width,
        height,
        frames: args.frames,
        style,
        motion,
        ..SceneConfig::default()
    };
    let scene = Scene::generate(&cfg)?;
    let start = std::time::Instant::now();
    let quiet = args.quiet;
    if !quiet {
        for line in scene.summary() {
            eprintln!("synth: {line}");
        }
    }
    let mut staging = densefeat::io::Staging::new();
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

/// Arguments of `densefeat synth-sheet`.
#[derive(Debug, Clone, Args)]
pub struct SynthSheetArgs {
    /// Scene style (`classic` or `real`).
    #[arg(long, default_value = "real")]
    pub style: String,
    /// First seed; the sheet shows seeds FIRST .. FIRST + count.
    #[arg(long, default_value_t = 100_000)]
    pub first_seed: u64,
    /// Number of scenes.
    #[arg(long, default_value_t = 12)]
    pub count: usize,
    /// Frame rendered of each scene.
    #[arg(long, default_value_t = 20)]
    pub frame: usize,
    /// Size of each image, WIDTHxHEIGHT.
    #[arg(long, default_value = "320x240")]
    pub size: String,
    /// Images per row.
    #[arg(long, default_value_t = 4)]
    pub columns: usize,
    /// Output PNG.
    #[arg(long)]
    pub out: PathBuf,
}

/// Gap between sheet cells, pixels.
const SHEET_GAP: usize = 4;

/// Render frame `--frame` of `--count` scenes into one PNG grid.
///
/// # Errors
/// [`Error::InvalidArgument`] for a bad flag; [`Error::Io`] on a write failure.
pub fn run_sheet(args: SynthSheetArgs) -> Result<()> {
    let (width, height) = parse_size(&args.size)?;
    let style: Style = args.style.parse()?;
    if args.count == 0 || args.columns == 0 {
        return Err(Error::invalid_argument("--count/--columns", "must be at least 1"));
    }
    let rows = args.count.div_ceil(args.columns);
    let (sw, sh) = (args.columns * (width + SHEET_GAP) + SHEET_GAP, rows * (height + SHEET_GAP) + SHEET_GAP);
    let mut sheet = ndarray::Array3::<f32>::from_elem((sh, sw, 3), 255.0);
    for k in 0..args.count {
        let seed = args.first_seed + k as u64;
        let cfg =
            SceneConfig { seed, width, height, frames: args.frame + 1, style, ..SceneConfig::default() };
        let frame = Scene::generate(&cfg)?.render(args.frame)?;
        let (ox, oy) = (
            SHEET_GAP + (k % args.columns) * (width + SHEET_GAP),
            SHEET_GAP + (k / args.columns) * (height + SHEET_GAP),
        );
        sheet.slice_mut(ndarray::s![oy..oy + height, ox..ox + width, ..]).assign(&frame.rgb);
    }
    densefeat::image::save_rgb_png(&args.out, &sheet)?;
    eprintln!(
        "synth-sheet: {} {style} scenes (seeds {}..) written to {}",
        args.count,
        args.first_seed,
        args.out.display()
    );
    Ok(())
}
