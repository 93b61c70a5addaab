//! Resampling feature maps between pyramid levels (SPEC.md §11.1): the 2x tent downsampling applied
//! `level` times, and bilinear upsampling on the integer-centre grid with its f64 reference. The
//! upsampling's row kernel is laid out per ISA: `portable.rs` (the body) and `avx512.rs` (that body
//! compiled for AVX-512F, the same bits).

use ndarray::{Array3, ArrayView3};
use rayon::prelude::*;

use crate::error::Result;
use crate::image::sample::axis;
use crate::image::sample_bilinear;
use crate::ops::downsample2x_at;
use crate::runtime::CpuFeatureLevel;

#[cfg(target_arch = "x86_64")]
mod avx512;
mod portable;

#[cfg(target_arch = "x86_64")]
use portable::upsample_row as upsample_row_portable;

/// Apply the 2x tent downsampling `level` times.
///
/// # Errors
/// Shape errors from [`downsample2x_at`].
pub fn downsample_to(x: ArrayView3<f32>, level: u32) -> Result<Array3<f32>> {
    downsample_to_at(x, level, CpuFeatureLevel::get())
}

/// [`downsample_to`] with the SIMD builds `cpu` allows (the same bits at every level).
///
/// # Errors
/// As [`downsample_to`].
pub fn downsample_to_at(x: ArrayView3<f32>, level: u32, cpu: CpuFeatureLevel) -> Result<Array3<f32>> {
    let mut out = x.to_owned();
    for _ in 0..level {
        out = downsample2x_at(out.view(), cpu)?;
    }
    Ok(out)
}

/// Bilinear upsampling by `2^levels` on the integer-centre grid (SPEC.md §2.1, §11.1): output pixel
/// `(i, j)` (`[out_h, out_w]`) is [`sample_bilinear`] of `x` at `(i / 2^levels, j / 2^levels)`, each
/// coordinate clamped to the last pixel of `x` (edge replication where the finer grid reaches past
/// it). Row-parallel; every pixel is an independent f64-weighted sample, so the bits do not depend on
/// the thread count.
///
/// The bits of [`upsample_to_reference`] (which calls [`sample_bilinear`] per pixel): the corners
/// and weights of every column are formed once by [`sample_bilinear`]'s corner rule, those of a row
/// once per row, and each channel is the same expression `((w00 I00 + w10 I10) + w01 I01) + w11 I11` in f64
/// (no fused multiply-add), read from contiguous rows, so the channel loop vectorises (AVX-512F
/// build where the CPU has it).
///
/// # Panics
/// If `x` has no pixel.
pub fn upsample_to(x: ArrayView3<f32>, levels: u32, out_h: usize, out_w: usize) -> Array3<f32> {
    upsample_to_at(x, levels, out_h, out_w, CpuFeatureLevel::get())
}

/// [`upsample_to`] with the SIMD builds `cpu` allows (the same bits at every level; the extractor
/// passes its backend's [`Backend::cpu_level`](crate::backend::Backend::cpu_level)).
///
/// # Panics
/// As [`upsample_to`].
pub fn upsample_to_at(
    x: ArrayView3<f32>,
    levels: u32,
    out_h: usize,
    out_w: usize,
    cpu: CpuFeatureLevel,
) -> Array3<f32> {
    let (h, w, c) = x.dim();
    assert!(h > 0 && w > 0, "cannot upsample an empty feature map");
    if c == 0 || out_h == 0 || out_w == 0 {
        return Array3::zeros((out_h, out_w, c));
    }
    let s = f64::from(1u32 << levels);
    let corner = |i: usize, n: usize| {
        let Some(a) = axis((i as f64 / s).min((n - 1) as f64), n) else { unreachable!("clamped inside") };
        a
    };
    let cols: Vec<(usize, usize, f64)> = (0..out_w).map(|j| corner(j, w)).collect();
    let x = x.as_standard_layout();
    let Some(src) = x.as_slice() else { unreachable!("standard layout is contiguous") };
    // Huge pages for the large map (one page fault per 2 MB instead of per 4 KB), starting on a
    // cache line so that the cost volume's block kernel reads it without an aligned copy.
    let mut map = crate::util::alloc::zeroed_map_aligned([out_h, out_w, c]);
    let Some(out) = map.as_slice_mut() else { unreachable!("a new map is standard layout") };
    #[cfg(target_arch = "x86_64")]
    let avx512 = cpu.avx512f();
    out.par_chunks_mut(out_w * c).enumerate().for_each(|(i, row)| {
        let (y0, y1, b) = corner(i, h);
        let rows = (&src[y0 * w * c..][..w * c], &src[y1 * w * c..][..w * c]);
        #[cfg(target_arch = "x86_64")]
        if avx512 {
            // SAFETY: the CPU reported AVX-512F.
            unsafe { avx512::upsample_row(rows, &cols, b, c, row) };
            return;
        }
        portable::upsample_row(rows, &cols, b, c, row);
    });
    map
}

/// The definition of [`upsample_to`]: [`sample_bilinear`] at every output pixel.
///
/// # Panics
/// If `x` has no pixel.
pub fn upsample_to_reference(x: ArrayView3<f32>, levels: u32, out_h: usize, out_w: usize) -> Array3<f32> {
    let (h, w, c) = x.dim();
    assert!(h > 0 && w > 0, "cannot upsample an empty feature map");
    let s = f64::from(1u32 << levels);
    let mut out = vec![0.0f32; out_h * out_w * c];
    out.par_chunks_mut((out_w * c).max(1)).enumerate().for_each(|(i, row)| {
        let yy = (i as f64 / s).min((h - 1) as f64);
        for (j, px) in row.chunks_mut(c.max(1)).enumerate() {
            let xx = (j as f64 / s).min((w - 1) as f64);
            let inside = sample_bilinear(&x, xx, yy, px);
            debug_assert!(inside, "clamped positions are inside");
        }
    });
    Array3::from_shape_vec((out_h, out_w, c), out).expect("length is H·W·C")
}
