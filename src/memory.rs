//! The one memory guard (SPEC.md §14.3). Every command that allocates in proportion to its arguments
//! estimates its peak first and refuses, before any heavy work or write, when the estimate is above
//! `--max-memory-mb` (default [`DEFAULT_MAX_MEMORY_MB`]), naming the flags that shrink it.
//!
//! The estimates are upper-bound models of the big arrays; SPEC.md §14.3 lists them beside measured
//! peak resident memory.

use crate::error::{Error, Result};

/// Default of every `--max-memory-mb` flag, MiB.
pub const DEFAULT_MAX_MEMORY_MB: usize = 2048;

const MIB: u64 = 1024 * 1024;

/// Refuse when `bytes` (an estimate for `what`) exceeds `max_mb` MiB.
///
/// # Errors
/// [`Error::InvalidArgument`] naming `--max-memory-mb`, the estimate, the limit and `shrink` (the
/// flags that make the run smaller).
pub fn check(max_mb: usize, what: &str, bytes: u64, shrink: &str) -> Result<()> {
    let limit = (max_mb as u64).saturating_mul(MIB);
    if bytes <= limit {
        return Ok(());
    }
    Err(Error::invalid_argument(
        "--max-memory-mb",
        format!(
            "{what} needs about {} MiB, over the limit of {max_mb} MiB: {shrink}, or raise --max-memory-mb",
            bytes.div_ceil(MIB)
        ),
    ))
}

/// Product of sizes without overflow (saturates: a saturated estimate is always refused).
pub fn product(factors: &[u64]) -> u64 {
    factors.iter().fold(1u64, |acc, &f| acc.saturating_mul(f))
}

/// Cost volume of `height x width` cells, `bins` hypotheses, `channels` feature channels: f32 sums,
/// the f32 costs copy, u16 counts (10 bytes a cell), DTAM's f32 block minima (one per 8 hypotheses)
/// and two feature maps (SPEC.md §11.2).
pub fn cost_volume_bytes(height: usize, width: usize, bins: usize, channels: usize) -> u64 {
    let (h, w, k, c) = (height as u64, width as u64, bins as u64, channels as u64);
    product(&[h, w, k, 10])
        .saturating_add(product(&[h, w, k.div_ceil(8), 4]))
        .saturating_add(product(&[2, h, w, c, 4]))
}

/// One forward pass of the feature network on a `height x width` image with `channels` channels
/// and block-1 stride `stride`: six level-1 maps of `C` f32 (block outputs, aggregation, im2col
/// panels) plus 16 bytes a level-0 pixel (the decoded image and its f32 copy). Measured peak
/// resident memory is 0.77-0.99 of this (SPEC.md §14.3).
pub fn network_forward_bytes(height: usize, width: usize, channels: usize, stride: usize) -> u64 {
    let s = stride.max(1) as u64;
    let (h1, w1) = ((height as u64).div_ceil(s), (width as u64).div_ceil(s));
    product(&[6, h1, w1, channels as u64, 4]).saturating_add(product(&[16, height as u64, width as u64]))
}

/// One training step on a `width x height` crop: `48 C + 64` bytes a crop pixel (two images'
/// activations kept for the backward pass, their gradients, the rendered pair), measured
/// 0.8-0.94 of this at C = 32 (SPEC.md §14.3).
pub fn train_step_bytes(width: usize, height: usize, channels: usize) -> u64 {
    product(&[width as u64, height as u64, 48u64.saturating_mul(channels as u64).saturating_add(64)])
}
