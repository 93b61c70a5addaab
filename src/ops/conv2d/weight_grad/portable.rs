//! The portable weight-gradient tap kernel.

use super::{Tap, C_OUT};

/// The portable tap: the chains by `f32::mul_add` (fused on every target).
pub(super) fn tap(t: &Tap<'_>, x_in: &[f32], g: &[f32], out: &mut [f32]) {
    for &(y, iy) in t.ys {
        for x in t.cols.clone() {
            let (xo, go) = t.offsets(y, iy, x);
            let gv = &g[go..go + C_OUT];
            for (c, &xv) in x_in[xo..xo + t.c_in].iter().enumerate() {
                for (acc, &gv) in out[c * C_OUT..(c + 1) * C_OUT].iter_mut().zip(gv) {
                    *acc = xv.mul_add(gv, *acc);
                }
            }
        }
    }
}
