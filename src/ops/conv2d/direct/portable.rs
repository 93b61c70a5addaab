//! The portable kernel of [`DirectKernel::Portable`](super::DirectKernel::Portable): one output
//! pixel at a time, any `c_out`, every target (no fused multiply-add), the order of SPEC.md §7.7.

use super::{tap_range, Activation, PackedConv2d, CONV_KERNEL, CONV_PADDING};

/// One output row with the portable kernel; `input` holds the image's rows from `row0` on.
pub(super) fn conv_row(
    packed: &PackedConv2d,
    input: &[f32],
    row0: usize,
    y: usize,
    activation: Activation,
    out_row: &mut [f32],
) {
    let geom = packed.geometry();
    let (h, w, c_in, c_out, s) = (geom.h(), geom.w(), geom.c_in(), geom.c_out(), geom.stride());
    let (ky_lo, ky_hi) = tap_range(y, s, h);
    let weights = packed.weights();
    for (x, acc) in out_row.chunks_exact_mut(c_out).enumerate() {
        let (kx_lo, kx_hi) = tap_range(x, s, w);
        let run = (kx_hi - kx_lo) * c_in;
        acc.copy_from_slice(packed.bias());
        for ky in ky_lo..ky_hi {
            let at = ((s * y + ky - CONV_PADDING - row0) * w + s * x + kx_lo - CONV_PADDING) * c_in;
            let taps = &input[at..at + run];
            let w_at = (ky * CONV_KERNEL + kx_lo) * c_in * c_out;
            for (&v, w_row) in taps.iter().zip(weights[w_at..w_at + run * c_out].chunks_exact(c_out)) {
                for (a, &wv) in acc.iter_mut().zip(w_row) {
                    *a += v * wv;
                }
            }
        }
        if activation != Activation::None {
            for a in acc.iter_mut() {
                *a = activation.apply_f32(*a);
            }
        }
    }
}
