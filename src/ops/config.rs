//! The feature network's hyper-parameters and the shape arithmetic that follows from them
//! (SPEC.md §8.1): how many blocks, how wide, whether block 1 downsamples, and on which pyramid
//! level each block's output lives.

use crate::error::{Error, Result};

/// Largest number of encoder blocks (the paper's network has five).
pub const MAX_BLOCKS: usize = 5;
/// Channels of the RGB input image.
pub const IMAGE_CHANNELS: usize = 3;
/// The paper's feature width.
pub const DEFAULT_CHANNELS: usize = 32;

/// Hyper-parameters of the feature network (SPEC.md §8.1).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NetworkConfig {
    /// Number of encoder blocks, `1..=5`.
    pub blocks: usize,
    /// Output channels of every convolution (and of the features), at least 1.
    pub channels: usize,
    /// Stride of block 1's first convolution: 2 (the paper) or 1 (full-resolution features).
    pub b1_stride: usize,
    /// Mean RGB colour (0-255 scale) subtracted from the image before block 1; no other scaling.
    pub input_mean: [f32; 3],
}

impl Default for NetworkConfig {
    /// The paper's network: five blocks of 32 channels, block 1 with stride 2, mean 0.
    fn default() -> Self {
        NetworkConfig { blocks: MAX_BLOCKS, channels: DEFAULT_CHANNELS, b1_stride: 2, input_mean: [0.0; 3] }
    }
}

impl NetworkConfig {
    /// Checks every field's range.
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] naming the field: `blocks` outside `1..=5`, `channels == 0` or
    /// above 4096, `b1_stride` other than 1 or 2, a non-finite mean.
    pub fn validate(&self) -> Result<()> {
        if !(1..=MAX_BLOCKS).contains(&self.blocks) {
            return Err(Error::invalid_argument(
                "blocks",
                format!("{} is not in 1..={MAX_BLOCKS}", self.blocks),
            ));
        }
        if !(1..=4096).contains(&self.channels) {
            return Err(Error::invalid_argument("channels", format!("{} is not in 1..=4096", self.channels)));
        }
        if self.b1_stride != 1 && self.b1_stride != 2 {
            return Err(Error::invalid_argument("b1_stride", format!("{} is not 1 or 2", self.b1_stride)));
        }
        if self.input_mean.iter().any(|m| !m.is_finite()) {
            return Err(Error::invalid_argument(
                "input_mean",
                format!("{:?} is not finite", self.input_mean),
            ));
        }
        Ok(())
    }

    /// Pyramid level of block `k`'s output (`k` 0-based): `k + 1` with block-1 stride 2, `k` with
    /// stride 1. A level-`l` map of a `W`-wide image is `ceil(W / 2^l)` wide (SPEC.md §2.6).
    pub fn block_level(&self, k: usize) -> usize {
        k + usize::from(self.b1_stride == 2)
    }

    /// `log2` of the total stride: the level of the last block's output.
    pub fn total_stride_log2(&self) -> usize {
        self.block_level(self.blocks - 1)
    }

    /// Stride of block `k`'s first convolution.
    pub fn block_stride(&self, k: usize) -> usize {
        if k == 0 {
            self.b1_stride
        } else {
            2
        }
    }

    /// Input channels of block `k`: 3 (the image) for block 0, otherwise the previous block's
    /// `channels` followed by the 3 image channels.
    pub fn block_in_channels(&self, k: usize) -> usize {
        if k == 0 {
            IMAGE_CHANNELS
        } else {
            self.channels + IMAGE_CHANNELS
        }
    }

    /// Size `(h, w)` of a level-`level` map of an `h x w` image: `(ceil(h / 2^l), ceil(w / 2^l))`.
    pub fn level_size(h: usize, w: usize, level: usize) -> (usize, usize) {
        (h.div_ceil(1 << level), w.div_ceil(1 << level))
    }

    /// Input size after padding an `h x w` image at the bottom/right to a multiple of the total
    /// stride `2^total_stride_log2()`.
    pub fn padded_size(&self, h: usize, w: usize) -> (usize, usize) {
        let m = 1usize << self.total_stride_log2();
        (h.div_ceil(m) * m, w.div_ceil(m) * m)
    }

    /// `(h, w, channels)` of every block's output (and aggregate) for an `h x w` image, after
    /// cropping (SPEC.md §8.2).
    pub fn output_shapes(&self, h: usize, w: usize) -> Vec<[usize; 3]> {
        (0..self.blocks)
            .map(|k| {
                let (hl, wl) = Self::level_size(h, w, self.block_level(k));
                [hl, wl, self.channels]
            })
            .collect()
    }
}
