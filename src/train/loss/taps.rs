//! The in-image hypotheses of one reference pixel and their bilinear taps (SPEC.md §13.1 step 2):
//! for every bin `l`, `p = p0 + ρ_l t`, the sample position `(fx p_x / p_z + cx, fy p_y / p_z +
//! cy)` when `p_z` is positive and finite, and §2.1's bilinear corners and weights when it lies
//! inside the live image. Three implementations with the same f64 operations (products and sums
//! unfused), so they list the same taps bit for bit: a portable one, an AVX-512 one (8 bins per
//! step) and an AVX2 one (4 bins per step), chosen at run time like the cost kernels.

use super::kernel::{LossKernels, Tap};
use crate::geometry::Warp;
use crate::image::sample::axis;

/// The fixed geometry of one reference pixel and one live frame.
#[derive(Clone, Copy, Debug)]
pub(super) struct PixelRay {
    /// `R K_r⁻¹ u̇`.
    pub p0: [f64; 3],
    /// `t` of `T_lr`.
    pub t: [f64; 3],
    /// The live camera's `fx, fy, cx, cy`.
    pub k: [f64; 4],
    /// Live map width and height.
    pub size: (usize, usize),
    /// Channels (the taps' column offsets are `x * C`).
    pub c: usize,
}

impl PixelRay {
    /// The ray of reference pixel `(x, y)` under `warp`, into a live map of `wl x hl`.
    pub fn new(warp: &Warp, x: usize, y: usize, wl: usize, hl: usize, c: usize) -> Self {
        let t = warp.translation();
        let cam = warp.target();
        PixelRay {
            p0: super::ray_point(warp, x, y),
            t: [t.x, t.y, t.z],
            k: [cam.fx, cam.fy, cam.cx, cam.cy],
            size: (wl, hl),
            c,
        }
    }
}

/// Lists into `taps` (cleared first) the in-image hypotheses among `rhos`, in bin order.
/// The AVX-512 build lists 8 bins per step, the AVX2 one 4, the portable one the rest.
pub(super) fn hypothesis_taps(kernels: LossKernels, ray: &PixelRay, rhos: &[f64], taps: &mut Vec<Tap>) {
    taps.clear();
    #[cfg(target_arch = "x86_64")]
    if ray.size.0 >= 2 && ray.size.1 >= 2 {
        // SAFETY (both): the caller checked the CPU feature (`kernel::loss_kernels`).
        let done = match kernels {
            LossKernels::Avx512 => unsafe { avx512::taps(ray, rhos, taps) },
            LossKernels::Avx2 => unsafe { avx2::taps(ray, rhos, taps) },
            LossKernels::Portable => 0,
        };
        portable(ray, rhos, done, taps);
        return;
    }
    let _ = kernels;
    portable(ray, rhos, 0, taps);
}

/// The portable taps of bins `from..`.
fn portable(ray: &PixelRay, rhos: &[f64], from: usize, taps: &mut Vec<Tap>) {
    let ([x0, y0, z0], [tx, ty, tz], [fx, fy, cx, cy]) = (ray.p0, ray.t, ray.k);
    let (wl, hl) = ray.size;
    for (l, &rho) in rhos.iter().enumerate().skip(from) {
        let px = x0 + rho * tx;
        let py = y0 + rho * ty;
        let pz = z0 + rho * tz;
        if !(pz > 0.0 && pz.is_finite()) {
            continue;
        }
        let (u, v) = (fx * px / pz + cx, fy * py / pz + cy);
        let (Some((xa, xb, a)), Some((ya, yb, b))) = (axis(u, wl), axis(v, hl)) else { continue };
        let wt = [(1.0 - a) * (1.0 - b), a * (1.0 - b), (1.0 - a) * b, a * b];
        taps.push(Tap {
            bin: l as u32,
            y: [ya as u32, yb as u32],
            xc: [xa * ray.c, xb * ray.c],
            w: wt.map(|v| v as f32),
        });
    }
}

#[cfg(target_arch = "x86_64")]
mod avx512 {
    use super::{PixelRay, Tap};
    use std::arch::x86_64::*;

