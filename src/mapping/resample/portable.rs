//! The portable row kernel of the feature upsampling.

/// One output row of [`super::upsample_to`]: `rows` are the source rows `y0`, `y1`, `b` the row weight.
#[inline(always)]
pub(super) fn upsample_row(
    (r0, r1): (&[f32], &[f32]),
    cols: &[(usize, usize, f64)],
    b: f64,
    c: usize,
    out: &mut [f32],
) {
    for (px, &(x0, x1, a)) in out.chunks_exact_mut(c).zip(cols) {
        let (w00, w10, w01, w11) = ((1.0 - a) * (1.0 - b), a * (1.0 - b), (1.0 - a) * b, a * b);
        let (i00, i10) = (&r0[x0 * c..][..c], &r0[x1 * c..][..c]);
        let (i01, i11) = (&r1[x0 * c..][..c], &r1[x1 * c..][..c]);
        for ch in 0..c {
            let v = w00 * i00[ch] as f64 + w10 * i10[ch] as f64 + w01 * i01[ch] as f64 + w11 * i11[ch] as f64;
            px[ch] = v as f32;
        }
    }
}
