//! The feature network's parameters: their PyTorch names and layouts, Xavier initialisation, and
//! the safetensors file format (SPEC.md §8.3-8.5).
//!
//! Tensor names are exactly `FeatureNet().state_dict()`'s: `blocks.{k}.conv{1,2,3}.{weight,bias}`
//! for `k = 0 .. blocks-1`, then `deconvs.{i}.{weight,bias}` for `i = 0 .. blocks-2`. Convolution
//! weights are `[c_out, c_in, 3, 3]`, transposed-convolution weights `[c_in, c_out, 5, 5]`, biases
//! `[c_out]`, all f32 little-endian.

use std::collections::{BTreeMap, BTreeSet, HashMap};
use std::path::Path;

use ndarray::{Array1, Array4};
use safetensors::{Dtype, SafeTensorError, SafeTensors};

use crate::error::{Error, Result};
use crate::io::write_atomic;
use crate::ops::config::NetworkConfig;
use crate::ops::geometry::{CONV_KERNEL, DECONV_KERNEL};
use crate::ops::LayerParams;
use crate::util::rng::SplitMix64;

/// Value of the `format` metadata key.
pub const FORMAT: &str = "densefeat-featurenet-v1";
/// Largest safetensors header we read (JSON bytes). Ours is about 3 KiB.
pub const MAX_HEADER_BYTES: usize = 1 << 20;
/// Metadata keys every file must carry.
pub const METADATA_KEYS: [&str; 6] =
    ["format", "blocks", "channels", "b1_stride", "input_mean", "provenance"];

/// The three convolutions of one encoder block.
#[derive(Clone, Debug, PartialEq)]
pub struct BlockParams {
    /// 3x3, stride 1 or 2, followed by ReLU.
    pub conv1: LayerParams,
    /// 3x3, stride 1, followed by ReLU.
    pub conv2: LayerParams,
    /// 3x3, stride 1, linear.
    pub conv3: LayerParams,
}

/// All parameters of the feature network, with the configuration they were made for.
#[derive(Clone, Debug, PartialEq)]
pub struct NetworkWeights {
    /// Hyper-parameters (stored in the file's metadata).
    pub config: NetworkConfig,
    /// `blocks[k]` is PyTorch's `blocks.k`.
    pub blocks: Vec<BlockParams>,
    /// `deconvs[i]` (PyTorch `deconvs.i`) upsamples block `i + 1`'s aggregate onto block `i`'s grid.
    pub deconvs: Vec<LayerParams>,
    /// Free text: how the weights were made ("xavier-uniform seed=0", a training run, ...).
    pub provenance: String,
}

/// Which kind of layer a tensor belongs to.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LayerKind {
    /// `nn.Conv2d`, weight `[c_out, c_in, 3, 3]`.
    Conv,
    /// `nn.ConvTranspose2d`, weight `[c_in, c_out, 5, 5]`.
    Deconv,
}

/// One entry of the state dict: name, shape and layer kind.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct TensorSpec {
    /// PyTorch `state_dict` key.
    pub name: String,
    /// Shape.
    pub shape: Vec<usize>,
    /// Layer the tensor belongs to.
    pub kind: LayerKind,
    /// `true` for a bias.
    pub is_bias: bool,
}

/// `(name prefix, weight shape, kind)` of every layer, in `state_dict` order.
fn layer_specs(config: &NetworkConfig) -> Vec<(String, [usize; 4], LayerKind)> {
    let c = config.channels;
    let mut layers = Vec::new();
    for k in 0..config.blocks {
        let c_in = config.block_in_channels(k);
        for (j, cin) in [(1, c_in), (2, c), (3, c)] {
            layers.push((format!("blocks.{k}.conv{j}"), [c, cin, CONV_KERNEL, CONV_KERNEL], LayerKind::Conv));
        }
    }
    for i in 0..config.blocks - 1 {
        layers.push((format!("deconvs.{i}"), [c, c, DECONV_KERNEL, DECONV_KERNEL], LayerKind::Deconv));
    }
    layers
}

/// Every tensor of `FeatureNet(config).state_dict()`, in its order.
pub fn tensor_specs(config: &NetworkConfig) -> Vec<TensorSpec> {
    let mut specs = Vec::new();
    for (prefix, shape, kind) in layer_specs(config) {
        let c_out = if kind == LayerKind::Conv { shape[0] } else { shape[1] };
        specs.push(TensorSpec {
            name: format!("{prefix}.weight"),
            shape: shape.to_vec(),
            kind,
            is_bias: false,
        });
        specs.push(TensorSpec { name: format!("{prefix}.bias"), shape: vec![c_out], kind, is_bias: true });
    }
    specs
}

