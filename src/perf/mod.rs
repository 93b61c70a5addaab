//! Benchmark support shared by `densefeat bench` and `benches/`: deterministic inputs, the SGEMM
//! peak and process CPU time. The CLI only parses flags and prints.

mod cpu_time;
mod gemm;
mod inputs;

pub use cpu_time::process_cpu_seconds;
pub use gemm::{gemm_gflops, GEMM_ROW_BLOCK};
pub use inputs::{bench_inputs, pattern, refine_inputs, tv_inputs, BenchInputs, RefineInputs, TvInputs};
