//! The AVX-512F build of the feature upsampling's row kernel: the portable body, the same bits.

/// [`super::portable::upsample_row`] compiled for AVX-512F.
#[target_feature(enable = "avx512f")]
pub(super) fn upsample_row(
    rows: (&[f32], &[f32]),
    cols: &[(usize, usize, f64)],
    b: f64,
    c: usize,
    out: &mut [f32],
) {
    super::upsample_row_portable(rows, cols, b, c, out);
}
