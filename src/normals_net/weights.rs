//! The normal predictor's parameters (SPEC.md §13.11): a feature-network trunk of its own (§8.3
//! names) and the head `head.{weight,bias}` (`[3, C, 3, 3]`, `[3]`), and their file
//! `normalnet.safetensors` (format `densefeat-normalnet-v1`).

use std::collections::BTreeMap;
use std::path::Path;

use ndarray::{Array1, Array4};

use crate::error::{Error, Result};
use crate::io::write_atomic;
use crate::nn::weights::{config_from_fields, fans, tensor_specs};
use crate::nn::NetworkWeights;
use crate::normals_net::file::{to_bytes, TensorFile, TensorOut};
use crate::ops::LayerParams;
use crate::util::rng::SplitMix64;

/// Value of the `format` metadata key of a normal-predictor weights file.
pub const NORMALNET_FORMAT: &str = "densefeat-normalnet-v1";
/// Output channels of the head: a normal's three camera-frame components.
pub const HEAD_CHANNELS: usize = 3;
/// Seed of the head's Xavier initialisation (SPEC.md §13.11).
pub const HEAD_SEED: u64 = 0x6e6f_726d_616c;
/// Name prefix of the head's tensors.
pub const HEAD_NAME: &str = "head";

/// Trunk and head of the normal predictor.
#[derive(Clone, Debug, PartialEq)]
pub struct NormalNetWeights {
    /// A feature network of its own (the features' architecture, SPEC.md §8.1).
    pub trunk: NetworkWeights,
    /// 3x3 convolution `C -> 3` on the trunk's aggregated features, weight `[3, C, 3, 3]`.
    pub head: LayerParams,
}

/// Name and shape of every tensor of a normal predictor with trunk `config`, in file order
/// (trunk in `state_dict` order, then `head.weight`, `head.bias`).
pub fn normalnet_tensor_specs(config: &crate::nn::NetworkConfig) -> Vec<(String, Vec<usize>)> {
    let mut v: Vec<(String, Vec<usize>)> =
        tensor_specs(config).into_iter().map(|s| (s.name, s.shape)).collect();
    v.push((format!("{HEAD_NAME}.weight"), vec![HEAD_CHANNELS, config.channels, 3, 3]));
    v.push((format!("{HEAD_NAME}.bias"), vec![HEAD_CHANNELS]));
    v
}

