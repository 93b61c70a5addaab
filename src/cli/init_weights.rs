//! `densefeat init-weights`: write Xavier-initialised (untrained) feature-network weights.

use std::path::{Path, PathBuf};

use clap::Args;

use densefeat::error::{Error, Result};
use densefeat::image::load_rgb;
use densefeat::nn::NetworkWeights;
use densefeat::ops::NetworkConfig;
use densefeat::sequence::COLOUR_EXTENSIONS;

/// Arguments of `densefeat init-weights`.
#[derive(Debug, Clone, Args)]
pub struct InitWeightsArgs {
    /// RNG seed of the Xavier-uniform draw (SPEC.md §8.6).
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Number of encoder blocks (1-5).
    #[arg(long, default_value_t = 5)]
    pub blocks: usize,
    /// Channels of every layer.
    #[arg(long, default_value_t = 32)]
    pub channels: usize,
    /// Stride of block 1 (1 or 2).
    #[arg(long, default_value_t = 2)]
    pub b1_stride: usize,
    /// Input mean as "r,g,b" (0-255 scale).
    #[arg(long, conflicts_with = "mean_of_images", default_value = "0,0,0")]
    pub mean: String,
    /// Measure the input mean as the mean colour of every PNG in this folder instead.
    #[arg(long)]
    pub mean_of_images: Option<PathBuf>,
    /// Output `.safetensors` file (written atomically).
    #[arg(long)]
    pub out: PathBuf,
}

/// Parses "r,g,b".
pub(crate) fn parse_mean(text: &str) -> Result<[f32; 3]> {
    let bad = || Error::invalid_argument("--mean", format!("{text:?}: expected three numbers r,g,b"));
    let values: Vec<f32> =
        text.split(',').map(|p| p.trim().parse().map_err(|_| bad())).collect::<Result<_>>()?;
    values.try_into().map_err(|_| bad())
}

/// Mean colour (f64 accumulation, rounded to f32) of every `.png`, `.jpg` and `.jpeg` in `dir`, all pixels weighted
/// equally.
///
/// # Errors
/// [`Error::Io`] / [`Error::BadFile`] from reading; [`Error::InvalidArgument`] if there is no PNG.
pub fn mean_colour_of_pngs(dir: &Path) -> Result<[f32; 3]> {
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
        .map_err(|e| Error::io(dir, e))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| {
            p.extension().is_some_and(|x| COLOUR_EXTENSIONS.iter().any(|c| x.eq_ignore_ascii_case(c)))
        })
        .collect();
    files.sort();
    if files.is_empty() {
        return Err(Error::invalid_argument(
            "--mean-of-images",
            format!("no .png/.jpg/.jpeg in {}", dir.display()),
        ));
    }
    let (mut sum, mut count) = ([0.0f64; 3], 0usize);
    for f in &files {
        let img = load_rgb(f)?;
        for px in img.rows() {
            for (s, v) in sum.iter_mut().zip(px.iter()) {
                *s += f64::from(*v);
            }
            count += 1;
        }
    }
    Ok(sum.map(|s| (s / count as f64) as f32))
}

/// Writes the weights the arguments describe.
///
/// # Errors
/// [`Error::InvalidArgument`] for a bad configuration; I/O errors naming the file.
pub fn run(args: InitWeightsArgs) -> Result<()> {
    let input_mean = match &args.mean_of_images {
        Some(dir) => mean_colour_of_pngs(dir)?,
        None => parse_mean(&args.mean)?,
    };
    let config =
        NetworkConfig { blocks: args.blocks, channels: args.channels, b1_stride: args.b1_stride, input_mean };
    config.validate()?;
    let mut staging = densefeat::io::Staging::new();
    let out = staging.file(&args.out)?;
    let weights = NetworkWeights::xavier_uniform(&config, args.seed)?;
    weights.save(&out)?;
    staging.commit()?;
    let [r, g, b] = input_mean;
    eprintln!(
        "init-weights: wrote {} ({} blocks, {} channels, b1 stride {}, mean {r},{g},{b}, {})",
        args.out.display(),
        config.blocks,
        config.channels,
        config.b1_stride,
        weights.provenance
    );
    Ok(())
}
