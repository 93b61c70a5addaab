//! What fills the cost volume: raw RGB (the DTAM baseline), the learned features, or one of the
//! baselines of the paper's feature comparison (block 1 of the network alone, dense SIFT, and the
//! grey image whose affine-warped 7x7 patches the patch volume compares; SPEC.md §9a), on one common
//! output grid of pyramid level `L` (0 = the input resolution, the default; SPEC.md §11.1).
//! RGB and dense SIFT are computed at level 0 and tent-downsampled `L` times (SPEC.md §2.1). The
//! network outputs its features (and block 1 its output) at its own level `L_n` (1 with block-1
//! stride 2, 0 with block-1 stride 1, SPEC.md §8): when `L < L_n` they are bilinearly upsampled on the
//! integer-centre grid of SPEC.md §2.1 (output pixel `i` sits at network pixel `i / 2^(L_n - L)`,
//! clamped to the last network pixel), when `L > L_n` tent-downsampled. Every kind is matched and
//! evaluated on the same pixels with the level-`L` intrinsics of SPEC.md §2.6.

use std::path::{Path, PathBuf};

use ndarray::Array3;

use crate::backend::{Backend, Tensor, VolumeBuilder};
use crate::costvolume::patch::{PatchImpl, PatchVolume};
use crate::dsift::{dense_sift, DsiftImpl, DsiftParams};
use crate::error::{Error, Result};
use crate::geometry::{InverseDepthBins, PinholeCamera};
use crate::image::{to_gray, RgbImage};
use crate::nn::{FeatureNet, NetworkWeights};
use std::sync::Arc;

pub use super::resample::{
    downsample_to, downsample_to_at, upsample_to, upsample_to_at, upsample_to_reference,
};

/// The weights shipped in `fixtures/weights/`, compiled into the binary so that the demo and
/// `--features learned` need no file at run time.
pub const SHIPPED_WEIGHTS: &[u8] =
    include_bytes!("../../fixtures/weights/featurenet_trained_mf8sow.safetensors");

/// Name the shipped weights carry in messages.
pub const SHIPPED_WEIGHTS_NAME: &str = "fixtures/weights/featurenet_trained_mf8sow.safetensors (built in)";

/// The weights at `path`, or the shipped ones compiled into the binary for `None`.
///
/// # Errors
/// Weight-file errors naming the file.
pub fn load_weights(path: Option<&Path>) -> Result<NetworkWeights> {
    match path {
        Some(p) => NetworkWeights::load(p),
        None => NetworkWeights::from_safetensors_bytes(SHIPPED_WEIGHTS, Path::new(SHIPPED_WEIGHTS_NAME)),
    }
}

/// DTAM's default `λ` for RGB (SPEC.md §10.1a; validation sweep of 2026-12-03).
pub const LAMBDA_RGB: f64 = 300.0;

/// DTAM's default `λ` for the learned features (SPEC.md §10.1a; validation sweep of 2026-12-03).
pub const LAMBDA_LEARNED: f64 = 30.0;

/// The normal prior's default `λ` with RGB (SPEC.md §10.1a; validation sweep with the built-in
/// predictor's normals, 2026-12-03).
pub const LAMBDA_RGB_NORMALS: f64 = 300.0;

/// The normal prior's default `λ` with the learned features (SPEC.md §10.1a; validation sweep with
/// the built-in predictor's normals, 2026-12-03).
pub const LAMBDA_LEARNED_NORMALS: f64 = 100.0;

/// The learned features' default border taper `R` (SPEC.md §10.1c), in pixels of the input
/// resolution; chosen on the 101 validation scenes (2026-12-05) for both of their regularisers.
pub const BORDER_TAPER_LEARNED: f64 = 32.0;

/// RGB's default `c₀` of the normal prior's confidence weighting (SPEC.md §10.2), chosen on the 101
/// validation scenes (2026-12-06): rgb-normals mean δ<1.25 0.6952 unweighted, 0.7141 at 1.2 (0.8-2
/// within 0.001 of it). The learned features keep 0: at 0.1 / 0.3 their prior reads 0.9337 / 0.9330
/// against 0.9337 without.
pub const PRIOR_CONFIDENCE_RGB: f64 = 1.2;

/// The learned features' default `σ` of the normal prior's normal edges, degrees (SPEC.md §10.2,
/// "Normal edges"; chosen on the 101 validation scenes, 2026-12-07).
pub const PRIOR_EDGES_LEARNED: f64 = 30.0;

