//! Training checkpoints (SPEC.md §13.6): one safetensors file with the weights under their
//! PyTorch names, Adam's moments as `adam.m.NAME` / `adam.v.NAME`, and in the metadata the network
//! configuration, the step, Adam's step count and the training configuration it was made with.
//! Written atomically; loading checks every tensor's presence, dtype and shape.

use std::collections::BTreeMap;
use std::path::Path;

use ndarray::{Array1, Array4};
use safetensors::{Dtype, SafeTensors};

use crate::error::{Error, Result};
use crate::io::write_atomic;
use crate::nn::weights::{config_from_fields, f32_safetensors_bytes, tensor_specs, TensorOut};
use crate::nn::NetworkWeights;
use crate::train::optim::AdamState;

/// Format tag of a checkpoint.
pub const CHECKPOINT_FORMAT: &str = "densefeat-checkpoint-v1";

/// A checkpoint's content.
#[derive(Clone, Debug, PartialEq)]
pub struct Checkpoint {
    /// Steps completed.
    pub step: usize,
    /// Network weights.
    pub weights: NetworkWeights,
    /// Optimiser state.
    pub adam: AdamState,
    /// The training configuration as text (checked on resume).
    pub train_config: String,
}

fn flat(w: &NetworkWeights) -> Vec<&[f32]> {
    w.layers()
        .into_iter()
        .flat_map(|l| [l.weight.as_slice().unwrap_or(&[]), l.bias.as_slice().unwrap_or(&[])])
        .collect()
}

impl Checkpoint {
    /// Serialises and writes atomically.
    ///
    /// # Errors
    /// [`Error::Io`] on a write failure.
    pub fn save(&self, path: &Path) -> Result<()> {
        let specs = tensor_specs(&self.weights.config);
        // Sorted metadata and a fixed tensor order (SPEC.md §8.4's layout): the same run writes
        // the same bytes (a HashMap's order differs from process to process).
        let mut meta: BTreeMap<String, String> = self.weights.metadata().into_iter().collect();
        meta.insert("format".into(), CHECKPOINT_FORMAT.into());
        meta.insert("step".into(), self.step.to_string());
        meta.insert("adam_step".into(), self.adam.step.to_string());
        meta.insert("train_config".into(), self.train_config.clone());
        let groups =
            [("", flat(&self.weights)), ("adam.m.", flat(&self.adam.m)), ("adam.v.", flat(&self.adam.v))];
        let mut tensors = Vec::new();
        for (prefix, data) in &groups {
            for (spec, data) in specs.iter().zip(data) {
                tensors.push(TensorOut {
                    name: format!("{prefix}{}", spec.name),
                    shape: spec.shape.clone(),
                    data,
                });
            }
        }
        let bytes = f32_safetensors_bytes(&meta, &tensors)?;
        write_atomic(path, &bytes)
    }

    /// Reads and checks a checkpoint.
    ///
    /// # Errors
    /// [`Error::Io`] if unreadable, [`Error::BadFile`] naming the file for a wrong format, a
    /// missing or misshapen tensor, or bad metadata.
    pub fn load(path: &Path) -> Result<Self> {
        let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
        let bad = |what: String| Error::bad_file(path, what);
        let (_, header) =
            SafeTensors::read_metadata(&bytes).map_err(|e| bad(format!("not a safetensors file: {e}")))?;
        let meta = header.metadata().clone().unwrap_or_default();
        let get = |k: &str| meta.get(k).cloned().ok_or_else(|| bad(format!("metadata has no {k:?}")));
        if get("format")? != CHECKPOINT_FORMAT {
            return Err(bad(format!("format is not {CHECKPOINT_FORMAT:?} (is it a weights file?)")));
        }
        let num = |k: &str| -> Result<usize> {
            get(k)?.parse().map_err(|_| bad(format!("metadata {k:?} is not a number")))
        };
        let config =
            config_from_fields(|k| meta.get(k).map(String::as_str).ok_or(format!("metadata has no {k:?}")))
                .map_err(bad)?;
        let st = SafeTensors::deserialize(&bytes).map_err(|e| bad(e.to_string()))?;
        let template = NetworkWeights::xavier_uniform(&config, 0)?.zeros_like();
        let specs = tensor_specs(&config);
        let fill = |prefix: &str| -> Result<NetworkWeights> {
            let mut w = template.clone();
            for (layer, pair) in w.layers_mut().into_iter().zip(specs.chunks_exact(2)) {
                for (spec, is_bias) in [(&pair[0], false), (&pair[1], true)] {
                    let name = format!("{prefix}{}", spec.name);
                    let t = st.tensor(&name).map_err(|_| bad(format!("tensor {name:?} is missing")))?;
                    if t.dtype() != Dtype::F32 || t.shape() != spec.shape.as_slice() {
                        return Err(bad(format!(
                            "tensor {name:?} is {:?} {:?}, expected F32 {:?}",
                            t.dtype(),
                            t.shape(),
                            spec.shape
                        )));
                    }
                    let vals: Vec<f32> = t
                        .data()
                        .chunks_exact(4)
                        .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
                        .collect();
                    if is_bias {
                        layer.bias = Array1::from(vals);
                    } else {
                        let s = &spec.shape;
                        layer.weight = Array4::from_shape_vec((s[0], s[1], s[2], s[3]), vals)
                            .map_err(|e| bad(e.to_string()))?;
                    }
                }
            }
            Ok(w)
        };
        let mut weights = fill("")?;
        weights.provenance = get("provenance")?;
        let adam = AdamState { step: num("adam_step")?, m: fill("adam.m.")?, v: fill("adam.v.")? };
        Ok(Checkpoint { step: num("step")?, weights, adam, train_config: get("train_config")? })
    }
}
