//! `densefeat features`: run the feature network on one image and save the features as `.npy`
//! (and optionally a PCA picture of them).

use std::path::{Path, PathBuf};

use clap::Args;

use super::backend_flag::BackendFlag;
use densefeat::backend::Backend;
use densefeat::error::Result;
use densefeat::image::{load_rgb, read_dimensions, save_rgb_png};
use densefeat::io::{write_npy_f32, Staging};
use densefeat::mapping::features::load_weights;
use densefeat::nn::viz::pca_rgb;
use densefeat::nn::{FeatureNet, NetworkWeights};

use super::validate::{flag, MemoryLimit};

/// Arguments of `densefeat features`.
#[derive(Debug, Clone, Args)]
pub struct FeaturesArgs {
    /// Input image (8-bit PNG or JPEG).
    pub image: PathBuf,
    /// Weights (`.safetensors`, SPEC.md §8.4). Default: the shipped trained weights
    /// (fixtures/weights/featurenet_trained_mf8sow.safetensors, built into the binary: no file needed).
    #[arg(long)]
    pub weights: Option<PathBuf>,
    /// Output `.npy`: `[H_l, W_l, C]` f32, C order, where `l` is block 1's level.
    #[arg(long)]
    pub out: PathBuf,
    /// Also write a PNG of the features' top three principal components.
    #[arg(long)]
    pub viz: Option<PathBuf>,
    /// Memory limit.
    #[command(flatten)]
    pub memory: MemoryLimit,
    /// Where the network runs.
    #[command(flatten)]
    pub backend: BackendFlag,
}

fn features_with(
    image: &Path,
    weights: NetworkWeights,
    backend: &dyn Backend,
) -> Result<ndarray::Array3<f32>> {
    let net = FeatureNet::new(weights)?;
    let rgb = load_rgb(image)?;
    net.features(rgb.view(), backend)
}

/// Runs the command.
///
/// # Errors
/// Reading or writing errors naming the file.
pub fn run(args: FeaturesArgs) -> Result<()> {
    let start = std::time::Instant::now();
    // Up front (SPEC.md §14.1): the image header, the weights, the memory, the output paths.
    let backend = args.backend.resolve()?;
    let (w, h) = read_dimensions(&args.image)?;
    let weights = load_weights(args.weights.as_deref())?;
    let config = &weights.config;
    let bytes = densefeat::memory::network_forward_bytes(h, w, config.channels, config.b1_stride);
    let what = format!("the network on {} ({w}x{h} pixels, from its header)", args.image.display());
    args.memory.check(&what, bytes, "use a smaller image")?;
    if args.viz.as_ref() == Some(&args.out) {
        return Err(flag("viz", "is the same file as --out"));
    }
    let mut staging = Staging::new();
    let out = staging.file(&args.out)?;
    let viz = args.viz.as_ref().map(|v| staging.file(v)).transpose()?;
    let feats = features_with(&args.image, weights, backend.as_ref())?;
    write_npy_f32(&out, feats.view())?;
    if let Some(viz) = &viz {
        save_rgb_png(viz, &pca_rgb(feats.view())?)?;
    }
    staging.commit()?;
    let (h, w, c) = feats.dim();
    eprintln!(
        "features: {} -> {} [{h}, {w}, {c}] in {:.2} s",
        args.image.display(),
        args.out.display(),
        start.elapsed().as_secs_f64()
    );
    Ok(())
}
