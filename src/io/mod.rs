//! File output helpers: every file we write appears whole or not at all.

mod atomic;

pub use atomic::{write_atomic, write_atomic_with};
