//! The fused weight gradient of the 3x3 convolution for 32 output channels (SPEC.md §7.8), the
//! network's width: no im2col matrix and no GEMM packing. For one chunk of output rows, every
//! weight's gradient is one chain of fused multiply-adds over the chunk's output pixels in
//! row-major order,
//!
//! ```text
//! part[((ky·3 + kx)·C_in + c)·32 + o] = fma(x[s·y+ky−1, s·x+kx−1, c], g[y, x, o], ...)   (from 0)
//! ```
//!
//! skipping the pixels whose tap falls in the zero padding. Each chain is the same whichever way
//! the channels are blocked, so the portable (`f32::mul_add`), AVX2+FMA and AVX-512 versions give
//! the same bits.

use crate::ops::geometry::{Conv2dGeometry, CONV_KERNEL, CONV_PADDING};

#[cfg(target_arch = "x86_64")]
#[macro_use]
mod simd;
#[cfg(target_arch = "x86_64")]
mod avx2;
#[cfg(target_arch = "x86_64")]
mod avx512;
mod portable;

/// Output channels of the fused kernel.
pub(crate) const C_OUT: usize = 32;

/// Whether the fused kernel computes `geom`'s weight gradient.
pub(crate) fn supports(geom: &Conv2dGeometry) -> bool {
    geom.c_out() == C_OUT
}

/// The output columns `x` whose tap `kx` lies inside the input (`0 <= s x + kx − 1 < w`).
fn valid_columns(kx: usize, s: usize, w: usize, w_out: usize) -> std::ops::Range<usize> {
    let lo = CONV_PADDING.saturating_sub(kx).div_ceil(s);
    // s x + kx − 1 <= w − 1  ⇔  x <= (w + 1 − 1 − kx) / s, i.e. x < (w − kx + CONV_PADDING − 1) / s + 1.
    let hi = if w + CONV_PADDING > kx { ((w + CONV_PADDING - 1 - kx) / s + 1).min(w_out) } else { 0 };
    lo..hi.max(lo)
}

/// The output rows `y` whose tap row `s y + ky − 1` lies inside the input's `h` rows, with it.
fn tap_rows(ys: std::ops::Range<usize>, ky: usize, s: usize, h: usize) -> Vec<(usize, usize)> {
    ys.filter_map(|y| (s * y + ky).checked_sub(CONV_PADDING).filter(|&iy| iy < h).map(|iy| (y, iy))).collect()
}

/// The partial weight gradient of output rows `y0..y0 + rows` into `part` (`9 C_in · 32` values,
/// overwritten). `x_in` is the `[h, w, C_in]` input, `g` the `[h_out, w_out, 32]` output gradient.
///
/// # Panics
/// If `geom` is not [`supports`]ed or a slice is shorter than its shape. `level`: the SIMD builds it
/// may use (the same bits at every level).
pub(crate) fn chunk(
    geom: &Conv2dGeometry,
    x_in: &[f32],
    g: &[f32],
    y0: usize,
    rows: usize,
    part: &mut [f32],
    level: crate::runtime::CpuFeatureLevel,
) {
    assert!(supports(geom));
    let [h, w, c_in] = geom.input_shape();
    let (w_out, s) = (geom.w_out(), geom.stride());
    assert!(
        x_in.len() >= h * w * c_in && g.len() >= (y0 + rows) * w_out * C_OUT && y0 + rows <= geom.h_out()
    );
    assert_eq!(part.len(), CONV_KERNEL * CONV_KERNEL * c_in * C_OUT);
    part.fill(0.0);
    for ky in 0..CONV_KERNEL {
        for kx in 0..CONV_KERNEL {
            let cols = valid_columns(kx, s, w, w_out);
            if cols.is_empty() {
                continue;
            }
            let ys = tap_rows(y0..y0 + rows, ky, s, h);
            let tap = Tap { ys: &ys, cols: cols.clone(), s, kx, w, w_out, c_in };
            let out = &mut part[(ky * CONV_KERNEL + kx) * c_in * C_OUT..][..c_in * C_OUT];
            #[cfg(target_arch = "x86_64")]
            {
                if level.avx512f() {
                    // SAFETY: the CPU has AVX-512F (`avx512f` checks it); the asserts above bound every access.
                    unsafe { avx512::tap(&tap, x_in, g, out) };
                    continue;
                }
                if level.avx2_fma() {
                    // SAFETY: the CPU has AVX2 and FMA (`avx2_fma` checks them); as above.
                    unsafe { avx2::tap(&tap, x_in, g, out) };
                    continue;
                }
            }
            portable::tap(&tap, x_in, g, out);
        }
    }
}