/// PyTorch's `_calculate_fan_in_and_fan_out` for a 4-D weight: `fan_in = size(1)·k·k`,
/// `fan_out = size(0)·k·k`. (For a transposed convolution, `size(1)` is its `c_out`.)
pub fn fans(weight_shape: &[usize; 4]) -> (usize, usize) {
    let receptive = weight_shape[2] * weight_shape[3];
    (weight_shape[1] * receptive, weight_shape[0] * receptive)
}

impl NetworkWeights {
    /// Xavier (Glorot) uniform initialisation, PyTorch's `xavier_uniform_(w, gain=1)`: each weight
    /// is `U(-a, a)`, `a = sqrt(6 / (fan_in + fan_out))` ([`fans`]), biases are zero. Values are
    /// drawn from [`SplitMix64`] seeded with `seed`, layer by layer in `state_dict` order, each
    /// weight tensor in row-major order, as `a (2 u - 1)` with `u ∈ [0, 1)` (53 bits), computed in
    /// f64 and rounded to f32.
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] if `config` is invalid.
    pub fn xavier_uniform(config: &NetworkConfig, seed: u64) -> Result<Self> {
        config.validate()?;
        let mut rng = SplitMix64::new(seed);
        let mut layers = layer_specs(config).into_iter().map(|(_, shape, kind)| {
            let (fan_in, fan_out) = fans(&shape);
            let a = (6.0 / (fan_in + fan_out) as f64).sqrt();
            let weight = Array4::from_shape_simple_fn(shape, || (a * (2.0 * rng.unit() - 1.0)) as f32);
            let c_out = if kind == LayerKind::Conv { shape[0] } else { shape[1] };
            LayerParams { weight, bias: Array1::zeros(c_out) }
        });
        let mut next = || layers.next().ok_or_else(|| Error::invalid_argument("config", "layer count"));
        let mut blocks = Vec::with_capacity(config.blocks);
        for _ in 0..config.blocks {
            blocks.push(BlockParams { conv1: next()?, conv2: next()?, conv3: next()? });
        }
        let deconvs = (1..config.blocks).map(|_| next()).collect::<Result<Vec<_>>>()?;
        Ok(NetworkWeights {
            config: *config,
            blocks,
            deconvs,
            provenance: format!("xavier-uniform seed={seed}"),
        })
    }

    /// Every layer in `state_dict` order (block convs, then deconvs).
    pub fn layers(&self) -> Vec<&LayerParams> {
        let convs = self.blocks.iter().flat_map(|b| [&b.conv1, &b.conv2, &b.conv3]);
        convs.chain(self.deconvs.iter()).collect()
    }

    /// Every layer, mutably, in the order of [`NetworkWeights::layers`].
    pub fn layers_mut(&mut self) -> Vec<&mut LayerParams> {
        let convs = self.blocks.iter_mut().flat_map(|b| [&mut b.conv1, &mut b.conv2, &mut b.conv3]);
        convs.chain(self.deconvs.iter_mut()).collect()
    }

    /// `self += other`, layer by layer (weights, then biases), elementwise. Shapes must match
    /// (gradients of the same network).
    ///
    /// # Panics
    /// If the two hold different layers.
    pub fn add_assign(&mut self, other: &NetworkWeights) {
        let theirs = other.layers();
        let ours = self.layers_mut();
        assert_eq!(ours.len(), theirs.len(), "add_assign of different networks");
        for (a, b) in ours.into_iter().zip(theirs) {
            a.weight += &b.weight;
            a.bias += &b.bias;
        }
    }

    /// The same configuration and shapes with every value 0 (a gradient accumulator).
    pub fn zeros_like(&self) -> Self {
        let mut z = self.clone();
        for l in z.layers_mut() {
            l.weight.fill(0.0);
            l.bias.fill(0.0);
        }
        z.provenance = "zeros".to_string();
        z
    }

    /// Checks that the layer count and every shape match [`tensor_specs`] for `self.config`.
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] naming the first tensor that disagrees.
    pub fn validate(&self) -> Result<()> {
        self.config.validate()?;
        let specs = tensor_specs(&self.config);
        let layers = self.layers();
        if layers.len() * 2 != specs.len() {
            return Err(Error::invalid_argument(
                "weights",
                format!("{} layers, the configuration needs {}", layers.len(), specs.len() / 2),
            ));
        }
        for (layer, pair) in layers.iter().zip(specs.chunks_exact(2)) {
            for (shape, spec) in [(layer.weight.shape(), &pair[0]), (layer.bias.shape(), &pair[1])] {
                if shape != spec.shape.as_slice() {
                    return Err(Error::invalid_argument(
                        spec.name.clone(),
                        format!("shape {shape:?}, expected {:?}", spec.shape),
                    ));
                }
            }
        }
        Ok(())
    }

    /// The header's `__metadata__` (SPEC.md §8.4).
    pub fn metadata(&self) -> HashMap<String, String> {
        let c = &self.config;
        let [r, g, b] = c.input_mean;
        HashMap::from([
            ("format".to_string(), FORMAT.to_string()),
            ("blocks".to_string(), c.blocks.to_string()),
            ("channels".to_string(), c.channels.to_string()),
            ("b1_stride".to_string(), c.b1_stride.to_string()),
            ("input_mean".to_string(), format!("{r},{g},{b}")),
            ("provenance".to_string(), self.provenance.clone()),
        ])
    }

    /// The safetensors file's bytes, reproducible byte for byte: the header is JSON with keys in
    /// sorted order (`__metadata__` first), padded with spaces to a multiple of 8 bytes; tensor
    /// data follow in `state_dict` order, f32 little-endian.
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] if the weights do not match their configuration.
    pub fn to_safetensors_bytes(&self) -> Result<Vec<u8>> {
        self.validate()?;
        let specs = tensor_specs(&self.config);
        let tensors: Vec<&[f32]> = self
            .layers()
            .into_iter()
            .flat_map(|l| [l.weight.as_slice(), l.bias.as_slice()])
            .map(|s| s.ok_or_else(|| Error::invalid_argument("weights", "tensor is not contiguous")))
            .collect::<Result<_>>()?;
        let named: Vec<TensorOut<'_>> = specs
            .iter()
            .zip(&tensors)
            .map(|(spec, data)| TensorOut { name: spec.name.clone(), shape: spec.shape.clone(), data })
            .collect();
        f32_safetensors_bytes(&self.metadata().into_iter().collect(), &named)
    }

    /// Saves the weights as safetensors (SPEC.md §8.4), atomically.
    ///
    /// # Errors
    /// [`Error::Io`] on a write failure, [`Error::InvalidArgument`] for inconsistent weights.
    pub fn save(&self, path: &Path) -> Result<()> {
        write_atomic(path, &self.to_safetensors_bytes()?)
    }

    /// Loads and fully validates a weights file (SPEC.md §8.5).
    ///
    /// # Errors
    /// [`Error::Io`] if unreadable; [`Error::BadFile`] naming the file for every rule of §8.5.
    pub fn load(path: &Path) -> Result<Self> {
        let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
        Self::from_safetensors_bytes(&bytes, path)
    }

    /// Parses a weights file's bytes; `path` only names the file in errors.
    ///
    /// # Errors
    /// [`Error::BadFile`] for every rule of SPEC.md §8.5.
    pub fn from_safetensors_bytes(bytes: &[u8], path: &Path) -> Result<Self> {
        let bad = |what: String| Error::bad_file(path, what);
        let Some((len_bytes, rest)) = bytes.split_first_chunk::<8>() else {
            return Err(bad(format!("truncated: {} bytes, a safetensors file starts with 8", bytes.len())));
        };
        let header_len = u64::from_le_bytes(*len_bytes);
        if header_len > MAX_HEADER_BYTES as u64 {
            return Err(bad(format!(
                "header of {header_len} bytes is larger than the {MAX_HEADER_BYTES}-byte cap"
            )));
        }
        let header_len = header_len as usize;
        let Some(header) = rest.get(..header_len) else {
            return Err(bad(format!(
                "truncated: header of {header_len} bytes but only {} bytes follow the length",
                rest.len()
            )));
        };
        let json: serde_json::Value = std::str::from_utf8(header)
            .map_err(|e| e.to_string())
            .and_then(|s| serde_json::from_str(s).map_err(|e| e.to_string()))
            .map_err(|e| bad(format!("header is not JSON: {e}")))?;
        let config = parse_metadata(&json).map_err(|what| bad(format!("metadata: {what}")))?;
        check_entries(&json, &config).map_err(bad)?;
        let st = SafeTensors::deserialize(bytes).map_err(|e| bad(describe_safetensors_error(&e)))?;
        read_tensors(&st, &config, &json, path)
    }
}

