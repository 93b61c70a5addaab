//! The AVX-512F weight-gradient tap kernel: the body in `simd.rs` for this vector type.

tap_kernel!("avx512f", __m512, 16, 8, _mm512_loadu_ps, _mm512_storeu_ps, _mm512_set1_ps, _mm512_fmadd_ps);
