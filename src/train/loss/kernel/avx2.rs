//! The AVX2 build of the loss kernels (x86-64; callers check `CpuFeatureLevel::avx2_fma` and
//! `C % 16 == 0`): the portable kernels' operation order, each 16-channel lane group held in two
//! 8-lane registers (lanes 0-7 and 8-15), so the lane tree and every sum see the same values.
//! For CPUs without AVX-512 (SPEC.md §13.1's kernels; the same bits as the other two builds).

use super::{lane_tree, LiveRows, Tap, LANES};
use std::arch::x86_64::*;

/// Lanes of one AVX2 register of f32.
const HALF: usize = LANES / 2;

/// AVX2 [`super::costs`]; `fu.len()` must be a multiple of 16.
#[target_feature(enable = "avx2")]
pub(super) unsafe fn costs(
    fu: &[f32],
    fl: &[f32],
    row: usize,
    taps: &[Tap],
    resid: &mut [f32],
    energies: &mut [f32],
) {
    let c = fu.len();
    debug_assert_eq!(c % LANES, 0);
    assert!(resid.len() >= taps.len() * c && energies.len() >= taps.len());
    for (j, tap) in taps.iter().enumerate() {
        let base = tap.corners().map(|(y, x)| y * row + x);
        assert!(base.iter().all(|&b| b + c <= fl.len()));
        let w = tap.w.map(|v| _mm256_set1_ps(v));
        // acc[0]: lanes 0-7 (channels ≡ 0-7 mod 16), acc[1]: lanes 8-15.
        let mut acc = [_mm256_setzero_ps(); 2];
        for blk in (0..c).step_by(HALF) {
            let a = &mut acc[(blk / HALF) % 2];
            // SAFETY: every offset + 8 is within its slice (asserted above; blk + 8 <= c).
            unsafe {
                let ld = |o: usize| _mm256_loadu_ps(fl.as_ptr().add(o + blk));
                let mut s = _mm256_mul_ps(w[0], ld(base[0]));
                s = _mm256_add_ps(s, _mm256_mul_ps(w[1], ld(base[1])));
                s = _mm256_add_ps(s, _mm256_mul_ps(w[2], ld(base[2])));
                s = _mm256_add_ps(s, _mm256_mul_ps(w[3], ld(base[3])));
                let v = _mm256_sub_ps(_mm256_loadu_ps(fu.as_ptr().add(blk)), s);
                _mm256_storeu_ps(resid.as_mut_ptr().add(j * c + blk), v);
                *a = _mm256_add_ps(*a, _mm256_mul_ps(v, v));
            }
        }
        let mut lanes = [0.0f32; LANES];
        // SAFETY: `lanes` holds 16 f32.
        unsafe {
            _mm256_storeu_ps(lanes.as_mut_ptr(), acc[0]);
            _mm256_storeu_ps(lanes.as_mut_ptr().add(HALF), acc[1]);
        }
        energies[j] = lane_tree(lanes);
    }
}

/// AVX2 [`super::backward`]: the 32-channel kernel below for the network's maps; other multiples
/// of 16 take the portable kernel (the same bits).
#[target_feature(enable = "avx2")]
pub(super) unsafe fn backward(
    taps: &[Tap],
    coefs: &[f32],
    resid: &[f32],
    d_u: &mut [f32],
    live: &mut LiveRows,
) {
    if d_u.len() == 2 * LANES {
        // SAFETY: as this function's.
        unsafe { backward_32(taps, coefs, resid, d_u, live) };
    } else {
        super::portable::backward(taps, coefs, resid, d_u, live);
    }
}

/// [`backward`] for 32 channels (the network's): the same operations in the same order, with
/// `d_u` and the tap's residual held in four registers each, and the corners' tile pointers
/// looked up once per run of consecutive taps in the same bilinear cell (an epipolar line crosses
/// a cell in several bins). The corners are updated in memory one after another, in the portable
/// order, so corners that share memory (a 1-row or 1-column map) see each other's writes.
#[target_feature(enable = "avx2")]
unsafe fn backward_32(taps: &[Tap], coefs: &[f32], resid: &[f32], d_u: &mut [f32], live: &mut LiveRows) {
    const C: usize = 2 * LANES;
    const R: usize = C / HALF;
    assert!(d_u.len() == C && resid.len() >= taps.len() * C && coefs.len() >= taps.len());
    let mut u = [_mm256_setzero_ps(); R];
    for (i, ui) in u.iter_mut().enumerate() {
        // SAFETY: d_u holds 32 f32.
        *ui = unsafe { _mm256_loadu_ps(d_u.as_ptr().add(i * HALF)) };
    }
    let mut run: Option<([u32; 2], [usize; 2])> = None;
    let mut ptrs = [std::ptr::null_mut::<f32>(); 4];
    for (j, tap) in taps.iter().enumerate() {
        let coef = coefs[j];
        if coef == 0.0 {
            continue;
        }
        let mut r = [_mm256_setzero_ps(); R];
        for (i, ri) in r.iter_mut().enumerate() {
            // SAFETY: resid holds taps.len() · 32 values.
            *ri = unsafe { _mm256_loadu_ps(resid.as_ptr().add(j * C + i * HALF)) };
        }
        let cv = _mm256_set1_ps(coef);
        for (ui, &ri) in u.iter_mut().zip(&r) {
            *ui = _mm256_add_ps(*ui, _mm256_mul_ps(cv, ri));
        }
        let cell = (tap.y, tap.xc);
        if run != Some(cell) {
            // Looking a corner up may allocate another tile, never move one already handed out.
            let [k0, k1, k2, k3] = tap.corners();
            ptrs = [
                live.at_mut(k0.0, k0.1, C).as_mut_ptr(),
                live.at_mut(k1.0, k1.1, C).as_mut_ptr(),
                live.at_mut(k2.0, k2.1, C).as_mut_ptr(),
                live.at_mut(k3.0, k3.1, C).as_mut_ptr(),
            ];
            run = Some(cell);
        }
        for (t, &p) in ptrs.iter().enumerate() {
            let cw = _mm256_set1_ps(-coef * tap.w[t]);
            for (i, &ri) in r.iter().enumerate() {
                // SAFETY: 32 writable values at each corner pointer (`at_mut`'s slices).
                unsafe {
                    let q = p.add(i * HALF);
                    _mm256_storeu_ps(q, _mm256_add_ps(_mm256_loadu_ps(q), _mm256_mul_ps(cw, ri)));
                }
            }
        }
    }
    for (i, &ui) in u.iter().enumerate() {
        // SAFETY: d_u holds 32 f32.
        unsafe { _mm256_storeu_ps(d_u.as_mut_ptr().add(i * HALF), ui) };
    }
}
