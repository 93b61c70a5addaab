//! NumPy `.npy` files (format version 1.0), written by hand: the magic `\x93NUMPY`, version
//! `1 0`, a little-endian `u16` header length, the header dict padded with spaces and a newline so
//! that the data starts at a multiple of 64 bytes, then the data in C order.

use std::io::Write;
use std::path::Path;

use ndarray::{ArrayView, Dimension};

use crate::error::Result;
use crate::io::write_atomic_with;

/// Magic string and version 1.0.
const MAGIC: &[u8] = b"\x93NUMPY\x01\x00";
/// Alignment of the data start.
const ALIGN: usize = 64;

/// The full preamble (magic, version, header length, padded header) of a C-order little-endian
/// f32 array of the given shape.
pub fn npy_f32_header(shape: &[usize]) -> Vec<u8> {
    let dims: Vec<String> = shape.iter().map(|d| d.to_string()).collect();
    let shape_text =
        if dims.len() == 1 { format!("({},)", dims[0]) } else { format!("({})", dims.join(", ")) };
    let mut dict = format!("{{'descr': '<f4', 'fortran_order': False, 'shape': {shape_text}, }}");
    // magic + version (8) + length (2) + dict + padding + '\n' is a multiple of 64.
    let unpadded = MAGIC.len() + 2 + dict.len() + 1;
    dict.push_str(&" ".repeat(unpadded.next_multiple_of(ALIGN) - unpadded));
    dict.push('\n');
    let mut out = MAGIC.to_vec();
    // Invariant: the dict of a 3-D shape is far below u16::MAX bytes.
    out.extend_from_slice(&(dict.len() as u16).to_le_bytes());
    out.extend_from_slice(dict.as_bytes());
    out
}

/// Writes an f32 array of any dimension (`[H, W]`, `[H, W, C]`, ...) as `.npy` (C order, `<f4`),
/// atomically.
///
/// # Errors
/// [`crate::Error::Io`] naming `path` on a write failure.
pub fn write_npy_f32<D: Dimension>(path: &Path, array: ArrayView<f32, D>) -> Result<()> {
    let header = npy_f32_header(array.shape());
    write_atomic_with(path, |w| {
        w.write_all(&header)?;
        for v in array.iter() {
            w.write_all(&v.to_le_bytes())?;
        }
        Ok(())
    })
}
