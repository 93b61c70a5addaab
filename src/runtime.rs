//! What the machine offers and how work is spread over it: the one CPU-feature probe and the one
//! rayon pool builder every kernel and command uses, and the one median.

use crate::error::{Error, Result};

/// Environment variable that, set to any value, makes [`has_avx512f`] answer `false`, so that the
/// AVX2 / portable paths can be run and timed on an AVX-512 machine (SPEC.md §7.7). The same as
/// `DENSEFEAT_CPU_LEVEL=avx2`.
pub const NO_AVX512_ENV: &str = "DENSEFEAT_NO_AVX512";

/// Environment variable capping the [`CpuFeatureLevel`] every kernel uses: `portable`, `avx2` or
/// `avx512` (a level above the CPU's is the CPU's). The binary refuses any other value up front
/// ([`check_cpu_level_env`]).
pub const CPU_LEVEL_ENV: &str = "DENSEFEAT_CPU_LEVEL";

/// The SIMD level the kernels may use (issue 33 item 3; rav1e's `CpuFeatureLevel` is the model):
/// the CPU's, capped by [`CPU_LEVEL_ENV`] and [`NO_AVX512_ENV`], chosen once per process
/// ([`CpuFeatureLevel::get`]). Every kernel with a SIMD path asks [`has_avx512f`] or
/// [`has_avx2_fma`], which read this one value; no other CPU-feature probe exists in the crate (a
/// test scans the source). Levels are ordered: each includes the ones below it.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum CpuFeatureLevel {
    /// Plain Rust (whatever the compiler vectorises for the build's baseline target).
    Portable,
    /// AVX2 and FMA (x86-64).
    Avx2,
    /// AVX-512F, with AVX2 and FMA (x86-64).
    Avx512,
}

impl CpuFeatureLevel {
    /// Every level, lowest first.
    pub const ALL: [CpuFeatureLevel; 3] =
        [CpuFeatureLevel::Portable, CpuFeatureLevel::Avx2, CpuFeatureLevel::Avx512];

    /// The name [`CPU_LEVEL_ENV`] takes.
    pub fn name(self) -> &'static str {
        match self {
            CpuFeatureLevel::Portable => "portable",
            CpuFeatureLevel::Avx2 => "avx2",
            CpuFeatureLevel::Avx512 => "avx512",
        }
    }

    /// The level called `name`, if any.
    pub fn parse(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|l| l.name() == name)
    }

    /// What the CPU offers, ignoring the environment (always [`CpuFeatureLevel::Portable`] off
    /// x86-64).
    pub fn detected() -> Self {
        #[cfg(target_arch = "x86_64")]
        {
            let avx2 =
                std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma");
            if avx2 && std::arch::is_x86_feature_detected!("avx512f") {
                CpuFeatureLevel::Avx512
            } else if avx2 {
                CpuFeatureLevel::Avx2
            } else {
                CpuFeatureLevel::Portable
            }
        }
        #[cfg(not(target_arch = "x86_64"))]
        {
            CpuFeatureLevel::Portable
        }
    }

    /// Whether a kernel handed this level may use AVX-512F: the level includes it and the CPU has
    /// it (so a level above the CPU's never runs an instruction the CPU lacks).
    pub fn avx512f(self) -> bool {
        self >= CpuFeatureLevel::Avx512 && Self::cpu() >= CpuFeatureLevel::Avx512
    }

    /// Whether a kernel handed this level may use AVX2 and FMA (the level includes them and the CPU
    /// has them).
    pub fn avx2_fma(self) -> bool {
        self >= CpuFeatureLevel::Avx2 && Self::cpu() >= CpuFeatureLevel::Avx2
    }

    /// Whether a kernel handed this level may use AVX-512F with its BW, VL and DQ extensions (the
    /// cost volume's block kernel): [`CpuFeatureLevel::avx512f`] and the CPU has the three.
    pub fn avx512_bw_vl_dq(self) -> bool {
        #[cfg(target_arch = "x86_64")]
        {
            static EXT: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
            self.avx512f()
                && *EXT.get_or_init(|| {
                    std::arch::is_x86_feature_detected!("avx512bw")
                        && std::arch::is_x86_feature_detected!("avx512vl")
                        && std::arch::is_x86_feature_detected!("avx512dq")
                })
        }
        #[cfg(not(target_arch = "x86_64"))]
        {
            false
        }
    }

    /// [`CpuFeatureLevel::detected`], probed once.
    fn cpu() -> Self {
        static CPU: std::sync::OnceLock<CpuFeatureLevel> = std::sync::OnceLock::new();
        *CPU.get_or_init(Self::detected)
    }

    /// The level of this process: [`CpuFeatureLevel::detected`] capped by [`CPU_LEVEL_ENV`]
    /// (an unknown value caps nothing; the binary refuses it before any work) and by
    /// [`NO_AVX512_ENV`]. Read once per process.
    pub fn get() -> Self {
        static LEVEL: std::sync::OnceLock<CpuFeatureLevel> = std::sync::OnceLock::new();
        *LEVEL.get_or_init(|| {
            let mut level = Self::cpu();
            if let Some(cap) = std::env::var(CPU_LEVEL_ENV).ok().and_then(|v| Self::parse(&v)) {
                level = level.min(cap);
            }
            if std::env::var_os(NO_AVX512_ENV).is_some() {
                level = level.min(CpuFeatureLevel::Avx2);
            }
            level
        })
    }
}

