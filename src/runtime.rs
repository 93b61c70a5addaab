//! What the machine offers and how work is spread over it: the one CPU-feature probe and the one
//! rayon pool builder every kernel and command uses, and the one median.

use crate::error::{Error, Result};

/// Whether the CPU has AVX-512F (always `false` off x86-64). Every kernel with an AVX-512 path
/// asks here (the cost volume, the direct convolution, the training loss).
pub fn has_avx512f() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::arch::is_x86_feature_detected!("avx512f")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// A rayon pool of `threads` threads for a command's `--threads` flag.
///
/// # Errors
/// [`Error::InvalidArgument`] naming `--threads` for 0 or a pool that cannot start.
pub fn thread_pool(threads: usize) -> Result<rayon::ThreadPool> {
    if threads == 0 {
        return Err(Error::invalid_argument("--threads", "0: must be at least 1"));
    }
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .map_err(|e| Error::invalid_argument("--threads", e.to_string()))
}

/// The median (the mean of the two middle values for an even count; NaN for none), reordering `v`.
pub fn median(v: &mut [f64]) -> f64 {
    let n = v.len();
    if n == 0 {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    if n % 2 == 1 {
        v[n / 2]
    } else {
        (v[n / 2 - 1] + v[n / 2]) / 2.0
    }
}

#[cfg(test)]
mod tests {
    #[test]
    fn median_of_odd_even_and_empty() {
        assert_eq!(super::median(&mut [3.0, 1.0, 2.0]), 2.0);
        assert_eq!(super::median(&mut [4.0, 1.0, 3.0, 2.0]), 2.5);
        assert!(super::median(&mut []).is_nan());
    }

    #[test]
    fn zero_threads_names_the_flag() {
        let e = super::thread_pool(0).unwrap_err().to_string();
        assert!(e.contains("--threads"), "{e}");
    }
}
