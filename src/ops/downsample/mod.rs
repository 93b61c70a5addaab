//! 2x image downsampling (SPEC.md §2.1, §7.4) and the network's elementwise helpers on
//! channels-last `[H, W, C]` arrays.

use ndarray::{Array3, ArrayView3};
use rayon::prelude::*;

use crate::error::{Error, Result};
use crate::ops::geometry::DownsampleGeometry;
use crate::runtime::CpuFeatureLevel;

#[cfg(target_arch = "x86_64")]
mod avx512;
mod portable;

use crate::util::alloc::zeroed_map;
#[cfg(target_arch = "x86_64")]
use portable::combine as combine_portable;

/// Tent filter `[1/4, 1/2, 1/4]`, centred on input pixel `2j` for output pixel `j`.
const TENT: [f64; 3] = [0.25, 0.5, 0.25];

/// Input index of tap `t ∈ {0, 1, 2}` of output `j` along an axis of length `n`: `2j + t - 1`,
/// clamped to `0..n` (edge replication).
#[inline]
fn tap(j: usize, t: usize, n: usize) -> usize {
    (2 * j + t).saturating_sub(1).min(n - 1)
}

/// 2x downsampling with the separable tent `[1/4, 1/2, 1/4]` centred on input pixel `2j`, edges
/// replicated, so output pixel `j` sits at input pixel `2j` as after a stride-2 convolution:
///
/// `out[j, i, c] = Σ_{a, b ∈ {0,1,2}} t[a] t[b] in[clamp(2j + a - 1), clamp(2i + b - 1), c]`.
///
/// The nine-term sum is formed in f64 (the products by powers of two are exact) and rounded once
/// to f32, so a constant image stays exactly constant.
///
/// ```text
///  n = 5:   in0 in0 in1 in2 in3 in4 in4     (edges replicated)
///  out0     [1/4 1/2 1/4]
///  out1             [1/4 1/2 1/4]
///  out2                     [1/4 1/2 1/4]
/// ```
///
/// # Shapes
/// `[h, w, c]` to `[ceil(h/2), ceil(w/2), c]`.
///
/// # Errors
/// [`Error::InvalidArgument`] if a dimension is zero.
pub fn downsample2x(input: ArrayView3<f32>) -> Result<Array3<f32>> {
    downsample2x_at(input, CpuFeatureLevel::get())
}

/// [`downsample2x`] with the SIMD builds `level` allows (the same bits at every level; a backend
/// passes its own).
///
/// # Errors
/// As [`downsample2x`].
pub fn downsample2x_at(input: ArrayView3<f32>, level: CpuFeatureLevel) -> Result<Array3<f32>> {
    let (h, w, c) = input.dim();
    let geom = DownsampleGeometry::new(h, w, c)?;
    let [h_out, w_out, _] = geom.output_shape();
    let mut out = zeroed_map([h_out, w_out, c]);
    let Some(out_slice) = out.as_slice_mut() else { unreachable!("a new array is contiguous") };
    let input = input.as_standard_layout();
    let Some(src) = input.as_slice() else { unreachable!("standard layout is contiguous") };
    let avx512 = level.avx512f();
    out_slice.par_chunks_mut(w_out * c).enumerate().for_each_init(
        || TentRows::new(w_out, c),
        |taps, (j, row)| {
            for a in 0..3 {
                taps.load(a, &src[tap(j, a, h) * w * c..][..w * c]);
            }
            for ch in 0..c {
                taps.combine(ch, avx512);
                for (o, &v) in row[ch..].iter_mut().step_by(c).zip(&taps.plane) {
                    *o = v;
                }
            }
        },
    );
    Ok(out)
}

/// One output row's taps, per input row and channel, as f64 (exact), split so that output `i`'s
/// three taps along a row are `even[i]`, `odd[i]`, `even[i + 1]`: `even[i] = in[clamp(2i - 1)]`,
/// `odd[i] = in[2i]`. Every output column then reads contiguous memory, and the nine-term sum
/// vectorises across columns in the definition's order (the same bits as
/// [`downsample2x_reference`]).
struct TentRows {
    /// `[3][c]` rows of `w_out + 1` values.
    even: Vec<Vec<f64>>,
    /// `[3][c]` rows of `w_out` values.
    odd: Vec<Vec<f64>>,
    channels: usize,
    plane: Vec<f32>,
}

impl TentRows {
    fn new(w_out: usize, c: usize) -> Self {
        Self {
            even: (0..3 * c).map(|_| vec![0.0; w_out + 1]).collect(),
            odd: (0..3 * c).map(|_| vec![0.0; w_out]).collect(),
            channels: c,
            plane: vec![0.0; w_out],
        }
    }

