//! The AVX2+FMA weight-gradient tap kernel: the body in `simd.rs` for this vector type.

tap_kernel!("avx2,fma", __m256, 8, 2, _mm256_loadu_ps, _mm256_storeu_ps, _mm256_set1_ps, _mm256_fmadd_ps);
