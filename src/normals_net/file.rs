//! A plain f32 safetensors writer and checked reader for the normal predictor's files
//! (SPEC.md §13.11): weights `normalnet.safetensors` and the training checkpoint.
//!
//! The writer is byte-reproducible as §8.4's: the header is JSON with keys sorted (`__metadata__`
//! first), padded with spaces to a multiple of 8 bytes, tensor data in the order given.

use std::collections::HashMap;
use std::path::Path;

use safetensors::{Dtype, SafeTensors};

use crate::error::{Error, Result};
use crate::nn::weights::MAX_HEADER_BYTES;

pub use crate::nn::weights::{f32_safetensors_bytes as to_bytes, TensorOut};

/// A parsed file: its metadata and a checked accessor for its tensors.
pub struct TensorFile<'a> {
    /// `__metadata__`.
    pub metadata: HashMap<String, String>,
    st: SafeTensors<'a>,
    path: &'a Path,
}

impl<'a> TensorFile<'a> {
    /// Parses `bytes` (`path` names the file in errors). The header may be at most
    /// [`MAX_HEADER_BYTES`].
    ///
    /// # Errors
    /// [`Error::BadFile`] naming `path` for anything that is not a safetensors file.
    pub fn parse(bytes: &'a [u8], path: &'a Path) -> Result<Self> {
        let bad = |what: String| Error::bad_file(path, what);
        let Some(len) = bytes.first_chunk::<8>() else {
            return Err(bad(format!("truncated: {} bytes, a safetensors file starts with 8", bytes.len())));
        };
        if u64::from_le_bytes(*len) > MAX_HEADER_BYTES as u64 {
            return Err(bad(format!("header larger than the {MAX_HEADER_BYTES}-byte cap")));
        }
        let (_, header) =
            SafeTensors::read_metadata(bytes).map_err(|e| bad(format!("not a safetensors file: {e}")))?;
        let metadata = header.metadata().clone().unwrap_or_default();
        let st = SafeTensors::deserialize(bytes).map_err(|e| bad(format!("not a safetensors file: {e}")))?;
        Ok(TensorFile { metadata, st, path })
    }

    /// Metadata value `key`.
    ///
    /// # Errors
    /// [`Error::BadFile`] if it is missing.
    pub fn meta(&self, key: &str) -> Result<&str> {
        self.metadata
            .get(key)
            .map(String::as_str)
            .ok_or_else(|| Error::bad_file(self.path, format!("metadata has no {key:?}")))
    }

    /// Tensor `name`, checked: present, F32, of shape `shape`, every value finite.
    ///
    /// # Errors
    /// [`Error::BadFile`] naming the file and the tensor.
    pub fn tensor(&self, name: &str, shape: &[usize]) -> Result<Vec<f32>> {
        let bad = |what: String| Error::bad_file(self.path, what);
        let t = self.st.tensor(name).map_err(|_| bad(format!("tensor {name:?} is missing")))?;
        if t.dtype() != Dtype::F32 || t.shape() != shape {
            return Err(bad(format!(
                "tensor {name:?} is {:?} {:?}, expected F32 {shape:?}",
                t.dtype(),
                t.shape()
            )));
        }
        let values: Vec<f32> =
            t.data().chunks_exact(4).map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]])).collect();
        if let Some(i) = values.iter().position(|v| !v.is_finite()) {
            return Err(bad(format!("tensor {name:?}: non-finite value {} at flat index {i}", values[i])));
        }
        Ok(values)
    }

    /// Refuses tensors other than `expected`.
    ///
    /// # Errors
    /// [`Error::BadFile`] listing the unexpected names.
    pub fn only(&self, expected: &[String]) -> Result<()> {
        let mut extra: Vec<&str> =
            self.st.names().into_iter().filter(|n| !expected.iter().any(|e| e == *n)).collect();
        extra.sort_unstable();
        if extra.is_empty() {
            Ok(())
        } else {
            Err(Error::bad_file(self.path, format!("unexpected tensors {extra:?}")))
        }
    }
}
