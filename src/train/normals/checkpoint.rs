//! The normal predictor's training checkpoint (SPEC.md §13.11): its weights under their file
//! names, AdamW's moments as `adam.m.NAME` / `adam.v.NAME`, and in the metadata the network
//! fields, `step`, `adam_step` and the training fingerprint `train_config`.

use std::path::Path;

use crate::error::{Error, Result};
use crate::io::write_atomic;
use crate::normals_net::file::{to_bytes, TensorFile};
use crate::normals_net::weights::normalnet_tensor_specs;
use crate::normals_net::NormalNetWeights;

/// Format tag of a normal-predictor checkpoint.
pub const NORMAL_CHECKPOINT_FORMAT: &str = "densefeat-normalnet-checkpoint-v1";

/// AdamW's state for the predictor (moments shaped like its weights).
#[derive(Clone, Debug, PartialEq)]
pub struct NormalAdam {
    /// Steps taken.
    pub step: usize,
    /// First moments.
    pub m: NormalNetWeights,
    /// Second moments.
    pub v: NormalNetWeights,
}

impl NormalAdam {
    /// Zero moments for `w`.
    pub fn new(w: &NormalNetWeights) -> Self {
        NormalAdam { step: 0, m: w.zeros_like(), v: w.zeros_like() }
    }
}

/// A checkpoint's content.
#[derive(Clone, Debug, PartialEq)]
pub struct NormalCheckpoint {
    /// Steps completed.
    pub step: usize,
    /// The predictor.
    pub weights: NormalNetWeights,
    /// The optimiser.
    pub adam: NormalAdam,
    /// The training configuration as text (checked on resume).
    pub train_config: String,
}

impl NormalCheckpoint {
    /// Serialises and writes atomically (byte-reproducible).
    ///
    /// # Errors
    /// [`Error::Io`] on a write failure.
    pub fn save(&self, path: &Path) -> Result<()> {
        let mut meta = self.weights.metadata();
        meta.insert("format".into(), NORMAL_CHECKPOINT_FORMAT.into());
        meta.insert("step".into(), self.step.to_string());
        meta.insert("adam_step".into(), self.adam.step.to_string());
        meta.insert("train_config".into(), self.train_config.clone());
        let mut tensors = self.weights.tensors("");
        tensors.extend(self.adam.m.tensors("adam.m."));
        tensors.extend(self.adam.v.tensors("adam.v."));
        write_atomic(path, &to_bytes(&meta, &tensors)?)
    }

    /// Reads and checks a checkpoint.
    ///
    /// # Errors
    /// [`Error::Io`] if unreadable; [`Error::BadFile`] naming the file for another format (a
    /// weights file, a feature-network checkpoint), bad metadata, or a missing or misshapen tensor.
    pub fn load(path: &Path) -> Result<Self> {
        let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
        let file = TensorFile::parse(&bytes, path)?;
        let format = file.meta("format")?;
        if format != NORMAL_CHECKPOINT_FORMAT {
            return Err(Error::bad_file(
                path,
                format!(
                    "format {format:?}, expected {NORMAL_CHECKPOINT_FORMAT:?} (a train-normals checkpoint)"
                ),
            ));
        }
        let num = |k: &str| -> Result<usize> {
            file.meta(k)?
                .parse()
                .map_err(|_| Error::bad_file(path, format!("metadata {k:?} is not a number")))
        };
        let template = NormalNetWeights::template_from(&file, path)?;
        let names: Vec<String> = normalnet_tensor_specs(&template.trunk.config)
            .into_iter()
            .flat_map(|(n, _)| [n.clone(), format!("adam.m.{n}"), format!("adam.v.{n}")])
            .collect();
        file.only(&names)?;
        let (mut weights, mut m, mut v) = (template.clone(), template.clone(), template);
        weights.fill_from(&file, "")?;
        m.fill_from(&file, "adam.m.")?;
        v.fill_from(&file, "adam.v.")?;
        weights.trunk.provenance = file.meta("provenance")?.to_string();
        Ok(NormalCheckpoint {
            step: num("step")?,
            weights,
            adam: NormalAdam { step: num("adam_step")?, m, v },
            train_config: file.meta("train_config")?.to_string(),
        })
    }
}
