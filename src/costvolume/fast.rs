//! The fast kernel.
//!
//! Per reference pixel `u`, `p(ρ) = R K⁻¹ u̇ + ρ t` is affine in `ρ`: `a = R K⁻¹ u̇` is computed
//! once ([`Warp::point`] at `ρ = 0`) and each hypothesis costs three multiply-adds, a projection and
//! a bounds check, with exactly the `f64` expressions of [`Warp::apply_volume`] and `sample_bilinear`, so
//! validity (and hence every count) matches the reference bit for bit. A branch-free loop over the
//! hypotheses fills validity, corner offset and four `f32` bilinear weights (it vectorises, division
//! included); the channel loop then reads the
//! four corner vectors contiguously (channels last), shares the weights across channels, and keeps
//! [`LANES`] independent `f32` partial sums that are folded by a fixed pairwise tree. The lane
//! structure is explicit, so the bits do not depend on which vector width the compiler picks: the
//! AVX-512 build of the same function and the baseline build agree exactly.
//!
//! Rows are processed in parallel (rayon); each row's `W·K` cells belong to one task.

use nalgebra::Vector3;
use rayon::prelude::*;

use crate::geometry::{PinholeCamera, Warp};
use crate::runtime::CpuFeatureLevel;

/// Width of the channel loop's partial sums (one AVX-512 register of `f32`).
const LANES: usize = 16;

/// Cameras and warp of one live frame.
pub(super) struct Geometry<'a> {
    /// The reference camera (the volume's rows and columns).
    pub camera: &'a PinholeCamera,
    /// The live frame's camera (its features' size; projection and bounds).
    pub live: &'a PinholeCamera,
    pub warp: &'a Warp,
    /// `t_nr`.
    pub t: Vector3<f64>,
}

/// Reference and live features, `[H, W, C]` row-major.
pub(super) struct Slices<'a> {
    pub reference: &'a [f32],
    pub live: &'a [f32],
    pub channels: usize,
    /// Per-frame truncation `τ` (SPEC.md §9.13): a frame adds `min(l1, τ)`.
    pub truncation: f32,
}

/// Per-hypothesis scratch of one pixel (length `K` each): validity, the flat offset of the
/// top-left corner's first channel, and the bilinear weights `(1-a)(1-b), a(1-b), (1-a)b, ab`
/// rounded to `f32`. Filled by a branch-free loop over `k` that the compiler vectorises.
#[derive(Clone, Debug, Default)]
struct Scratch {
    ok: Vec<bool>,
    offset: Vec<usize>,
    w: [Vec<f32>; 4],
}

impl Scratch {
    fn new(k: usize) -> Self {
        Self { ok: vec![false; k], offset: vec![0; k], w: std::array::from_fn(|_| vec![0.0; k]) }
    }
}

/// Which kernel [`CostVolumeImpl::Fast`](super::CostVolumeImpl::Fast) runs on this CPU:
/// `"avx512-blocks"` (AVX-512 F/BW/VL/DQ: the 16-hypothesis block kernels for RGB and 16·N
/// channels, the per-hypothesis row kernel otherwise), `"avx512"` (AVX-512F only: the row kernel)
/// or `"portable"`. Maps too large for 32-bit gather offsets fall back to the row kernel.
pub fn fast_kernel_name() -> &'static str {
    fast_kernel_name_at(CpuFeatureLevel::get())
}

/// [`fast_kernel_name`] for a volume handed `level`.
pub fn fast_kernel_name_at(level: CpuFeatureLevel) -> &'static str {
    #[cfg(target_arch = "x86_64")]
    if level.avx512_bw_vl_dq() {
        return "avx512-blocks";
    }
    if level.avx512f() {
        "avx512"
    } else {
        "portable"
    }
}

