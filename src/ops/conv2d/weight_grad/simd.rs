//! The one body of the SIMD weight-gradient kernels (`avx2.rs`, `avx512.rs` instantiate it).

/// Generates `tap` for one vector type: input channels in blocks of `$cb` (the last block
/// shorter), the block's `$cb x 32` accumulators in registers across the tap's pixels.
macro_rules! tap_kernel {
    ($feat:literal, $v:ty, $lanes:expr, $cb:expr, $load:path, $store:path, $set1:path, $fma:path) => {
        use super::{Tap, C_OUT};
        use std::arch::x86_64::*;

        const NV: usize = C_OUT / $lanes;

        /// # Safety
        /// The CPU has `$feat`; every offset of `t` plus its run is inside `x_in` and `g`,
        /// `out` holds `c_in · 32` values.
        #[target_feature(enable = $feat)]
        pub(super) unsafe fn tap(t: &Tap<'_>, x_in: &[f32], g: &[f32], out: &mut [f32]) {
            let mut c0 = 0;
            while c0 < t.c_in {
                let n = (t.c_in - c0).min($cb);
                // SAFETY: as this function's.
                unsafe { block(t, x_in, g, &mut out[c0 * C_OUT..(c0 + n) * C_OUT], c0, n) };
                c0 += n;
            }
        }

        /// Channels `c0..c0 + n` (`n <= $cb`).
        #[target_feature(enable = $feat)]
        unsafe fn block(t: &Tap<'_>, x_in: &[f32], g: &[f32], out: &mut [f32], c0: usize, n: usize) {
            // Every chain starts from 0 (`out` was zeroed, so this is its value).
            // SAFETY: an all-zero vector register is 0.0 in every lane.
            let mut acc: [[$v; NV]; $cb] = [[unsafe { std::mem::zeroed() }; NV]; $cb];
            for &(y, iy) in t.ys {
                for x in t.cols.clone() {
                    let (xo, go) = t.offsets(y, iy, x);
                    // SAFETY: the caller bounds every offset plus its run (chunk's asserts).
                    unsafe {
                        let gp = g.as_ptr().add(go);
                        let gv: [$v; NV] = std::array::from_fn(|j| $load(gp.add(j * $lanes)));
                        let xp = x_in.as_ptr().add(xo + c0);
                        for (i, a) in acc.iter_mut().enumerate().take(n) {
                            let xb = $set1(*xp.add(i));
                            for j in 0..NV {
                                a[j] = $fma(xb, gv[j], a[j]);
                            }
                        }
                    }
                }
            }
            for (i, a) in acc.iter().enumerate().take(n) {
                for (j, v) in a.iter().enumerate() {
                    // SAFETY: as above.
                    unsafe { $store(out.as_mut_ptr().add(i * C_OUT + j * $lanes), *v) };
                }
            }
        }
    };
}