/// A message for the safetensors crate's structural errors (offsets, sizes).
fn describe_safetensors_error(e: &SafeTensorError) -> String {
    match e {
        SafeTensorError::MetadataIncompleteBuffer => {
            "data size mismatch: the tensors' data_offsets do not end at the end of the file".to_string()
        }
        SafeTensorError::TensorInvalidInfo => {
            "data size mismatch: a tensor's data_offsets span disagrees with its dtype and shape".to_string()
        }
        SafeTensorError::InvalidOffset(name) => {
            format!("data size mismatch: tensor {name:?} has bad data_offsets")
        }
        other => format!("invalid safetensors header: {other}"),
    }
}

/// Reads the configuration from `__metadata__` (SPEC.md §8.4).
fn parse_metadata(json: &serde_json::Value) -> std::result::Result<NetworkConfig, String> {
    let meta = json.get("__metadata__").ok_or("no __metadata__ entry")?;
    let meta = meta.as_object().ok_or("__metadata__ is not an object")?;
    let get = |key: &str| -> std::result::Result<&str, String> {
        let v = meta.get(key).ok_or(format!("missing key {key:?}"))?;
        v.as_str().ok_or(format!("{key:?} is not a string"))
    };
    for key in METADATA_KEYS {
        get(key)?;
    }
    let format = get("format")?;
    if format != FORMAT {
        return Err(format!("format {format:?}, expected {FORMAT:?}"));
    }
    config_from_fields(get)
}

