//! The AVX-512F build of the 2x tent downsampling's column loop: the portable body, the same bits.

/// [`super::portable::combine`] compiled for AVX-512F, so the column loop vectorises eight columns per instruction.
///
/// # Safety
/// The CPU must have AVX-512F.
#[target_feature(enable = "avx512f")]
pub(super) unsafe fn combine(even: [&[f64]; 3], odd: [&[f64]; 3], plane: &mut [f32]) {
    super::combine_portable(even, odd, plane);
}
