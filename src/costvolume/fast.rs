//! The fast kernel.
//!
//! Per reference pixel `u`, `p(ρ) = R K⁻¹ u̇ + ρ t` is affine in `ρ`: `a = R K⁻¹ u̇` is computed
//! once ([`Warp::point`] at `ρ = 0`) and each hypothesis costs three multiply-adds, a projection and
//! a bounds check, with exactly the `f64` expressions of [`Warp::apply`] and `sample_bilinear`, so
//! validity (and hence every count) matches the reference bit for bit. Valid hypotheses are
//! collected first (corner offset and four `f32` bilinear weights); the channel loop then reads the
//! four corner vectors contiguously (channels last), shares the weights across channels, and keeps
//! [`LANES`] independent `f32` partial sums that are folded by a fixed pairwise tree. The lane
//! structure is explicit, so the bits do not depend on which vector width the compiler picks: the
//! AVX-512 build of the same function and the baseline build agree exactly.
//!
//! Rows are processed in parallel (rayon); each row's `W·K` cells belong to one task.

use nalgebra::Vector3;
use rayon::prelude::*;

use crate::geometry::{PinholeCamera, Warp};

/// Width of the channel loop's partial sums (one AVX-512 register of `f32`).
const LANES: usize = 16;

/// Camera and warp of one live frame.
pub(super) struct Geometry<'a> {
    pub camera: &'a PinholeCamera,
    pub warp: &'a Warp,
    /// `t_nr`.
    pub t: Vector3<f64>,
}

/// Reference and live features, `[H, W, C]` row-major.
pub(super) struct Slices<'a> {
    pub reference: &'a [f32],
    pub live: &'a [f32],
    pub channels: usize,
}

/// One valid hypothesis of a pixel: its bin, the flat offset of the top-left corner's first channel,
/// the offsets to the right and lower corners (0 on a 1-pixel-wide or -high image), and the weights
/// `(1-a)(1-b), a(1-b), (1-a)b, ab` rounded to `f32`.
#[derive(Clone, Copy, Debug, Default)]
struct Tap {
    k: usize,
    offset: usize,
    dx: usize,
    dy: usize,
    w: [f32; 4],
}

/// Which kernel [`CostVolumeImpl::Fast`](super::CostVolumeImpl::Fast) runs on this CPU:
/// `"avx512"` or `"portable"`.
pub fn fast_kernel_name() -> &'static str {
    if has_avx512() {
        "avx512"
    } else {
        "portable"
    }
}

fn has_avx512() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::arch::is_x86_feature_detected!("avx512f")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// Corner index and weight along one axis, as `image::sample` does; `None` outside `[0, n-1]`.
#[inline(always)]
fn axis(x: f64, n: usize) -> Option<(usize, usize, f64)> {
    if !(x >= 0.0 && x <= (n - 1) as f64) {
        return None;
    }
    if n == 1 {
        return Some((0, 0, 0.0));
    }
    let x0 = (x.floor() as usize).min(n - 2);
    Some((x0, 1, x - x0 as f64))
}