/// Which features to match.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum FeatureKind {
    /// Raw RGB, 3 channels, 0-255 (DTAM's photometric error).
    Rgb,
    /// The learned network: the shipped weights (`None`) or a safetensors file.
    Learned(Option<PathBuf>),
    /// Block 1's output of the network alone (the paper's "B1 only" baseline, SPEC.md §9a.1): the
    /// shipped weights (`None`) or a safetensors file.
    B1(Option<PathBuf>),
    /// Dense SIFT, 128 channels (SPEC.md §9a.2).
    Dsift,
    /// 7x7 grey patches, affine-warped per hypothesis before matching (SPEC.md §9a.5): the features
    /// are the grey image (1 channel) and the patch volume compares patches of it.
    Patch7,
}

impl std::str::FromStr for FeatureKind {
    type Err = Error;

    /// `rgb`, `learned`, `learned=PATH`, `b1`, `b1=PATH`, `dsift` or `patch7`.
    fn from_str(s: &str) -> Result<Self> {
        let weights = |p: &str| (!p.is_empty()).then(|| PathBuf::from(p));
        match s {
            "rgb" => return Ok(FeatureKind::Rgb),
            "learned" => return Ok(FeatureKind::Learned(None)),
            "b1" => return Ok(FeatureKind::B1(None)),
            "dsift" => return Ok(FeatureKind::Dsift),
            "patch7" => return Ok(FeatureKind::Patch7),
            _ => {}
        }
        if let Some(p) = s.strip_prefix("learned=").and_then(weights) {
            return Ok(FeatureKind::Learned(Some(p)));
        }
        if let Some(p) = s.strip_prefix("b1=").and_then(weights) {
            return Ok(FeatureKind::B1(Some(p)));
        }
        Err(Error::invalid_argument(
            "--features",
            format!("{s:?}: expected rgb, learned, learned=WEIGHTS, b1, b1=WEIGHTS, dsift or patch7"),
        ))
    }
}

impl FeatureKind {
    /// The short name used in tables, folder names and messages: `rgb`, `learned`, `b1`, `dsift` or
    /// `patch7`.
    pub fn name(&self) -> &'static str {
        match self {
            FeatureKind::Rgb => "rgb",
            FeatureKind::Learned(_) => "learned",
            FeatureKind::B1(_) => "b1",
            FeatureKind::Dsift => "dsift",
            FeatureKind::Patch7 => "patch7",
        }
    }

    /// DTAM's default `λ` for this kind (SPEC.md §10.1a), chosen on the validation scenes by mean
    /// δ<1.25 over λ ∈ {30, 100, 300, 1000, 3000}: RGB [`LAMBDA_RGB`], the learned features
    /// [`LAMBDA_LEARNED`]; the other kinds were not swept and keep [`crate::dtam::MAPPING_DEFAULTS`]'s.
    pub fn default_lambda(&self) -> f64 {
        match self {
            FeatureKind::Rgb => LAMBDA_RGB,
            FeatureKind::Learned(_) => LAMBDA_LEARNED,
            FeatureKind::B1(_) | FeatureKind::Dsift | FeatureKind::Patch7 => {
                crate::dtam::MAPPING_DEFAULTS.lambda
            }
        }
    }

    /// The default `λ` of the surface-normal prior's solve for this kind (SPEC.md §10.1a), chosen
    /// on the validation scenes with the built-in predictor's normals: RGB [`LAMBDA_RGB_NORMALS`],
    /// the learned features [`LAMBDA_LEARNED_NORMALS`]; the other kinds keep their
    /// [`FeatureKind::default_lambda`].
    pub fn default_lambda_normals(&self) -> f64 {
        match self {
            FeatureKind::Rgb => LAMBDA_RGB_NORMALS,
            FeatureKind::Learned(_) => LAMBDA_LEARNED_NORMALS,
            FeatureKind::B1(_) | FeatureKind::Dsift | FeatureKind::Patch7 => self.default_lambda(),
        }
    }

    /// The default border taper `R` of this kind's data term (SPEC.md §10.1c), in pixels of the
    /// input resolution: the learned features [`BORDER_TAPER_LEARNED`]; every other kind 0 (off: on
    /// validation it costs RGB-TV 0.005 of mean δ<1.25; the baselines were not swept).
    pub fn default_border_taper(&self) -> f64 {
        match self {
            FeatureKind::Learned(_) => BORDER_TAPER_LEARNED,
            FeatureKind::Rgb | FeatureKind::B1(_) | FeatureKind::Dsift | FeatureKind::Patch7 => 0.0,
        }
    }

    /// The default `c₀` of the normal prior's confidence weighting for this kind (SPEC.md §10.2):
    /// RGB [`PRIOR_CONFIDENCE_RGB`]; every other kind 0 (off).
    pub fn default_prior_confidence(&self) -> f64 {
        match self {
            FeatureKind::Rgb => PRIOR_CONFIDENCE_RGB,
            FeatureKind::Learned(_) | FeatureKind::B1(_) | FeatureKind::Dsift | FeatureKind::Patch7 => 0.0,
        }
    }

    /// The default `σ` (degrees) of the normal prior's normal edges for this kind (SPEC.md §10.2,
    /// "Normal edges"): the learned features [`PRIOR_EDGES_LEARNED`]; every other kind 0 (off: not
    /// measured on the 101 validation scenes).
    pub fn default_prior_edges(&self) -> f64 {
        match self {
            FeatureKind::Learned(_) => PRIOR_EDGES_LEARNED,
            FeatureKind::Rgb | FeatureKind::B1(_) | FeatureKind::Dsift | FeatureKind::Patch7 => 0.0,
        }
    }

    /// The weights file of a network kind (`None`: the shipped weights, or not a network kind).
    pub fn weights(&self) -> Option<&Path> {
        match self {
            FeatureKind::Learned(p) | FeatureKind::B1(p) => p.as_deref(),
            FeatureKind::Rgb | FeatureKind::Dsift | FeatureKind::Patch7 => None,
        }
    }

    /// Whether the features come from the network (learned, block 1).
    pub fn uses_network(&self) -> bool {
        matches!(self, FeatureKind::Learned(_) | FeatureKind::B1(_))
    }
}

