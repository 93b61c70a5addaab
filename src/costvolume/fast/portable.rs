//! The portable row kernel of [`CostVolumeImpl::Fast`](crate::costvolume::CostVolumeImpl::Fast):
//! plain Rust written so the channel loop vectorises ([`LANES`] partial sums folded by a fixed
//! tree); the AVX-512 build compiles this same body with the target feature on (`avx512::row_generic`).

use super::{Geometry, Scratch, Slices, LANES};

/// [`row`] with the channel count as a compile-time constant for the common counts (so the channel
/// loop unrolls completely); the same arithmetic, hence the same bits, as the generic instance.
#[inline(always)]
pub(super) fn row_any(
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
pub(in crate::costvolume) mod tests {
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