/// Checks [`CPU_LEVEL_ENV`]: unset or one of `portable`, `avx2`, `avx512`.
///
/// # Errors
/// [`Error::InvalidArgument`] naming the variable and the accepted values.
pub fn check_cpu_level_env() -> Result<()> {
    match std::env::var(CPU_LEVEL_ENV) {
        Err(std::env::VarError::NotPresent) => Ok(()),
        Ok(v) if CpuFeatureLevel::parse(&v).is_some() => Ok(()),
        Ok(v) => {
            Err(Error::invalid_argument(CPU_LEVEL_ENV, format!("{v:?}: expected portable, avx2 or avx512")))
        }
        Err(e) => Err(Error::invalid_argument(CPU_LEVEL_ENV, e.to_string())),
    }
}

/// Whether the kernels may use AVX-512F: [`CpuFeatureLevel::get`] is [`CpuFeatureLevel::Avx512`]
/// (so `false` with [`NO_AVX512_ENV`] set, and always off x86-64). Every kernel with an AVX-512
/// path asks here (the cost volume, the direct convolution and transposed convolution, the training
/// loss and weight gradients, DTAM, the feature upsampling).
pub fn has_avx512f() -> bool {
    CpuFeatureLevel::get().avx512f()
}

/// Whether the kernels may use AVX-512F with its BW, VL and DQ extensions (the cost volume's
/// kernel): [`has_avx512f`] and the CPU has the three (probed once).
pub fn has_avx512_bw_vl_dq() -> bool {
    CpuFeatureLevel::get().avx512_bw_vl_dq()
}

/// Whether the kernels may use AVX2 and FMA: [`CpuFeatureLevel::get`] is at least
/// [`CpuFeatureLevel::Avx2`] (always `false` off x86-64).
pub fn has_avx2_fma() -> bool {
    CpuFeatureLevel::get().avx2_fma()
}

/// `threads`, or every core the process may use when it is 0 (for flags whose help says
/// "0: all cores").
pub fn all_cores_if_zero(threads: usize) -> usize {
    if threads > 0 {
        threads
    } else {
        std::thread::available_parallelism().map_or(1, std::num::NonZero::get)
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

/// Largest block glibc's `malloc` may serve from its heap instead of a fresh `mmap` (its ceiling
/// for `M_MMAP_THRESHOLD` on 64-bit targets).
#[cfg(all(target_os = "linux", target_env = "gnu"))]
const HEAP_BLOCK_MAX_BYTES: libc::c_int = 32 << 20;

/// Free memory glibc keeps at the top of its heap before returning it to the OS.
#[cfg(all(target_os = "linux", target_env = "gnu"))]
const HEAP_KEEP_BYTES: libc::c_int = 1 << 30;

/// Lets glibc's allocator reuse the memory of freed activation maps instead of returning it to the
/// OS (SPEC.md §8.9): blocks up to 32 MB come from the heap (`M_MMAP_THRESHOLD`, fixed at glibc's
/// ceiling instead of its sliding default) and up to 1 GiB of free heap top is kept
/// (`M_TRIM_THRESHOLD`). A forward pass returns fresh maps that the caller drops; without this the
/// next pass gets them back as new pages that the OS zero-fills, one page fault at a time. Peak
/// memory is unchanged; memory freed after the peak stays with the process. Process-wide, so the
/// `densefeat` binary calls it at start; library users may. Returns whether glibc accepted both
/// settings (always `false` off Linux/glibc, where it does nothing).
pub fn keep_freed_memory() -> bool {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    {
        // SAFETY: mallopt only changes allocator parameters; both values are in its documented range.
        unsafe {
            libc::mallopt(libc::M_MMAP_THRESHOLD, HEAP_BLOCK_MAX_BYTES) == 1
                && libc::mallopt(libc::M_TRIM_THRESHOLD, HEAP_KEEP_BYTES) == 1
        }
    }
    #[cfg(not(all(target_os = "linux", target_env = "gnu")))]
    {
        false
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
    fn glibc_accepts_the_allocator_settings() {
        let accepted = super::keep_freed_memory();
        assert_eq!(accepted, cfg!(all(target_os = "linux", target_env = "gnu")));
    }

    #[test]
    fn zero_threads_names_the_flag() {
        let e = super::thread_pool(0).unwrap_err().to_string();
        assert!(e.contains("--threads"), "{e}");
    }
}