/// Feature channels and the network's block-1 stride of a feature kind (`(3, 1)` for RGB, `(128, 1)`
/// for dense SIFT, `(1, 1)` for 7x7 patches), reading a weights file's header and tensors now so that a bad file is reported
/// before any work.
///
/// # Errors
/// Weight-file errors naming the file.
pub fn feature_channels(kind: &FeatureKind) -> Result<(usize, usize)> {
    let w = match kind {
        FeatureKind::Rgb => return Ok((3, 1)),
        FeatureKind::Dsift => return Ok((crate::dsift::CHANNELS, 1)),
        FeatureKind::Patch7 => return Ok((1, 1)),
        FeatureKind::Learned(path) | FeatureKind::B1(path) => load_weights(path.as_deref())?,
    };
    Ok((w.config.channels, w.config.b1_stride))
}

/// Feature channels of a kind and the bytes its extraction holds at its peak for one `height x
/// width` (level-0) frame beside the cost volume (SPEC.md §11.2, §14.3): nothing for RGB, one
/// network forward ([`crate::memory::network_forward_bytes`]) for learned and block-1 features, the
/// dense-SIFT planes and its level-0 descriptors ([`crate::dsift::extraction_bytes`]) for dense SIFT.
///
/// # Errors
/// Weight-file errors naming the file.
pub fn feature_memory(kind: &FeatureKind, height: usize, width: usize) -> Result<(usize, u64)> {
    let (channels, stride) = feature_channels(kind)?;
    let bytes = match kind {
        FeatureKind::Rgb | FeatureKind::Patch7 => 0,
        FeatureKind::Dsift => crate::dsift::extraction_bytes(height, width),
        FeatureKind::Learned(_) | FeatureKind::B1(_) => {
            crate::memory::network_forward_bytes(height, width, channels, stride)
        }
    };
    Ok((channels, bytes))
}

/// Features of one image on the level-`level` grid, `[H_l, W_l, C]`.
#[derive(Clone, Debug)]
pub struct FeatureMap {
    /// The features, channels-last.
    pub data: Array3<f32>,
    /// Pyramid level of the grid they live on.
    pub level: u32,
}

/// Turns images into feature maps of one [`FeatureKind`] on the level-`level` grid.
#[derive(Debug)]
pub struct FeatureExtractor {
    kind: FeatureKind,
    backend: Arc<dyn Backend>,
    net: Option<FeatureNet>,
    level: u32,
    net_level: Option<u32>,
}

impl FeatureExtractor {
    /// Load the network if needed. Features are produced on the level-`level` grid (RGB and dense
    /// SIFT tent-downsampled from level 0; network features resampled from the network's own level,
    /// see the module documentation).
    ///
    /// # Errors
    /// Weight-file errors naming the file.
    pub fn new(kind: FeatureKind, level: u32, backend: Arc<dyn Backend>) -> Result<Self> {
        let net = match &kind {
            FeatureKind::Learned(path) | FeatureKind::B1(path) => {
                Some(FeatureNet::new(load_weights(path.as_deref())?)?)
            }
            FeatureKind::Rgb | FeatureKind::Dsift | FeatureKind::Patch7 => None,
        };
        let net_level = net.as_ref().map(Self::output_level);
        Ok(Self { kind, backend, net, level, net_level })
    }

    /// The level the network computes its features at (`None` for RGB and dense SIFT).
    pub fn network_output_level(&self) -> Option<u32> {
        self.net_level
    }