    /// The input row `src_row` (`[w, c]`) as tap row `a`, every channel, in one pass (the image's
    /// three channels unrolled).
    fn load(&mut self, a: usize, src_row: &[f32]) {
        match self.channels {
            3 => self.load_channels::<3>(a, src_row),
            _ => self.load_channels::<0>(a, src_row),
        }
    }

    /// [`TentRows::load`] for `C` channels (`C = 0`: the run-time count).
    fn load_channels<const C: usize>(&mut self, a: usize, src_row: &[f32]) {
        let c = if C == 0 { self.channels } else { C };
        let w_out = self.plane.len();
        let (even, odd) = (&mut self.even[a * c..][..c], &mut self.odd[a * c..][..c]);
        for ch in 0..c {
            let (e, o) = (&mut even[ch][..w_out + 1], &mut odd[ch][..w_out]);
            e[0] = f64::from(src_row[ch]);
            // Pixel pairs (2i, 2i + 1); the last odd-indexed tap of an odd width is the edge pixel.
            let pairs = src_row.chunks_exact(2 * c);
            let tail = pairs.remainder();
            for (i, pair) in pairs.enumerate() {
                o[i] = f64::from(pair[ch]);
                e[i + 1] = f64::from(pair[c + ch]);
            }
            if !tail.is_empty() {
                o[w_out - 1] = f64::from(tail[ch]);
                e[w_out] = f64::from(tail[ch]);
            }
        }
    }

    /// `plane[i]`: the nine-term sum of output column `i`, channel `ch`.
    fn combine(&mut self, ch: usize, avx512: bool) {
        let c = self.channels;
        let even = [0, 1, 2].map(|a| self.even[a * c + ch].as_slice());
        let odd = [0, 1, 2].map(|a| self.odd[a * c + ch].as_slice());
        #[cfg(target_arch = "x86_64")]
        if avx512 {
            // SAFETY: the CPU has AVX-512F (`CpuFeatureLevel::avx512f` checked it).
            unsafe { avx512::combine(even, odd, &mut self.plane) };
            return;
        }
        let _ = avx512;
        portable::combine(even, odd, &mut self.plane);
    }
}

/// The definition of [`downsample2x`] as plain loops (the nine terms per output value in f64, in the
/// order of the formula), one thread: the reference the fast version is tested against bit for bit.
///
/// # Errors
/// [`Error::InvalidArgument`] if a dimension is zero.
pub fn downsample2x_reference(input: ArrayView3<f32>) -> Result<Array3<f32>> {
    let (h, w, c) = input.dim();
    let geom = DownsampleGeometry::new(h, w, c)?;
    let [h_out, w_out, _] = geom.output_shape();
    let mut out = Array3::<f32>::zeros((h_out, w_out, c));
    for j in 0..h_out {
        for i in 0..w_out {
            for ch in 0..c {
                let mut acc = 0.0f64;
                for (a, ta) in TENT.iter().enumerate() {
                    for (b, tb) in TENT.iter().enumerate() {
                        acc += ta * tb * f64::from(input[[tap(j, a, h), tap(i, b, w), ch]]);
                    }
                }
                out[[j, i, ch]] = acc as f32;
            }
        }
    }
    Ok(out)
}

/// Concatenates two maps along channels: `[h, w, ca]`, `[h, w, cb]` to `[h, w, ca + cb]`, `a`'s
/// channels first (PyTorch `torch.cat([a, b], dim=1)` in NCHW).
///
/// # Errors
/// [`Error::InvalidArgument`] if the heights or widths differ.
pub fn concat_channels(a: ArrayView3<f32>, b: ArrayView3<f32>) -> Result<Array3<f32>> {
    let (h, w, ca) = a.dim();
    let mut out = zeroed_map([h, w, ca + b.dim().2]);
    let Some(dst) = out.as_slice_mut() else { unreachable!("a new array is contiguous") };
    concat_channels_into(a, b, dst)?;
    Ok(out)
}

/// The check of every channel concatenation: `a` and `b` (`[h, w, c]` shapes) have the same height
/// and width.
///
/// # Errors
/// [`Error::InvalidArgument`] naming `concat_channels` and both shapes otherwise.
pub fn check_same_spatial(a: &[usize], b: &[usize]) -> Result<()> {
    if a[..2] != b[..2] {
        return Err(Error::invalid_argument(
            "concat_channels",
            format!("spatial sizes differ: {a:?} and {b:?}"),
        ));
    }
    Ok(())
}

