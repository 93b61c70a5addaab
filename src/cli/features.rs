//! `densefeat features`: run the feature network on one image and save the features as `.npy`
//! (and optionally a PCA picture of them).

use std::path::{Path, PathBuf};

use clap::Args;

use crate::error::Result;
use crate::image::{load_rgb, save_rgb_png};
use crate::io::write_npy_f32;
use crate::nn::viz::pca_rgb;
use crate::nn::{FeatureNet, NetworkImpl, NetworkWeights};

/// The shipped trained weights (fixtures/weights/MODEL_CARD.md), in the source tree.
pub const DEFAULT_WEIGHTS: &str =
    concat!(env!("CARGO_MANIFEST_DIR"), "/fixtures/weights/featurenet_trained_b1s2.safetensors");

/// Arguments of `densefeat features`.
#[derive(Debug, Clone, Args)]
pub struct FeaturesArgs {
    /// Input image (8-bit PNG or JPEG).
    pub image: PathBuf,
    /// Weights (`.safetensors`, SPEC.md §8.4). Default: the shipped untrained init weights.
    #[arg(long, default_value = DEFAULT_WEIGHTS)]
    pub weights: PathBuf,
    /// Output `.npy`: `[H_l, W_l, C]` f32, C order, where `l` is block 1's level.
    #[arg(long)]
    pub out: PathBuf,
    /// Also write a PNG of the features' top three principal components.
    #[arg(long)]
    pub viz: Option<PathBuf>,
}

/// Computes the features of `image` with the weights at `weights`.
///
/// # Errors
/// Reading errors naming the file.
pub fn features_of(image: &Path, weights: &Path) -> Result<ndarray::Array3<f32>> {
    let net = FeatureNet::new(NetworkWeights::load(weights)?)?;
    let rgb = load_rgb(image)?;
    let out = net.forward(rgb.view(), NetworkImpl::FAST)?;
    Ok(out.aggregated.into_iter().next().unwrap_or_default())
}

/// Runs the command.
///
/// # Errors
/// Reading or writing errors naming the file.
pub fn run(args: FeaturesArgs) -> Result<()> {
    let start = std::time::Instant::now();
    let feats = features_of(&args.image, &args.weights)?;
    write_npy_f32(&args.out, feats.view())?;
    if let Some(viz) = &args.viz {
        save_rgb_png(viz, &pca_rgb(feats.view())?)?;
    }
    let (h, w, c) = feats.dim();
    eprintln!(
        "features: {} -> {} [{h}, {w}, {c}] in {:.2} s",
        args.image.display(),
        args.out.display(),
        start.elapsed().as_secs_f64()
    );
    Ok(())
}
