//! The AVX-512 build of the loss kernels (x86-64; callers check `CpuFeatureLevel::avx512f` and
//! `C % 16 == 0`): the portable kernels' operation order, 16 channel lanes per register.

use super::{lane_tree, LiveRows, Tap, LANES};
use std::arch::x86_64::*;

/// AVX-512 [`super::costs`]; `fu.len()` must be a multiple of 16.
#[target_feature(enable = "avx512f")]
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
        let w = tap.w.map(|v| _mm512_set1_ps(v));
        let mut acc = _mm512_setzero_ps();
        for blk in (0..c).step_by(LANES) {
            // SAFETY: every offset + 16 is within its slice (asserted above).
            unsafe {
                let ld = |o: usize| _mm512_loadu_ps(fl.as_ptr().add(o + blk));
                let mut s = _mm512_mul_ps(w[0], ld(base[0]));
                s = _mm512_add_ps(s, _mm512_mul_ps(w[1], ld(base[1])));
                s = _mm512_add_ps(s, _mm512_mul_ps(w[2], ld(base[2])));
                s = _mm512_add_ps(s, _mm512_mul_ps(w[3], ld(base[3])));
                let v = _mm512_sub_ps(_mm512_loadu_ps(fu.as_ptr().add(blk)), s);
                _mm512_storeu_ps(resid.as_mut_ptr().add(j * c + blk), v);
                acc = _mm512_add_ps(acc, _mm512_mul_ps(v, v));
            }
        }
        let mut lanes = [0.0f32; LANES];
        // SAFETY: `lanes` holds 16 f32.
        unsafe { _mm512_storeu_ps(lanes.as_mut_ptr(), acc) };
        energies[j] = lane_tree(lanes);
    }
}

/// AVX-512 [`super::backward`]; `d_u.len()` must be a multiple of 16.
#[target_feature(enable = "avx512f")]
pub(super) unsafe fn backward(
    taps: &[Tap],
    coefs: &[f32],
    resid: &[f32],
    d_u: &mut [f32],
    live: &mut LiveRows,
) {
    let c = d_u.len();
    if c == 2 * LANES {
        // SAFETY: as this function's.
        unsafe { backward_32(taps, coefs, resid, d_u, live) };
        return;
    }
    for (j, tap) in taps.iter().enumerate() {
        let coef = coefs[j];
        if coef == 0.0 {
            continue;
        }
        let r = &resid[j * c..][..c];
        // SAFETY: the caller checked the CPU feature and `C % 16 == 0`.
        unsafe { axpy(coef, r, d_u) };
        for (t, (y, x)) in tap.corners().into_iter().enumerate() {
            let cw = -coef * tap.w[t];
            // SAFETY: as above.
            unsafe { axpy(cw, r, live.at_mut(y, x, c)) };
        }
    }
}

