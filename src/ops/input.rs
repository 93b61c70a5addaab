//! The network's input (SPEC.md §8.2): the image padded to the network's multiple with the mean
//! subtracted, and its pyramid.

use ndarray::{Array3, ArrayView3};
use rayon::prelude::*;

use crate::error::{Error, Result};
use crate::ops::config::{NetworkConfig, IMAGE_CHANNELS};
use crate::ops::downsample2x;
use crate::util::alloc::zeroed_map;

/// Pads `[h, w, c]` at the bottom and right to `[hp, wp, c]` by replicating the last row/column.
pub fn pad_edge(x: ArrayView3<f32>, hp: usize, wp: usize) -> Array3<f32> {
    let (h, w, c) = x.dim();
    Array3::from_shape_fn((hp, wp, c), |(y, i, ch)| x[[y.min(h - 1), i.min(w - 1), ch]])
}

/// Level 0 of [`image_pyramid`]: the image padded to the network's multiple (SPEC.md §8.2) with the
/// mean subtracted in f32.
///
/// # Errors
/// [`Error::InvalidArgument`] if the image is not `[H, W, 3]` with `H, W >= 1`.
pub fn padded_input(config: &NetworkConfig, image: ArrayView3<f32>) -> Result<Array3<f32>> {
    let (h, w, c) = image.dim();
    if c != IMAGE_CHANNELS || h == 0 || w == 0 {
        return Err(Error::invalid_argument(
            "image",
            format!("shape {:?}, expected [H >= 1, W >= 1, 3]", image.shape()),
        ));
    }
    let (hp, wp) = config.padded_size(h, w);
    // `pad_edge` then `v - mean[ch]` in f32, written row-parallel from slices.
    let image = image.as_standard_layout();
    let Some(src) = image.as_slice() else { unreachable!("standard layout is contiguous") };
    let mean = config.input_mean;
    let mut level0 = zeroed_map([hp, wp, c]);
    let Some(dst) = level0.as_slice_mut() else { unreachable!("a new array is contiguous") };
    dst.par_chunks_mut(wp * c).enumerate().for_each(|(y, row)| {
        let src_row = &src[y.min(h - 1) * w * c..][..w * c];
        let (inside, pad) = row.split_at_mut(w * c);
        let subtract = |o: &mut [f32], v: &[f32]| {
            for ((o, &v), m) in o.iter_mut().zip(v).zip(mean) {
                *o = v - m;
            }
        };
        for (o, v) in inside.chunks_exact_mut(IMAGE_CHANNELS).zip(src_row.chunks_exact(IMAGE_CHANNELS)) {
            subtract(o, v);
        }
        for o in pad.chunks_exact_mut(IMAGE_CHANNELS) {
            subtract(o, &src_row[(w - 1) * c..]);
        }
    });
    Ok(level0)
}

/// The image pyramid the blocks see: level 0 is the image padded (SPEC.md §8.2) with the mean
/// subtracted in f32, level `l + 1` is [`downsample2x`] of level `l`, up to `max_level`.
///
/// # Errors
/// [`Error::InvalidArgument`] if the image is not `[H, W, 3]` with `H, W >= 1`.
pub fn image_pyramid(
    config: &NetworkConfig,
    image: ArrayView3<f32>,
    max_level: usize,
) -> Result<Vec<Array3<f32>>> {
    let mut levels = vec![padded_input(config, image)?];
    for l in 0..max_level {
        let next = downsample2x(levels[l].view())?;
        levels.push(next);
    }
    Ok(levels)
}
