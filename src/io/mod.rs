//! File output helpers: every file we write appears whole or not at all.

mod atomic;
mod npy;

pub use atomic::{write_atomic, write_atomic_with};
pub use npy::{npy_f32_header, write_npy_f32};