/// The network configuration from its metadata fields `blocks`, `channels`, `b1_stride` and
/// `input_mean` (SPEC.md §8.4), validated; `get` looks a field up. Shared by weights files and
/// training checkpoints.
pub(crate) fn config_from_fields<'a>(
    get: impl Fn(&str) -> std::result::Result<&'a str, String>,
) -> std::result::Result<NetworkConfig, String> {
    let int = |key: &str| -> std::result::Result<usize, String> {
        let text = get(key)?;
        text.parse().map_err(|_| format!("{key} {text:?} is not a non-negative integer"))
    };
    let text = get("input_mean")?;
    let mean: Vec<f32> = text
        .split(',')
        .map(|p| p.trim().parse::<f32>())
        .collect::<std::result::Result<_, _>>()
        .map_err(|_| format!("input_mean {text:?} is not three comma-separated numbers"))?;
    let input_mean: [f32; 3] =
        mean.try_into().map_err(|_| format!("input_mean {text:?} is not three comma-separated numbers"))?;
    let config = NetworkConfig {
        blocks: int("blocks")?,
        channels: int("channels")?,
        b1_stride: int("b1_stride")?,
        input_mean,
    };
    config.validate().map_err(|e| e.to_string())?;
    Ok(config)
}

/// Checks the header's tensor names, dtypes and shapes against the configuration, before the
/// data offsets are looked at (so a wrong dtype is reported as such, not as a size mismatch).
fn check_entries(json: &serde_json::Value, config: &NetworkConfig) -> std::result::Result<(), String> {
    let header = json.as_object().ok_or("header is not a JSON object")?;
    let specs = tensor_specs(config);
    let expected: BTreeSet<&str> = specs.iter().map(|s| s.name.as_str()).collect();
    let present: BTreeSet<&str> =
        header.keys().map(String::as_str).filter(|k| *k != "__metadata__").collect();
    let missing: Vec<_> = expected.difference(&present).collect();
    let extra: Vec<_> = present.difference(&expected).collect();
    if !missing.is_empty() || !extra.is_empty() {
        return Err(format!(
            "tensor names do not match a {}-block network: missing {missing:?}, unexpected {extra:?}",
            config.blocks
        ));
    }
    for spec in &specs {
        let entry = &header[&spec.name];
        let dtype = entry.get("dtype").and_then(|d| d.as_str()).unwrap_or("(none)");
        if dtype != "F32" {
            return Err(format!("{}: dtype {dtype}, expected F32", spec.name));
        }
        let shape: Option<Vec<usize>> = entry
            .get("shape")
            .and_then(|s| s.as_array())
            .and_then(|a| a.iter().map(|d| d.as_u64().and_then(|d| usize::try_from(d).ok())).collect());
        match shape {
            Some(shape) if shape == spec.shape => {}
            Some(shape) => return Err(format!("{}: shape {shape:?}, expected {:?}", spec.name, spec.shape)),
            None => return Err(format!("{}: no valid shape", spec.name)),
        }
    }
    Ok(())
}