/// [`backward`] for 32 channels (the network's): the same operations in the same order, with
/// `d_u` held in two registers across the taps, and the four corners of a run of consecutive
/// taps in the same bilinear cell (an epipolar line crosses a cell in several bins) held in
/// eight: loaded when the run starts and stored when it ends, before the next cell's corners
/// (which may share two of them) are loaded. Every corner sees the same additions in the same
/// order as one update per tap in memory, so the bits are those of the portable kernel.
#[target_feature(enable = "avx512f")]
unsafe fn backward_32(taps: &[Tap], coefs: &[f32], resid: &[f32], d_u: &mut [f32], live: &mut LiveRows) {
    const C: usize = 2 * LANES;
    assert!(d_u.len() == C && resid.len() >= taps.len() * C && coefs.len() >= taps.len());
    // SAFETY: d_u holds 32 f32.
    let (mut u0, mut u1) =
        unsafe { (_mm512_loadu_ps(d_u.as_ptr()), _mm512_loadu_ps(d_u.as_ptr().add(LANES))) };
    // The open run's cell (rows and column offsets), its corners' tile pointers and values.
    let mut run: Option<([u32; 2], [usize; 2])> = None;
    let mut ptrs = [std::ptr::null_mut::<f32>(); 4];
    let mut acc = [[_mm512_setzero_ps(); 2]; 4];
    for (j, tap) in taps.iter().enumerate() {
        let coef = coefs[j];
        if coef == 0.0 {
            continue;
        }
        // SAFETY: resid holds taps.len() · 32 values.
        let (r0, r1) = unsafe {
            (_mm512_loadu_ps(resid.as_ptr().add(j * C)), _mm512_loadu_ps(resid.as_ptr().add(j * C + LANES)))
        };
        let cv = _mm512_set1_ps(coef);
        u0 = _mm512_add_ps(u0, _mm512_mul_ps(cv, r0));
        u1 = _mm512_add_ps(u1, _mm512_mul_ps(cv, r1));
        let cell = (tap.y, tap.xc);
        if run != Some(cell) {
            if run.take().is_some() {
                // SAFETY: the pointers of the open run, 32 values each (`at_mut`'s slices).
                unsafe { store_corners(&ptrs, &acc) };
            }
            let [k0, k1, k2, k3] = tap.corners();
            // Looking a corner up may allocate another tile, never move this one.
            ptrs = [
                live.at_mut(k0.0, k0.1, C).as_mut_ptr(),
                live.at_mut(k1.0, k1.1, C).as_mut_ptr(),
                live.at_mut(k2.0, k2.1, C).as_mut_ptr(),
                live.at_mut(k3.0, k3.1, C).as_mut_ptr(),
            ];
            if tap.y[0] == tap.y[1] || tap.xc[0] == tap.xc[1] {
                // Corners that share memory (a 1-row or 1-column map): one after another in
                // memory, so each sees the others' writes, as in the portable order.
                for (t, p) in ptrs.into_iter().enumerate() {
                    let cw = _mm512_set1_ps(-coef * tap.w[t]);
                    // SAFETY: 32 values at p.
                    unsafe {
                        _mm512_storeu_ps(p, _mm512_add_ps(_mm512_loadu_ps(p), _mm512_mul_ps(cw, r0)));
                        let p = p.add(LANES);
                        _mm512_storeu_ps(p, _mm512_add_ps(_mm512_loadu_ps(p), _mm512_mul_ps(cw, r1)));
                    }
                }
                continue;
            }
            for t in 0..4 {
                // SAFETY: 32 values at each pointer.
                unsafe {
                    acc[t][0] = _mm512_loadu_ps(ptrs[t]);
                    acc[t][1] = _mm512_loadu_ps(ptrs[t].add(LANES));
                }
            }
            run = Some(cell);
        }
        for (a, &wt) in acc.iter_mut().zip(&tap.w) {
            let cw = _mm512_set1_ps(-coef * wt);
            a[0] = _mm512_add_ps(a[0], _mm512_mul_ps(cw, r0));
            a[1] = _mm512_add_ps(a[1], _mm512_mul_ps(cw, r1));
        }
    }
    if run.is_some() {
        // SAFETY: as above.
        unsafe { store_corners(&ptrs, &acc) };
    }
    // SAFETY: d_u holds 32 f32.
    unsafe {
        _mm512_storeu_ps(d_u.as_mut_ptr(), u0);
        _mm512_storeu_ps(d_u.as_mut_ptr().add(LANES), u1);
    }
}

/// Stores the four corners' registers of a run of [`backward_32`].
///
/// # Safety
/// AVX-512F; each pointer has 32 writable f32.
#[target_feature(enable = "avx512f")]
#[inline]
unsafe fn store_corners(ptrs: &[*mut f32; 4], acc: &[[__m512; 2]; 4]) {
    for t in 0..4 {
        // SAFETY: the caller's contract.
        unsafe {
            _mm512_storeu_ps(ptrs[t], acc[t][0]);
            _mm512_storeu_ps(ptrs[t].add(LANES), acc[t][1]);
        }
    }
}

/// `y += a x` (products and sums unfused); equal lengths, a multiple of 16.
#[target_feature(enable = "avx512f")]
#[inline]
unsafe fn axpy(a: f32, x: &[f32], y: &mut [f32]) {
    assert_eq!(x.len(), y.len());
    let av = _mm512_set1_ps(a);
    for blk in (0..x.len()).step_by(LANES) {
        // SAFETY: blk + 16 <= len, both slices have that length.
        unsafe {
            let p = y.as_mut_ptr().add(blk);
            let v =
                _mm512_add_ps(_mm512_loadu_ps(p), _mm512_mul_ps(av, _mm512_loadu_ps(x.as_ptr().add(blk))));
            _mm512_storeu_ps(p, v);
        }
    }
}