impl NormalNetWeights {
    /// A predictor on `trunk` (copied: the predictor is its own instance) with the head drawn by
    /// PyTorch's `xavier_uniform_` (§8.6's rule: `a = sqrt(6 / (9 C + 27))`, values `a (2u - 1)`
    /// from [`SplitMix64`]`::new(seed)` in row-major order, f64 rounded to f32), bias 0.
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] if the trunk is inconsistent.
    pub fn from_trunk(trunk: NetworkWeights, seed: u64) -> Result<Self> {
        trunk.validate()?;
        let shape = [HEAD_CHANNELS, trunk.config.channels, 3, 3];
        let (fan_in, fan_out) = fans(&shape);
        let a = (6.0 / (fan_in + fan_out) as f64).sqrt();
        let mut rng = SplitMix64::new(seed);
        let weight = Array4::from_shape_simple_fn(shape, || (a * (2.0 * rng.unit() - 1.0)) as f32);
        Ok(NormalNetWeights { trunk, head: LayerParams { weight, bias: Array1::zeros(HEAD_CHANNELS) } })
    }

    /// Every layer: the trunk's in `state_dict` order, then the head.
    pub fn layers(&self) -> Vec<&LayerParams> {
        let mut v = self.trunk.layers();
        v.push(&self.head);
        v
    }

    /// Every layer, mutably, in the order of [`NormalNetWeights::layers`].
    pub fn layers_mut(&mut self) -> Vec<&mut LayerParams> {
        let mut v = self.trunk.layers_mut();
        v.push(&mut self.head);
        v
    }

    /// The same shapes with every value 0 (a gradient accumulator).
    pub fn zeros_like(&self) -> Self {
        let mut z = self.clone();
        for l in z.layers_mut() {
            l.weight.fill(0.0);
            l.bias.fill(0.0);
        }
        z.trunk.provenance = "zeros".into();
        z
    }

    /// `self += other`, layer by layer, elementwise.
    ///
    /// # Panics
    /// If the two hold different layers.
    pub fn add_assign(&mut self, other: &NormalNetWeights) {
        self.trunk.add_assign(&other.trunk);
        self.head.weight += &other.head.weight;
        self.head.bias += &other.head.bias;
    }

    /// The tensors in file order, their names prefixed with `prefix`.
    ///
    /// # Panics
    /// If a tensor is not contiguous (every constructor makes them so).
    pub fn tensors(&self, prefix: &str) -> Vec<TensorOut<'_>> {
        let specs = normalnet_tensor_specs(&self.trunk.config);
        let data = self.layers().into_iter().flat_map(|l| {
            [l.weight.as_slice().expect("contiguous weight"), l.bias.as_slice().expect("contiguous bias")]
        });
        specs
            .into_iter()
            .zip(data)
            .map(|((n, shape), data)| TensorOut { name: format!("{prefix}{n}"), shape, data })
            .collect()
    }

    /// Reads the tensors named `prefix` + [`normalnet_tensor_specs`] into the shapes of `self`.
    ///
    /// # Errors
    /// As [`TensorFile::tensor`].
    pub fn fill_from(&mut self, file: &TensorFile<'_>, prefix: &str) -> Result<()> {
        let specs = normalnet_tensor_specs(&self.trunk.config);
        for (layer, pair) in self.layers_mut().into_iter().zip(specs.chunks_exact(2)) {
            let w = file.tensor(&format!("{prefix}{}", pair[0].0), &pair[0].1)?;
            let b = file.tensor(&format!("{prefix}{}", pair[1].0), &pair[1].1)?;
            let s = &pair[0].1;
            layer.weight = Array4::from_shape_vec((s[0], s[1], s[2], s[3]), w)
                .map_err(|e| Error::invalid_argument(pair[0].0.clone(), e.to_string()))?;
            layer.bias = Array1::from(b);
        }
        Ok(())
    }

    /// Zeros of the predictor described by a file's metadata (its trunk configuration).
    ///
    /// # Errors
    /// [`Error::BadFile`] for malformed network metadata.
    pub fn template_from(file: &TensorFile<'_>, path: &Path) -> Result<Self> {
        let config = config_from_fields(|k| {
            file.metadata.get(k).map(String::as_str).ok_or(format!("metadata has no {k:?}"))
        })
        .map_err(|e| Error::bad_file(path, e))?;
        let trunk = NetworkWeights::xavier_uniform(&config, 0)?.zeros_like();
        Ok(Self::from_trunk(trunk, 0)?.zeros_like())
    }

    /// The file's metadata: §8.4's network fields, `format` [`NORMALNET_FORMAT`] and the
    /// trunk's `provenance`.
    pub fn metadata(&self) -> BTreeMap<String, String> {
        let mut m: BTreeMap<String, String> = self.trunk.metadata().into_iter().collect();
        m.insert("format".into(), NORMALNET_FORMAT.into());
        m
    }

    /// The bytes of `normalnet.safetensors` (byte-reproducible).
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] for inconsistent weights.
    pub fn to_safetensors_bytes(&self) -> Result<Vec<u8>> {
        self.trunk.validate()?;
        if self.head.weight.shape() != [HEAD_CHANNELS, self.trunk.config.channels, 3, 3]
            || self.head.bias.len() != HEAD_CHANNELS
        {
            return Err(Error::invalid_argument("head", "shape does not match the trunk"));
        }
        to_bytes(&self.metadata(), &self.tensors(""))
    }

    /// Saves atomically.
    ///
    /// # Errors
    /// [`Error::Io`] on a write failure.
    pub fn save(&self, path: &Path) -> Result<()> {
        write_atomic(path, &self.to_safetensors_bytes()?)
    }

    /// Loads and checks a `normalnet.safetensors` file.
    ///
    /// # Errors
    /// [`Error::Io`] if unreadable; [`Error::BadFile`] naming it for a wrong format (e.g. a
    /// feature-network file), bad metadata, or a missing, unexpected, misshapen or non-finite tensor.
    pub fn load(path: &Path) -> Result<Self> {
        let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
        Self::from_safetensors_bytes(&bytes, path)
    }

    /// Parses the bytes of a `normalnet.safetensors` file; `path` names it in errors.
    ///
    /// # Errors
    /// As [`NormalNetWeights::load`].
    pub fn from_safetensors_bytes(bytes: &[u8], path: &Path) -> Result<Self> {
        let file = TensorFile::parse(bytes, path)?;
        let format = file.meta("format")?;
        if format != NORMALNET_FORMAT {
            return Err(Error::bad_file(
                path,
                format!("format {format:?}, expected {NORMALNET_FORMAT:?} (a normal-predictor file from densefeat train-normals)"),
            ));
        }
        let mut w = Self::template_from(&file, path)?;
        let names: Vec<String> = normalnet_tensor_specs(&w.trunk.config).into_iter().map(|s| s.0).collect();
        file.only(&names)?;
        w.fill_from(&file, "")?;
        w.trunk.provenance = file.meta("provenance")?.to_string();
        Ok(w)
    }
}
