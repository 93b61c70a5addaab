//! What fills the cost volume: raw RGB (the DTAM baseline) or the learned features, on one common
//! grid. The learned network outputs its features at pyramid level `L` (1 with block-1 stride 2,
//! SPEC.md §8); the RGB baseline is brought to the same level with the 2x tent downsampling of
//! SPEC.md §2.1, so both methods are matched and evaluated at the same resolution with the level-`L`
//! intrinsics of SPEC.md §2.6.

use std::path::{Path, PathBuf};

use ndarray::{Array3, ArrayView3};

use crate::error::{Error, Result};
use crate::geometry::PinholeCamera;
use crate::image::RgbImage;
use crate::nn::{downsample2x, FeatureNet, NetworkImpl, NetworkWeights};

/// The weights shipped in `fixtures/weights/`, compiled into the binary so that the demo and
/// `--features learned` need no file at run time.
pub const SHIPPED_WEIGHTS: &[u8] =
    include_bytes!("../../fixtures/weights/featurenet_trained_b1s2.safetensors");

/// Name the shipped weights carry in messages.
pub const SHIPPED_WEIGHTS_NAME: &str = "fixtures/weights/featurenet_trained_b1s2.safetensors (built in)";

/// Which features to match.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum FeatureKind {
    /// Raw RGB, 3 channels, 0-255 (DTAM's photometric error).
    Rgb,
    /// The learned network: the shipped weights (`None`) or a safetensors file.
    Learned(Option<PathBuf>),
}

impl std::str::FromStr for FeatureKind {
    type Err = Error;

    /// `rgb`, `learned`, or `learned=PATH`.
    fn from_str(s: &str) -> Result<Self> {
        match s {
            "rgb" => Ok(FeatureKind::Rgb),
            "learned" => Ok(FeatureKind::Learned(None)),
            _ => match s.strip_prefix("learned=") {
                Some(p) if !p.is_empty() => Ok(FeatureKind::Learned(Some(PathBuf::from(p)))),
                _ => Err(Error::invalid_argument(
                    "--features",
                    format!("{s:?}: expected rgb, learned or learned=WEIGHTS"),
                )),
            },
        }
    }
}

/// Features of one image on the level-`level` grid, `[H_l, W_l, C]`.
#[derive(Clone, Debug)]
pub struct FeatureMap {
    /// The features, channels-last.
    pub data: Array3<f32>,
    /// Pyramid level of the grid they live on.
    pub level: u32,
}

/// Turns images into feature maps of one [`FeatureKind`].
#[derive(Debug)]
pub struct FeatureExtractor {
    kind: FeatureKind,
    net: Option<FeatureNet>,
    level: u32,
}

impl FeatureExtractor {
    /// Load the network if needed. RGB features are produced at `rgb_level` (use
    /// [`FeatureExtractor::network_level`] of a learned extractor to compare at the same grid).
    ///
    /// # Errors
    /// Weight-file errors naming the file.
    pub fn new(kind: FeatureKind, rgb_level: u32) -> Result<Self> {
        let net = match &kind {
            FeatureKind::Rgb => None,
            FeatureKind::Learned(None) => Some(FeatureNet::new(NetworkWeights::from_safetensors_bytes(
                SHIPPED_WEIGHTS,
                Path::new(SHIPPED_WEIGHTS_NAME),
            )?)?),
            FeatureKind::Learned(Some(p)) => Some(FeatureNet::new(NetworkWeights::load(p)?)?),
        };
        let level = match &net {
            Some(n) => Self::output_level(n),
            None => rgb_level,
        };
        Ok(Self { kind, net, level })
    }

    fn output_level(net: &FeatureNet) -> u32 {
        net.config().block_level(0) as u32
    }

    /// The level at which the shipped network outputs features (its block-1 grid).
    ///
    /// # Errors
    /// If the shipped weights fail to load (a build error, tested).
    pub fn network_level() -> Result<u32> {
        let w = NetworkWeights::from_safetensors_bytes(SHIPPED_WEIGHTS, Path::new(SHIPPED_WEIGHTS_NAME))?;
        Ok(w.config.block_level(0) as u32)
    }

    /// What it extracts.
    pub fn kind(&self) -> &FeatureKind {
        &self.kind
    }

    /// A short name for tables: `rgb` or `learned`.
    pub fn name(&self) -> &'static str {
        match self.kind {
            FeatureKind::Rgb => "rgb",
            FeatureKind::Learned(_) => "learned",
        }
    }

    /// Pyramid level of the output grid.
    pub fn level(&self) -> u32 {
        self.level
    }

    /// The camera of the output grid for a level-0 camera `k` (SPEC.md §2.6).
    pub fn camera(&self, k: &PinholeCamera) -> PinholeCamera {
        k.at_level(self.level)
    }

    /// Features of an RGB image (`[H, W, 3]`, 0-255).
    ///
    /// # Errors
    /// Shape errors from the kernels (not `[H, W, 3]`).
    pub fn extract(&self, rgb: &RgbImage) -> Result<FeatureMap> {
        let data = match &self.net {
            Some(net) => net.forward(rgb.view(), NetworkImpl::FAST)?.features().clone(),
            None => downsample_to(rgb.view(), self.level)?,
        };
        Ok(FeatureMap { data, level: self.level })
    }
}

/// Apply the 2x tent downsampling `level` times.
///
/// # Errors
/// Shape errors from [`downsample2x`].
pub fn downsample_to(x: ArrayView3<f32>, level: u32) -> Result<Array3<f32>> {
    let mut out = x.to_owned();
    for _ in 0..level {
        out = downsample2x(out.view())?;
    }
    Ok(out)
}