/// Add one live frame into `sums` / `counts` (`[H, W, K]`). `dispatch`: use AVX-512 when available.
pub(super) fn add_frame(
    geo: &Geometry,
    feats: &Slices,
    rhos: &[f64],
    sums: &mut [f32],
    counts: &mut [u16],
    dispatch: bool,
) {
    let (w, k_count) = (geo.camera.width, rhos.len());
    let row_cells = w * k_count;
    let use_avx512 = dispatch && has_avx512();
    sums.par_chunks_mut(row_cells).zip(counts.par_chunks_mut(row_cells)).enumerate().for_each_init(
        || Vec::with_capacity(k_count),
        |taps, (y, (sum_row, count_row))| {
            #[cfg(target_arch = "x86_64")]
            if use_avx512 {
                // SAFETY: `has_avx512()` reported AVX-512F on this CPU.
                unsafe { row_avx512(geo, feats, rhos, y, sum_row, count_row, taps) };
                return;
            }
            let _ = use_avx512;
            row(geo, feats, rhos, y, sum_row, count_row, taps);
        },
    );
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
unsafe fn row_avx512(
    geo: &Geometry,
    feats: &Slices,
    rhos: &[f64],
    y: usize,
    sum_row: &mut [f32],
    count_row: &mut [u16],
    taps: &mut Vec<Tap>,
) {
    row(geo, feats, rhos, y, sum_row, count_row, taps);
}

/// One reference row.
#[inline(always)]
fn row(
    geo: &Geometry,
    feats: &Slices,
    rhos: &[f64],
    y: usize,
    sum_row: &mut [f32],
    count_row: &mut [u16],
    taps: &mut Vec<Tap>,
) {
    let cam = geo.camera;
    let (w, h, c, k_count) = (cam.width, cam.height, feats.channels, rhos.len());
    for x in 0..w {
        // a = R K⁻¹ u̇ (+ 0·t, which leaves every later value's bits unchanged).
        let a = geo.warp.point(x as f64, y as f64, 0.0);
        taps.clear();
        for (k, &rho) in rhos.iter().enumerate() {
            let p = a + geo.t * rho;
            let Some(uv) = cam.project(&p) else { continue };
            let (Some((x0, dx, fa)), Some((y0, dy, fb))) = (axis(uv.x, w), axis(uv.y, h)) else {
                continue;
            };
            let wts = [(1.0 - fa) * (1.0 - fb), fa * (1.0 - fb), (1.0 - fa) * fb, fa * fb];
            taps.push(Tap {
                k,
                offset: (y0 * w + x0) * c,
                dx: dx * c,
                dy: dy * w * c,
                w: wts.map(|v| v as f32),
            });
        }
        let r = &feats.reference[(y * w + x) * c..(y * w + x + 1) * c];
        let sums = &mut sum_row[x * k_count..(x + 1) * k_count];
        let counts = &mut count_row[x * k_count..(x + 1) * k_count];
        for tap in taps.iter() {
            let o = tap.offset;
            let l1 = l1_distance(
                r,
                &feats.live[o..o + c],
                &feats.live[o + tap.dx..o + tap.dx + c],
                &feats.live[o + tap.dy..o + tap.dy + c],
                &feats.live[o + tap.dy + tap.dx..o + tap.dy + tap.dx + c],
                tap.w,
            );
            sums[tap.k] += l1;
            counts[tap.k] += 1;
        }
    }
}

/// `Σ_c |r_c - (w0 p00_c + w1 p10_c + w2 p01_c + w3 p11_c)|` in `f32`, with [`LANES`] partial sums
/// (channel `c` goes to lane `c mod LANES`) folded pairwise.
#[inline(always)]
fn l1_distance(r: &[f32], p00: &[f32], p10: &[f32], p01: &[f32], p11: &[f32], w: [f32; 4]) -> f32 {
    let mut acc = [0.0f32; LANES];
    let n = r.len();
    let full = n - n % LANES;
    let mut i = 0;
    while i < full {
        let (r, a, b, c, d) = (
            &r[i..i + LANES],
            &p00[i..i + LANES],
            &p10[i..i + LANES],
            &p01[i..i + LANES],
            &p11[i..i + LANES],
        );
        for l in 0..LANES {
            let s = w[0] * a[l] + w[1] * b[l] + w[2] * c[l] + w[3] * d[l];
            acc[l] += (r[l] - s).abs();
        }
        i += LANES;
    }
    for l in 0..n - full {
        let j = full + l;
        let s = w[0] * p00[j] + w[1] * p10[j] + w[2] * p01[j] + w[3] * p11[j];
        acc[l] += (r[j] - s).abs();
    }
    let mut width = LANES / 2;
    while width > 0 {
        for l in 0..width {
            acc[l] += acc[l + width];
        }
        width /= 2;
    }
    acc[0]
}