/// One tap `(ky, kx)` of a chunk: the output rows with their input rows, the valid columns.
struct Tap<'a> {
    ys: &'a [(usize, usize)],
    cols: std::ops::Range<usize>,
    s: usize,
    kx: usize,
    w: usize,
    w_out: usize,
    c_in: usize,
}

impl Tap<'_> {
    /// Offsets of pixel `(y, x)`'s tap input (`+ c`) and of its output gradient (`+ o`).
    #[inline(always)]
    fn offsets(&self, y: usize, iy: usize, x: usize) -> (usize, usize) {
        let ix = self.s * x + self.kx - CONV_PADDING;
        ((iy * self.w + ix) * self.c_in, (y * self.w_out + x) * C_OUT)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::util::rng::SplitMix64;

    /// Every ISA gives the portable chains' bits, on the network's input widths (3, 32, 35), both
    /// strides and maps with a 1-pixel edge.
    #[test]
    fn simd_and_portable_give_the_same_bits() {
        let mut rng = SplitMix64::new(5);
        for (h, w, c_in, s) in [(9, 11, 3, 1), (10, 13, 35, 2), (7, 5, 32, 1), (1, 1, 32, 2), (12, 17, 32, 2)]
        {
            let geom = Conv2dGeometry::new(h, w, c_in, C_OUT, s).unwrap();
            let x: Vec<f32> = (0..h * w * c_in).map(|_| rng.range(-2.0, 2.0) as f32).collect();
            let g: Vec<f32> =
                (0..geom.h_out() * geom.w_out() * C_OUT).map(|_| rng.range(-1.0, 1.0) as f32).collect();
            let (y0, rows) = (0, geom.h_out());
            let mut want = vec![0.0f32; 9 * c_in * C_OUT];
            for ky in 0..3 {
                for kx in 0..3 {
                    let ys = tap_rows(y0..y0 + rows, ky, s, h);
                    let t = Tap {
                        ys: &ys,
                        cols: valid_columns(kx, s, w, geom.w_out()),
                        s,
                        kx,
                        w,
                        w_out: geom.w_out(),
                        c_in,
                    };
                    portable::tap(&t, &x, &g, &mut want[(ky * 3 + kx) * c_in * C_OUT..][..c_in * C_OUT]);
                }
            }
            // Every CPU-feature level (AVX-512, AVX2 and portable on an AVX-512 machine): the
            // portable tap's bits.
            let mut got = vec![f32::NAN; 9 * c_in * C_OUT];
            for level in crate::runtime::CpuFeatureLevel::ALL {
                got.fill(f32::NAN);
                chunk(&geom, &x, &g, y0, rows, &mut got, level);
                let same = got.iter().zip(&want).all(|(a, b)| a.to_bits() == b.to_bits());
                assert!(same, "{level:?} {:?}", (h, w, c_in, s));
            }
            // Against a plain f64 sum.
            for (i, &v) in got.iter().enumerate() {
                let (t, c, o) = (i / (c_in * C_OUT), i / C_OUT % c_in, i % C_OUT);
                let (ky, kx) = (t / 3, t % 3);
                let mut sum = 0.0f64;
                for y in 0..geom.h_out() {
                    for xo in 0..geom.w_out() {
                        let (iy, ix) = (s * y + ky, s * xo + kx);
                        if iy >= 1 && ix >= 1 && iy - 1 < h && ix - 1 < w {
                            sum += f64::from(x[((iy - 1) * w + ix - 1) * c_in + c])
                                * f64::from(g[(y * geom.w_out() + xo) * C_OUT + o]);
                        }
                    }
                }
                assert!((f64::from(v) - sum).abs() <= 1e-4 * (1.0 + sum.abs()), "{v} vs {sum}");
            }
        }
    }

    #[test]
    fn valid_columns_are_those_inside_the_input() {
        for s in 1usize..=2 {
            for w in 1usize..9 {
                let w_out = (w + 2 - 3) / s + 1;
                for kx in 0usize..3 {
                    let want: Vec<usize> = (0..w_out)
                        .filter(|&x| (s * x + kx).checked_sub(1).is_some_and(|ix| ix < w))
                        .collect();
                    assert_eq!(
                        valid_columns(kx, s, w, w_out).collect::<Vec<_>>(),
                        want,
                        "s {s} w {w} kx {kx}"
                    );
                }
            }
        }
    }
}