/// [`concat_channels`] into a caller-provided slice (`[h, w, ca + cb]`, row-major, every value
/// overwritten).
///
/// # Errors
/// [`Error::InvalidArgument`] if the heights or widths differ or `out` has the wrong length.
pub fn concat_channels_into(a: ArrayView3<f32>, b: ArrayView3<f32>, out: &mut [f32]) -> Result<()> {
    check_same_spatial(a.shape(), b.shape())?;
    let (h, w, ca) = a.dim();
    let cb = b.dim().2;
    let c = ca + cb;
    crate::ops::expect_len("concat_channels output", out.len(), h * w * c)?;
    let (a, b) = (a.as_standard_layout(), b.as_standard_layout());
    let (Some(sa), Some(sb)) = (a.as_slice(), b.as_slice()) else {
        unreachable!("standard layout is contiguous")
    };
    if w * c > 0 {
        // Each output row is written by one task: a pure copy of contiguous channel runs.
        out.par_chunks_mut(w * c).enumerate().for_each(|(y, row)| {
            for (x, px) in row.chunks_exact_mut(c).enumerate() {
                let p = y * w + x;
                px[..ca].copy_from_slice(&sa[p * ca..(p + 1) * ca]);
                px[ca..].copy_from_slice(&sb[p * cb..(p + 1) * cb]);
            }
        });
    }
    Ok(())
}

/// Elementwise sum of two maps of the same shape.
///
/// # Errors
/// [`Error::InvalidArgument`] if the shapes differ.
pub fn add(a: ArrayView3<f32>, b: ArrayView3<f32>) -> Result<Array3<f32>> {
    if a.shape() != b.shape() {
        return Err(Error::invalid_argument(
            "add",
            format!("shapes differ: {:?} and {:?}", a.shape(), b.shape()),
        ));
    }
    let (a, b) = (a.as_standard_layout(), b.as_standard_layout());
    let (sa, sb) = (
        a.as_slice().expect("standard layout is contiguous"),
        b.as_slice().expect("standard layout is contiguous"),
    );
    let mut out = zeroed_map(a.dim().into());
    let dst = out.as_slice_mut().expect("freshly allocated arrays are contiguous");
    // Elementwise, in parallel over fixed chunks: each output written once, no reduction.
    const CHUNK: usize = 1 << 14;
    dst.par_chunks_mut(CHUNK).enumerate().for_each(|(i, o)| {
        let start = i * CHUNK;
        for ((o, &x), &y) in o.iter_mut().zip(&sa[start..]).zip(&sb[start..]) {
            *o = x + y;
        }
    });
    Ok(out)
}

/// Backward of [`downsample2x`]: the gradient with respect to its `[h, w, c]` input, the
/// transpose of the tent filter with edge replication (a clamped tap sends its share to the edge
/// pixel). Sums in f64 in a fixed order (output rows, then columns, then taps), rounded once; one
/// task per input channel plane would change nothing, so it runs serially (it is off the training
/// path, which never differentiates with respect to the image).
///
/// # Errors
/// [`Error::InvalidArgument`] if a dimension is zero or `d_out` is not `[ceil(h/2), ceil(w/2), c]`.
pub fn downsample2x_backward(d_out: ArrayView3<f32>, h: usize, w: usize) -> Result<Array3<f32>> {
    let c = d_out.dim().2;
    let geom = DownsampleGeometry::new(h, w, c)?;
    crate::ops::expect_shape("downsample2x_backward d_out", d_out.shape(), &geom.output_shape())?;
    let (h_out, w_out, _) = d_out.dim();
    let mut acc = ndarray::Array3::<f64>::zeros((h, w, c));
    for j in 0..h_out {
        for i in 0..w_out {
            for (a, ta) in TENT.iter().enumerate() {
                for (b, tb) in TENT.iter().enumerate() {
                    let (y, x) = (tap(j, a, h), tap(i, b, w));
                    for ch in 0..c {
                        acc[[y, x, ch]] += ta * tb * f64::from(d_out[[j, i, ch]]);
                    }
                }
            }
        }
    }
    Ok(acc.mapv(|v| v as f32))
}

/// Backward of [`concat_channels`]: splits `d_out` (`[h, w, ca + cb]`) into the gradients of `a`
/// (its first `ca` channels) and `b` (the rest).
///
/// # Errors
/// [`Error::InvalidArgument`] if `ca` exceeds the channel count.
pub fn concat_channels_backward(d_out: ArrayView3<f32>, ca: usize) -> Result<(Array3<f32>, Array3<f32>)> {
    let c = d_out.dim().2;
    if ca > c {
        return Err(Error::invalid_argument("concat_channels_backward", format!("{ca} channels of {c}")));
    }
    Ok((d_out.slice(ndarray::s![.., .., ..ca]).to_owned(), d_out.slice(ndarray::s![.., .., ca..]).to_owned()))
}