/// Checks names, dtypes, shapes and values against the configuration and builds the weights.
fn read_tensors(
    st: &SafeTensors,
    config: &NetworkConfig,
    json: &serde_json::Value,
    path: &Path,
) -> Result<NetworkWeights> {
    let bad = |what: String| Error::bad_file(path, what);
    let specs = tensor_specs(config);
    let expected: BTreeSet<&str> = specs.iter().map(|s| s.name.as_str()).collect();
    let present: BTreeSet<&str> = st.names().into_iter().collect();
    let missing: Vec<_> = expected.difference(&present).collect();
    let extra: Vec<_> = present.difference(&expected).collect();
    if !missing.is_empty() || !extra.is_empty() {
        return Err(bad(format!(
            "tensor names do not match a {}-block network: missing {missing:?}, unexpected {extra:?}",
            config.blocks
        )));
    }
    let mut tensors = Vec::with_capacity(specs.len());
    for spec in &specs {
        let view = st.tensor(&spec.name).map_err(|e| bad(format!("{}: {e}", spec.name)))?;
        if view.dtype() != Dtype::F32 {
            return Err(bad(format!("{}: dtype {:?}, expected F32", spec.name, view.dtype())));
        }
        if view.shape() != spec.shape.as_slice() {
            return Err(bad(format!("{}: shape {:?}, expected {:?}", spec.name, view.shape(), spec.shape)));
        }
        let values: Vec<f32> =
            view.data().chunks_exact(4).map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]])).collect();
        if let Some(i) = values.iter().position(|v| !v.is_finite()) {
            return Err(bad(format!("{}: non-finite value {} at flat index {i}", spec.name, values[i])));
        }
        tensors.push(values);
    }
    let mut tensors = tensors.into_iter();
    let mut layers = layer_specs(config).into_iter().map(|(name, shape, _)| {
        let (Some(w), Some(b)) = (tensors.next(), tensors.next()) else {
            return Err(bad(format!("{name}: missing tensors")));
        };
        let weight = Array4::from_shape_vec(shape, w).map_err(|e| bad(format!("{name}.weight: {e}")))?;
        Ok(LayerParams { weight, bias: Array1::from(b) })
    });
    let mut next = || layers.next().unwrap_or_else(|| Err(bad("layer count".to_string())));
    let mut blocks = Vec::with_capacity(config.blocks);
    for _ in 0..config.blocks {
        blocks.push(BlockParams { conv1: next()?, conv2: next()?, conv3: next()? });
    }
    let deconvs = (1..config.blocks).map(|_| next()).collect::<Result<Vec<_>>>()?;
    let provenance = json["__metadata__"]["provenance"].as_str().unwrap_or_default().to_string();
    Ok(NetworkWeights { config: *config, blocks, deconvs, provenance })
}

/// One tensor to write: name, shape, values (row-major).
pub struct TensorOut<'a> {
    /// Name in the file.
    pub name: String,
    /// Shape.
    pub shape: Vec<usize>,
    /// Values, `shape.iter().product()` of them.
    pub data: &'a [f32],
}

/// The bytes of an f32 safetensors file (SPEC.md §8.4's byte-reproducible layout: JSON header with
/// keys sorted, `__metadata__` first, padded with spaces to a multiple of 8 bytes) holding `tensors` (in this order) and `metadata`.
///
/// # Errors
/// [`Error::InvalidArgument`] if a tensor's length disagrees with its shape.
pub fn f32_safetensors_bytes(
    metadata: &BTreeMap<String, String>,
    tensors: &[TensorOut<'_>],
) -> Result<Vec<u8>> {
    let mut header = serde_json::Map::new();
    let meta: serde_json::Map<String, serde_json::Value> =
        metadata.iter().map(|(k, v)| (k.clone(), serde_json::Value::String(v.clone()))).collect();
    header.insert("__metadata__".to_string(), serde_json::Value::Object(meta));
    let mut offset = 0usize;
    for t in tensors {
        if t.shape.iter().product::<usize>() != t.data.len() {
            return Err(Error::invalid_argument(
                t.name.clone(),
                format!("{} values for shape {:?}", t.data.len(), t.shape),
            ));
        }
        let end = offset + 4 * t.data.len();
        header.insert(
            t.name.clone(),
            serde_json::json!({ "dtype": "F32", "shape": t.shape, "data_offsets": [offset, end] }),
        );
        offset = end;
    }
    let mut json = serde_json::Value::Object(header).to_string().into_bytes();
    json.resize(json.len().next_multiple_of(8), b' ');
    let mut bytes = Vec::with_capacity(8 + json.len() + offset);
    bytes.extend_from_slice(&(json.len() as u64).to_le_bytes());
    bytes.extend_from_slice(&json);
    for t in tensors {
        bytes.extend(t.data.iter().flat_map(|v| v.to_le_bytes()));
    }
    Ok(bytes)
}