/// Add one live frame into `sums` / `counts` (`[H, W, K]`), with the SIMD builds `level` allows.
pub(super) fn add_frame(
    geo: &Geometry,
    feats: &Slices,
    rhos: &[f64],
    sums: &mut [f32],
    counts: &mut [u16],
    level: CpuFeatureLevel,
) {
    let (w, k_count) = (geo.camera.width, rhos.len());
    let row_cells = w * k_count;
    let use_avx512 = level.avx512f();
    #[cfg(target_arch = "x86_64")]
    let use_blocks = level.avx512_bw_vl_dq()
        && super::fast_avx512::fits_i32(w, geo.camera.height, feats.channels)
        && super::fast_avx512::fits_i32(geo.live.width, geo.live.height, feats.channels);
    // The block kernel loads whole 64-byte channel chunks of 16·N-channel maps: from a
    // cache-line-aligned copy no load straddles two lines (a copy changes no value).
    #[cfg(target_arch = "x86_64")]
    let aligned;
    #[cfg(target_arch = "x86_64")]
    let feats = if use_blocks
        && feats.channels.is_multiple_of(16)
        && !(feats.live.as_ptr() as usize).is_multiple_of(64)
    {
        aligned = super::fast_avx512::AlignedCopy::new(feats.live);
        &Slices {
            reference: feats.reference,
            live: aligned.as_slice(),
            channels: feats.channels,
            truncation: feats.truncation,
        }
    } else {
        feats
    };
    // Byte-valued RGB (every value an integer 0..=255, as decoded images are): one packed word per
    // pixel, so the block kernel gathers 4 words per hypothesis instead of 12 floats (same values).
    #[cfg(target_arch = "x86_64")]
    let packed = if use_blocks {
        super::fast_avx512::PackedRgb::new(feats.live, feats.channels, geo.live.width)
    } else {
        None
    };
    sums.par_chunks_mut(row_cells).zip(counts.par_chunks_mut(row_cells)).enumerate().for_each_init(
        || Scratch::new(k_count),
        |scratch, (y, (sum_row, count_row))| {
            #[cfg(target_arch = "x86_64")]
            if use_blocks {
                // SAFETY: `avx512_bw_vl_dq()` checked the CPU features, `fits_i32` the offsets; `packed`
                // is this frame's live map.
                unsafe { super::fast_avx512::row(geo, feats, packed.as_ref(), rhos, y, sum_row, count_row) };
                return;
            }
            #[cfg(target_arch = "x86_64")]
            if use_avx512 {
                // SAFETY: `avx512f()` reported AVX-512F on this CPU.
                unsafe { row_avx512(geo, feats, rhos, y, sum_row, count_row, scratch) };
                return;
            }
            let _ = use_avx512;
            row_any(geo, feats, rhos, y, sum_row, count_row, scratch);
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
    scratch: &mut Scratch,
) {
    row_any(geo, feats, rhos, y, sum_row, count_row, scratch);
}

/// [`row`] with the channel count as a compile-time constant for the common counts (so the channel
/// loop unrolls completely); the same arithmetic, hence the same bits, as the generic instance.
#[inline(always)]
fn row_any(
    geo: &Geometry,
    feats: &Slices,
    rhos: &[f64],
    y: usize,
    sum_row: &mut [f32],
    count_row: &mut [u16],
    scratch: &mut Scratch,
) {
    match feats.channels {
        1 => row::<1>(geo, feats, rhos, y, sum_row, count_row, scratch),
        3 => row::<3>(geo, feats, rhos, y, sum_row, count_row, scratch),
        16 => row::<16>(geo, feats, rhos, y, sum_row, count_row, scratch),
        32 => row::<32>(geo, feats, rhos, y, sum_row, count_row, scratch),
        64 => row::<64>(geo, feats, rhos, y, sum_row, count_row, scratch),
        _ => row::<0>(geo, feats, rhos, y, sum_row, count_row, scratch),
    }
}

/// One reference row. `CH`: the channel count, or 0 to read it from `feats`.
#[inline(always)]
fn row<const CH: usize>(
    geo: &Geometry,
    feats: &Slices,
    rhos: &[f64],
    y: usize,
    sum_row: &mut [f32],
    count_row: &mut [u16],
    scratch: &mut Scratch,
) {
    // Reference pixels in the reference camera; positions, bounds and offsets in the live one.
    let cam = geo.live;
    debug_assert!(CH == 0 || CH == feats.channels);
    let c = if CH == 0 { feats.channels } else { CH };
    let (w, k_count) = (geo.camera.width, rhos.len());
    let (lw, lh) = (cam.width, cam.height);
    // Bounds and corner clamps of `image::sample`: valid iff 0 <= x <= W-1; x0 = min(floor x, W-2);
    // on a 1-pixel-wide image x0 = 0, a = 0 and the right corner aliases the left one.
    let (x_max, y_max) = ((lw - 1) as f64, (lh - 1) as f64);
    let (x_cap, y_cap) = (lw.saturating_sub(2) as f64, lh.saturating_sub(2) as f64);
    let (dx, dy) = (if lw > 1 { c } else { 0 }, if lh > 1 { lw * c } else { 0 });
    let (fx, fy, cx, cy) = (cam.fx, cam.fy, cam.cx, cam.cy);
    let t = geo.t;
    let Scratch { ok, offset, w: wts } = scratch;
    let [w00, w10, w01, w11] = wts;
    let (ok, offset) = (&mut ok[..k_count], &mut offset[..k_count]);
    let (w00, w10, w01, w11) =
        (&mut w00[..k_count], &mut w10[..k_count], &mut w01[..k_count], &mut w11[..k_count]);
    for x in 0..w {
        // a = R K⁻¹ u̇ (+ 0·t, which leaves every later value's bits unchanged).
        let a = geo.warp.point(x as f64, y as f64, 0.0);
        // Branch-free over k, the same f64 expressions as `Warp::apply_volume` (p = a + ρ t, then
        // one division `1/p_z`) and `image::sample`, so validity matches the reference exactly.
        for k in 0..k_count {
            let rho = rhos[k];
            let (px, py, pz) = (a.x + t.x * rho, a.y + t.y * rho, a.z + t.z * rho);
            let inv = 1.0 / pz;
            let u = fx * px * inv + cx;
            let v = fy * py * inv + cy;
            ok[k] = pz > 0.0 && pz.is_finite() && u >= 0.0 && u <= x_max && v >= 0.0 && v <= y_max;
            let (x0, y0) = (u.floor().min(x_cap), v.floor().min(y_cap));
            let (fa, fb) = (u - x0, v - y0);
            // Saturating casts: garbage (never read) where `ok` is false.
            offset[k] = (y0 as usize * lw + x0 as usize) * c;
            w00[k] = ((1.0 - fa) * (1.0 - fb)) as f32;
            w10[k] = (fa * (1.0 - fb)) as f32;
            w01[k] = ((1.0 - fa) * fb) as f32;
            w11[k] = (fa * fb) as f32;
        }
        if x + PREFETCH_AHEAD < w {
            prefetch_cells(sum_row, count_row, (x + PREFETCH_AHEAD) * k_count, k_count);
        }
        let r = &feats.reference[(y * w + x) * c..(y * w + x + 1) * c];
        let sums = &mut sum_row[x * k_count..(x + 1) * k_count];
        let counts = &mut count_row[x * k_count..(x + 1) * k_count];
        for k in 0..k_count {
            if !ok[k] {
                continue;
            }
            let o = offset[k];
            let wk = [w00[k], w10[k], w01[k], w11[k]];
            let l1 = if CH == 3 {
                l1_rgb(feats.live, o, dx, dy, r, wk)
            } else {
                l1_distance(
                    r,
                    &feats.live[o..o + c],
                    &feats.live[o + dx..o + dx + c],
                    &feats.live[o + dy..o + dy + c],
                    &feats.live[o + dy + dx..o + dy + dx + c],
                    wk,
                )
            };
            sums[k] += l1.min(feats.truncation);
            counts[k] += 1;
        }
    }
}

/// How many pixels ahead [`row`] prefetches the sums and counts (SPEC.md §9.4).
const PREFETCH_AHEAD: usize = 2;

/// Ask for the cache lines of cells `at..at + k` of a row's sums and counts (x86-64: SSE's
/// `prefetcht0`, part of the baseline; elsewhere nothing). A hint: no value changes.
#[inline(always)]
fn prefetch_cells(sum_row: &[f32], count_row: &[u16], at: usize, k: usize) {
    #[cfg(target_arch = "x86_64")]
    {
        use std::arch::x86_64::{_mm_prefetch, _MM_HINT_T0};
        let (sums, counts) = (&sum_row[at..at + k], &count_row[at..at + k]);
        for i in (0..k).step_by(16) {
            // SAFETY: a prefetch never faults; the address is inside `sums`.
            unsafe { _mm_prefetch::<_MM_HINT_T0>(sums[i..].as_ptr().cast()) };
        }
        for i in (0..k).step_by(32) {
            // SAFETY: as above, inside `counts`.
            unsafe { _mm_prefetch::<_MM_HINT_T0>(counts[i..].as_ptr().cast()) };
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = (sum_row, count_row, at, k);
}

/// [`l1_distance`] for three channels, with the same bits: the four corners are read as one
/// 4-float SSE vector each (lane 3, the next pixel's first channel, is ignored), so a hypothesis
/// costs four loads instead of twelve. Per lane `s = ((w0 p00 + w1 p10) + w2 p01) + w3 p11` and
/// `|r - s|` exactly as the scalar loop, then `(|d0| + |d2|) + |d1|`, which is what
/// [`l1_distance`]'s pairwise fold of 16 lanes gives when lanes 3..16 are zero. SSE2 is part of the
/// x86_64 baseline, so the portable and the AVX-512 builds run this same code. Near the end of the
/// buffer (where the fourth lane would read past it) and off x86_64 it is [`l1_distance`] itself.
#[inline(always)]
fn l1_rgb(live: &[f32], o: usize, dx: usize, dy: usize, r: &[f32], w: [f32; 4]) -> f32 {
    #[cfg(target_arch = "x86_64")]
    if o + dy + dx + 4 <= live.len() {
        // SAFETY: the loads read 4 floats at o, o+dx, o+dy and o+dy+dx, all ending at or before
        // o+dy+dx+4 <= live.len(); `r` has 3 elements (checked by the slice pattern below).
        unsafe {
            use std::arch::x86_64::*;
            let [r0, r1, r2] = [r[0], r[1], r[2]];
            let p = live.as_ptr().add(o);
            let a = _mm_loadu_ps(p);
            let b = _mm_loadu_ps(p.add(dx));
            let c = _mm_loadu_ps(p.add(dy));
            let d = _mm_loadu_ps(p.add(dy + dx));
            let s = _mm_add_ps(
                _mm_add_ps(
                    _mm_add_ps(_mm_mul_ps(_mm_set1_ps(w[0]), a), _mm_mul_ps(_mm_set1_ps(w[1]), b)),
                    _mm_mul_ps(_mm_set1_ps(w[2]), c),
                ),
                _mm_mul_ps(_mm_set1_ps(w[3]), d),
            );
            let diff = _mm_sub_ps(_mm_setr_ps(r0, r1, r2, 0.0), s);
            let abs = _mm_and_ps(diff, _mm_castsi128_ps(_mm_set1_epi32(0x7fff_ffff)));
            let d02 = _mm_add_ss(abs, _mm_movehl_ps(abs, abs));
            let d1 = _mm_shuffle_ps::<0b01>(abs, abs);
            return _mm_cvtss_f32(_mm_add_ss(d02, d1));
        }
    }
    let c = 3;
    l1_distance(
        r,
        &live[o..o + c],
        &live[o + dx..o + dx + c],
        &live[o + dy..o + dy + c],
        &live[o + dy + dx..o + dy + dx + c],
        w,
    )
}

/// `Σ_c |r_c - (w0 p00_c + w1 p10_c + w2 p01_c + w3 p11_c)|` in `f32`, with [`LANES`] partial sums
/// (channel `c` goes to lane `c mod LANES`) folded pairwise.
#[inline(always)]
pub(super) fn l1_distance(r: &[f32], p00: &[f32], p10: &[f32], p01: &[f32], p11: &[f32], w: [f32; 4]) -> f32 {
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
    for (l, lane) in acc.iter_mut().enumerate().take(n - full) {
        let j = full + l;
        let s = w[0] * p00[j] + w[1] * p10[j] + w[2] * p01[j] + w[3] * p11[j];
        *lane += (r[j] - s).abs();
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

#[cfg(test)]
pub(super) mod tests {
    use super::{l1_distance, l1_rgb};
    use proptest::prelude::*;

    /// Feature values for the kernels' property tests: ordinary values plus ±0 and any `f32`
    /// (NaN, ±∞, subnormals).
    pub(in crate::costvolume) fn value() -> impl Strategy<Value = f32> {
        prop_oneof![
            8 => -300.0f32..300.0,
            1 => Just(0.0f32),
            1 => Just(-0.0f32),
            1 => prop::num::f32::ANY,
        ]
    }

    proptest! {
        /// The SSE three-channel kernel gives the bits of the generic one, for any corner layout.
        #[test]
        fn l1_rgb_equals_l1_distance(
            live in prop::collection::vec(value(), 24..40),
            r in prop::array::uniform3(value()),
            w in prop::array::uniform4(0.0f32..1.0),
            o in 0usize..6,
            dx in prop::sample::select(vec![0usize, 3]),
            dy in prop::sample::select(vec![0usize, 9, 12]),
        ) {
            prop_assume!(o + dy + dx + 3 <= live.len());
            let c = 3;
            let want = l1_distance(
                &r,
                &live[o..o + c],
                &live[o + dx..o + dx + c],
                &live[o + dy..o + dy + c],
                &live[o + dy + dx..o + dy + dx + c],
                w,
            );
            let got = l1_rgb(&live, o, dx, dy, &r, w);
            prop_assert!(got.to_bits() == want.to_bits() || (got.is_nan() && want.is_nan()), "{got} vs {want}");
        }
    }
}
