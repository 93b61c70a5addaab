//! `densefeat inspect PATH`: open a sequence folder (any supported format) and print its
//! [`Summary`].

use std::path::PathBuf;

use clap::Args;

use densefeat::error::Result;
use densefeat::sequence::inspect::Summary;
use densefeat::sequence::{open_with, CameraChoice, OpenOptions, DEFAULT_MAX_TIME_GAP};

/// Arguments of `densefeat inspect`.
#[derive(Debug, Args)]
pub struct InspectArgs {
    /// Sequence folder (TUM RGB-D / ICL-NUIM, DeepVideoMVS, 7-Scenes, COLMAP, transforms.json, or a
    /// rectified stereo pair).
    pub path: PathBuf,
    /// Camera for formats without one: fr1, fr2, fr3, icl, ros, or a camera file
    /// (`fx fy cx cy [k1 k2 p1 p2 [k3]]`, optional second line `width height`).
    #[arg(long)]
    pub camera: Option<String>,
    /// Largest rgb-depth timestamp difference when associating TUM frames, seconds.
    #[arg(long, default_value_t = DEFAULT_MAX_TIME_GAP)]
    pub max_gap: f64,
    /// Keep raw distorted frames instead of undistorting them on load.
    #[arg(long)]
    pub no_undistort: bool,
    /// Metres per unit of the sequence's poses and depths (makes a COLMAP model metric).
    #[arg(long)]
    pub scale: Option<f64>,
}

/// Open the sequence and print its summary to stdout.
///
/// # Errors
/// Any error opening the sequence or loading its frames, naming the file.
pub fn run(args: InspectArgs) -> Result<()> {
    let camera = args.camera.as_deref().map(str::parse::<CameraChoice>).transpose()?;
    let options = OpenOptions {
        camera,
        max_time_gap: args.max_gap,
        undistort: !args.no_undistort,
        scale: args.scale,
        ..OpenOptions::default()
    };
    let seq = open_with(&args.path, &options)?;
    print!("{}", Summary::new(&seq)?);
    Ok(())
}
