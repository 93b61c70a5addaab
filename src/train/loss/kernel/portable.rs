//! The portable loss kernels: the definition's operation order (16 channel lanes, products and sums
//! unfused, [`super::lane_tree`]), plain Rust for every target. `avx512.rs` gives the same bits.

use super::{lane_tree, LiveRows, Tap, LANES};

/// [`super::costs`], portable.
pub(super) fn costs(
    fu: &[f32],
    fl: &[f32],
    row: usize,
    taps: &[Tap],
    resid: &mut [f32],
    energies: &mut [f32],
) {
    let c = fu.len();
    for (j, tap) in taps.iter().enumerate() {
        let base = tap.corners().map(|(y, x)| y * row + x);
        let r = &mut resid[j * c..][..c];
        let mut acc = [0.0f32; LANES];
        for ch in 0..c {
            let s = tap.w[0] * fl[base[0] + ch]
                + tap.w[1] * fl[base[1] + ch]
                + tap.w[2] * fl[base[2] + ch]
                + tap.w[3] * fl[base[3] + ch];
            let v = fu[ch] - s;
            r[ch] = v;
            acc[ch % LANES] += v * v;
        }
        energies[j] = lane_tree(acc);
    }
}

/// [`super::backward`], portable.
pub(super) fn backward(taps: &[Tap], coefs: &[f32], resid: &[f32], d_u: &mut [f32], live: &mut LiveRows) {
    let c = d_u.len();
    for (j, tap) in taps.iter().enumerate() {
        let coef = coefs[j];
        if coef == 0.0 {
            continue;
        }
        let r = &resid[j * c..][..c];
        for (dv, &rv) in d_u.iter_mut().zip(r) {
            *dv += coef * rv;
        }
        for (t, (y, x)) in tap.corners().into_iter().enumerate() {
            let cw = -coef * tap.w[t];
            for (dv, &rv) in live.at_mut(y, x, c).iter_mut().zip(r) {
                *dv += cw * rv;
            }
        }
    }
}
