//! The machine's practical SGEMM peak, the yardstick `densefeat bench forward` reports against.

use std::time::Instant;

use rayon::prelude::*;

/// Rows of `A` (and `C`) per parallel SGEMM task.
pub const GEMM_ROW_BLOCK: usize = 64;

/// Median GFLOP/s of `C = A B` for `n x n` f32 matrices, split over rayon in blocks of
/// [`GEMM_ROW_BLOCK`] rows of `A` (each a `matrixmultiply::sgemm` call), in the current pool.
pub fn gemm_gflops(n: usize, runs: usize) -> f64 {
    let a: Vec<f32> = (0..n * n).map(|i| ((i * 7 % 13) as f32 - 6.0) / 8.0).collect();
    let b: Vec<f32> = (0..n * n).map(|i| ((i * 5 % 11) as f32 - 5.0) / 8.0).collect();
    let mut c = vec![0.0f32; n * n];
    let mut once = || {
        let start = Instant::now();
        c.par_chunks_mut(GEMM_ROW_BLOCK * n).enumerate().for_each(|(blk, c_rows)| {
            let rows = c_rows.len() / n;
            let a_rows = &a[blk * GEMM_ROW_BLOCK * n..][..rows * n];
            // SAFETY: a_rows is rows×n, b is n×n, c_rows is rows×n, all row-major and in bounds;
            // c_rows is a distinct &mut slice.
            unsafe {
                matrixmultiply::sgemm(
                    rows,
                    n,
                    n,
                    1.0,
                    a_rows.as_ptr(),
                    n as isize,
                    1,
                    b.as_ptr(),
                    n as isize,
                    1,
                    0.0,
                    c_rows.as_mut_ptr(),
                    n as isize,
                    1,
                );
            }
        });
        start.elapsed().as_secs_f64()
    };
    once();
    let mut times: Vec<f64> = (0..runs.max(1)).map(|_| once()).collect();
    2.0 * (n as f64).powi(3) / crate::runtime::median(&mut times) / 1e9
}