    fn output_level(net: &FeatureNet) -> u32 {
        net.config().block_level(0) as u32
    }

    /// The level at which the shipped network outputs features (its block-1 grid).
    ///
    /// # Errors
    /// If the shipped weights fail to load (a build error, tested).
    pub fn network_level() -> Result<u32> {
        Ok(load_weights(None)?.config.block_level(0) as u32)
    }

    /// What it extracts.
    pub fn kind(&self) -> &FeatureKind {
        &self.kind
    }

    /// A short name for tables: `rgb`, `learned`, `b1`, `dsift` or `patch7`.
    pub fn name(&self) -> &'static str {
        self.kind.name()
    }

    /// Channels of the feature maps it produces.
    pub fn channels(&self) -> usize {
        match (&self.kind, &self.net) {
            (FeatureKind::Dsift, _) => crate::dsift::CHANNELS,
            (FeatureKind::Patch7, _) => 1,
            (_, Some(net)) => net.config().channels,
            _ => crate::ops::config::IMAGE_CHANNELS,
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

    /// Features of an RGB image (`[H, W, 3]`, 0-255); the network runs on the extractor's backend.
    ///
    /// # Errors
    /// Shape errors from the kernels (not `[H, W, 3]`).
    pub fn extract(&self, rgb: &RgbImage) -> Result<FeatureMap> {
        let (h0, w0, _) = rgb.dim();
        let cpu = self.backend.cpu_level();
        let data = match (&self.net, self.net_level) {
            (Some(net), Some(nl)) => {
                let f = match self.kind {
                    FeatureKind::B1(_) => net.block1(rgb.view(), self.backend.as_ref())?,
                    _ => net.features(rgb.view(), self.backend.as_ref())?,
                };
                match self.level.cmp(&nl) {
                    std::cmp::Ordering::Equal => f,
                    std::cmp::Ordering::Greater => downsample_to_at(f.view(), self.level - nl, cpu)?,
                    std::cmp::Ordering::Less => {
                        let s = 1usize << self.level;
                        upsample_to_at(f.view(), nl - self.level, h0.div_ceil(s), w0.div_ceil(s), cpu)
                    }
                }
            }
            _ if self.kind == FeatureKind::Dsift => {
                let d = dense_sift(rgb.view(), &DsiftParams::DEFAULT, DsiftImpl::Fast)?;
                if self.level == 0 {
                    d
                } else {
                    downsample_to_at(d.view(), self.level, cpu)?
                }
            }
            _ if self.kind == FeatureKind::Patch7 => {
                let grey = to_gray(&downsample_to_at(rgb.view(), self.level, cpu)?);
                grey.insert_axis(ndarray::Axis(2))
            }
            _ => downsample_to_at(rgb.view(), self.level, cpu)?,
        };
        Ok(FeatureMap { data, level: self.level })
    }

    /// A volume for a keyframe's features from [`FeatureExtractor::extract`]: the backend's cost
    /// volume (SPEC.md §9), or for [`FeatureKind::Patch7`] the patch volume (SPEC.md §9a.5, CPU).
    ///
    /// # Errors
    /// As the backend's `cost_volume` or [`PatchVolume::new`]; [`Error::Unsupported`] for
    /// [`FeatureKind::Patch7`] on a backend other than the CPU.
    pub fn volume(
        &self,
        reference: Array3<f32>,
        camera: PinholeCamera,
        bins: InverseDepthBins,
        truncation: f32,
    ) -> Result<Box<dyn VolumeBuilder>> {
        if self.kind == FeatureKind::Patch7 {
            // No silent fallback (STYLE §7): the patch kernel exists on the CPU only.
            if self.backend.name() != "cpu" {
                return Err(Error::Unsupported {
                    backend: self.backend.name().into(),
                    what: "the patch7 cost volume (SPEC.md §9a.5) runs on the CPU only: use --backend cpu"
                        .into(),
                });
            }
            return Ok(Box::new(PatchVolume::new(reference, camera, bins, truncation, PatchImpl::Fast)?));
        }
        self.backend.cost_volume(&self.backend.upload_owned(reference)?, camera, bins, truncation)
    }

    /// Features from [`FeatureExtractor::extract`] where [`FeatureExtractor::volume`]'s builder reads
    /// them: uploaded to the backend, or on the host for [`FeatureKind::Patch7`].
    ///
    /// # Errors
    /// The backend's upload errors.
    pub fn upload(&self, features: Array3<f32>) -> Result<Tensor> {
        if self.kind == FeatureKind::Patch7 {
            return Ok(Tensor::host(features));
        }
        self.backend.upload_owned(features)
    }
}