    /// Bins per step.
    const STEP: usize = 8;

    /// AVX-512 taps of bins `0..n` with `n` the largest multiple of 8 in `rhos.len()`; returns `n`.
    /// Needs a live map of at least 2 x 2 (`axis`'s `n == 1` case is the portable one's).
    #[target_feature(enable = "avx512f")]
    pub(super) unsafe fn taps(ray: &PixelRay, rhos: &[f64], taps: &mut Vec<Tap>) -> usize {
        let (wl, hl) = ray.size;
        debug_assert!(wl >= 2 && hl >= 2);
        let s = _mm512_set1_pd;
        let ([x0, y0, z0], [tx, ty, tz], [fx, fy, cx, cy]) = (ray.p0, ray.t, ray.k);
        let (x0, y0, z0, tx, ty, tz) = (s(x0), s(y0), s(z0), s(tx), s(ty), s(tz));
        let (fx, fy, cx, cy) = (s(fx), s(fy), s(cx), s(cy));
        let (zero, one, inf) = (s(0.0), s(1.0), s(f64::INFINITY));
        let (wmax, hmax) = (s((wl - 1) as f64), s((hl - 1) as f64));
        let (wlast, hlast) = (s((wl - 2) as f64), s((hl - 2) as f64));
        let n = rhos.len() / STEP * STEP;
        let mut xs = [0i32; STEP];
        let mut ys = [0i32; STEP];
        let mut w = [[0.0f32; STEP]; 4];
        for base in (0..n).step_by(STEP) {
            // SAFETY: base + 8 <= rhos.len(); the stores write fixed 8-lane arrays.
            unsafe {
                let rho = _mm512_loadu_pd(rhos.as_ptr().add(base));
                let px = _mm512_add_pd(x0, _mm512_mul_pd(rho, tx));
                let py = _mm512_add_pd(y0, _mm512_mul_pd(rho, ty));
                let pz = _mm512_add_pd(z0, _mm512_mul_pd(rho, tz));
                // p_z > 0 and finite (both false for NaN).
                let front =
                    _mm512_cmp_pd_mask::<_CMP_GT_OQ>(pz, zero) & _mm512_cmp_pd_mask::<_CMP_LT_OQ>(pz, inf);
                let u = _mm512_add_pd(_mm512_div_pd(_mm512_mul_pd(fx, px), pz), cx);
                let v = _mm512_add_pd(_mm512_div_pd(_mm512_mul_pd(fy, py), pz), cy);
                // axis(): 0 <= x <= n - 1 (false for NaN), x0 = min(trunc x, n - 2), a = x - x0.
                let inside = _mm512_cmp_pd_mask::<_CMP_GE_OQ>(u, zero)
                    & _mm512_cmp_pd_mask::<_CMP_LE_OQ>(u, wmax)
                    & _mm512_cmp_pd_mask::<_CMP_GE_OQ>(v, zero)
                    & _mm512_cmp_pd_mask::<_CMP_LE_OQ>(v, hmax);
                let mut mask = front & inside;
                if mask == 0 {
                    continue;
                }
                const TRUNC: i32 = _MM_FROUND_TO_ZERO | _MM_FROUND_NO_EXC;
                let xf = _mm512_min_pd(_mm512_roundscale_pd::<TRUNC>(u), wlast);
                let yf = _mm512_min_pd(_mm512_roundscale_pd::<TRUNC>(v), hlast);
                let a = _mm512_sub_pd(u, xf);
                let b = _mm512_sub_pd(v, yf);
                let (na, nb) = (_mm512_sub_pd(one, a), _mm512_sub_pd(one, b));
                let wt =
                    [_mm512_mul_pd(na, nb), _mm512_mul_pd(a, nb), _mm512_mul_pd(na, b), _mm512_mul_pd(a, b)];
                for (dst, src) in w.iter_mut().zip(wt) {
                    _mm256_storeu_ps(dst.as_mut_ptr(), _mm512_cvtpd_ps(src));
                }
                // Lanes outside the mask may hold any integer; they are not read.
                _mm256_storeu_si256(xs.as_mut_ptr().cast(), _mm512_cvttpd_epi32(xf));
                _mm256_storeu_si256(ys.as_mut_ptr().cast(), _mm512_cvttpd_epi32(yf));
                while mask != 0 {
                    let i = mask.trailing_zeros() as usize;
                    mask &= mask - 1;
                    let (xa, ya) = (xs[i] as usize, ys[i] as u32);
                    taps.push(Tap {
                        bin: (base + i) as u32,
                        y: [ya, ya + 1],
                        xc: [xa * ray.c, (xa + 1) * ray.c],
                        w: [w[0][i], w[1][i], w[2][i], w[3][i]],
                    });
                }
            }
        }
        n
    }
}

#[cfg(target_arch = "x86_64")]
mod avx2 {
    use super::{PixelRay, Tap};
    use std::arch::x86_64::*;

    /// Bins per step.
    const STEP: usize = 4;

    /// AVX2 taps of bins `0..n` with `n` the largest multiple of 4 in `rhos.len()`; returns `n`.
    /// The AVX-512 build's operations, 4 lanes wide. Needs a live map of at least 2 x 2.
    #[target_feature(enable = "avx2")]
    pub(super) unsafe fn taps(ray: &PixelRay, rhos: &[f64], taps: &mut Vec<Tap>) -> usize {
        let (wl, hl) = ray.size;
        debug_assert!(wl >= 2 && hl >= 2);
        let s = _mm256_set1_pd;
        let ([x0, y0, z0], [tx, ty, tz], [fx, fy, cx, cy]) = (ray.p0, ray.t, ray.k);
        let (x0, y0, z0, tx, ty, tz) = (s(x0), s(y0), s(z0), s(tx), s(ty), s(tz));
        let (fx, fy, cx, cy) = (s(fx), s(fy), s(cx), s(cy));
        let (zero, one, inf) = (s(0.0), s(1.0), s(f64::INFINITY));
        let (wmax, hmax) = (s((wl - 1) as f64), s((hl - 1) as f64));
        let (wlast, hlast) = (s((wl - 2) as f64), s((hl - 2) as f64));
        let n = rhos.len() / STEP * STEP;
        let mut xs = [0i32; STEP];
        let mut ys = [0i32; STEP];
        let mut w = [[0.0f32; STEP]; 4];
        for base in (0..n).step_by(STEP) {
            // SAFETY: base + 4 <= rhos.len(); the stores write fixed 4-lane arrays.
            unsafe {
                let rho = _mm256_loadu_pd(rhos.as_ptr().add(base));
                let px = _mm256_add_pd(x0, _mm256_mul_pd(rho, tx));
                let py = _mm256_add_pd(y0, _mm256_mul_pd(rho, ty));
                let pz = _mm256_add_pd(z0, _mm256_mul_pd(rho, tz));
                let u = _mm256_add_pd(_mm256_div_pd(_mm256_mul_pd(fx, px), pz), cx);
                let v = _mm256_add_pd(_mm256_div_pd(_mm256_mul_pd(fy, py), pz), cy);
                // p_z > 0 and finite, 0 <= u <= w - 1, 0 <= v <= h - 1 (all false for NaN).
                let ok = [
                    _mm256_cmp_pd::<_CMP_GT_OQ>(pz, zero),
                    _mm256_cmp_pd::<_CMP_LT_OQ>(pz, inf),
                    _mm256_cmp_pd::<_CMP_GE_OQ>(u, zero),
                    _mm256_cmp_pd::<_CMP_LE_OQ>(u, wmax),
                    _mm256_cmp_pd::<_CMP_GE_OQ>(v, zero),
                    _mm256_cmp_pd::<_CMP_LE_OQ>(v, hmax),
                ]
                .into_iter()
                .reduce(|a, b| _mm256_and_pd(a, b))
                .unwrap_or(zero);
                let mut mask = _mm256_movemask_pd(ok) as u32;
                if mask == 0 {
                    continue;
                }
                const TRUNC: i32 = _MM_FROUND_TO_ZERO | _MM_FROUND_NO_EXC;
                let xf = _mm256_min_pd(_mm256_round_pd::<TRUNC>(u), wlast);
                let yf = _mm256_min_pd(_mm256_round_pd::<TRUNC>(v), hlast);
                let a = _mm256_sub_pd(u, xf);
                let b = _mm256_sub_pd(v, yf);
                let (na, nb) = (_mm256_sub_pd(one, a), _mm256_sub_pd(one, b));
                let wt =
                    [_mm256_mul_pd(na, nb), _mm256_mul_pd(a, nb), _mm256_mul_pd(na, b), _mm256_mul_pd(a, b)];
                for (dst, src) in w.iter_mut().zip(wt) {
                    _mm_storeu_ps(dst.as_mut_ptr(), _mm256_cvtpd_ps(src));
                }
                // Lanes outside the mask may hold any integer; they are not read.
                _mm_storeu_si128(xs.as_mut_ptr().cast(), _mm256_cvttpd_epi32(xf));
                _mm_storeu_si128(ys.as_mut_ptr().cast(), _mm256_cvttpd_epi32(yf));
                while mask != 0 {
                    let i = mask.trailing_zeros() as usize;
                    mask &= mask - 1;
                    let (xa, ya) = (xs[i] as usize, ys[i] as u32);
                    taps.push(Tap {
                        bin: (base + i) as u32,
                        y: [ya, ya + 1],
                        xc: [xa * ray.c, (xa + 1) * ray.c],
                        w: [w[0][i], w[1][i], w[2][i], w[3][i]],
                    });
                }
            }
        }
        n
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::runtime::CpuFeatureLevel;
    use crate::util::rng::SplitMix64;

    /// The AVX-512 and AVX2 taps (each where the CPU has it) are the portable ones, bit for bit,
    /// including the bins of the tail (K not a multiple of 8), rays that leave the image or pass
    /// behind the camera, and positions on the last row and column.
    #[test]
    fn avx512_and_portable_list_the_same_taps() {
        let mut rng = SplitMix64::new(7);
        let mut u = |a: f64, b: f64| rng.range(a, b);
        let (mut checked, mut listed) = (0, 0);
        for case in 0..400 {
            let (wl, hl) = [(2, 2), (3, 5), (40, 30), (128, 96)][case % 4];
            let ray = PixelRay {
                p0: [u(-1.0, 1.0), u(-1.0, 1.0), u(-0.2, 1.5)],
                t: [u(-0.5, 0.5), u(-0.3, 0.3), u(-0.5, 0.5)],
                k: [
                    u(0.5, 1.5) * wl as f64,
                    u(0.5, 1.5) * wl as f64,
                    (wl as f64 - 1.0) / 2.0,
                    (hl as f64 - 1.0) / 2.0,
                ],
                size: (wl, hl),
                c: 32,
            };
            let k = [61, 64, 256, 7][(case / 4) % 4];
            let rhos: Vec<f64> = (0..k).map(|l| 4.0 * l as f64 / (k - 1).max(1) as f64).collect();
            let mut a = Vec::new();
            let mut b = Vec::new();
            hypothesis_taps(LossKernels::Portable, &ray, &rhos, &mut b);
            for level in [CpuFeatureLevel::Avx2, CpuFeatureLevel::Avx512] {
                let fast = super::super::kernel::loss_kernels(level, 32);
                hypothesis_taps(fast, &ray, &rhos, &mut a);
                assert_eq!(a.len(), b.len(), "case {case}, {fast:?}");
                for (x, y) in a.iter().zip(&b) {
                    assert_eq!((x.bin, x.y, x.xc), (y.bin, y.y, y.xc), "case {case}, {fast:?}");
                    assert_eq!(x.w.map(f32::to_bits), y.w.map(f32::to_bits), "case {case}, {fast:?}");
                    assert!(x.y[1] < hl as u32 && x.xc[1] < wl * 32);
                }
            }
            checked += 1;
            listed += a.len();
        }
        assert_eq!(checked, 400);
        assert!(listed > 2_000, "too few in-image taps exercised: {listed}");
    }
}
