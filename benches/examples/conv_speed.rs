//! Interleaved A/B timing of the conv2d implementations on the network's shapes, for a shared,
//! noisy machine: each round runs every (shape, implementation, thread count) once, in turn, and
//! the report gives the median and best GFLOP/s (`2 · 9 c_in · h_out · w_out · c_out / time`; for
//! Winograd, which multiplies 2.25x (F2) or 4x (F4) less, this is the direct convolution's count: an
//! effective rate).
//! On Linux it also gives GFLOP per on-CPU second of the pool's threads (from
//! `/proc/thread-self/schedstat`, summed over the threads): time the threads spent descheduled by
//! other load does not count, so this column approximates the kernel's speed per core when it runs.
//! It is only indicative: rayon's brief spinning counts as CPU time, and on this VM the accounting
//! ran about 25% below wall time for the FMA peak loop even when idle. The peak loop is printed
//! before and after, to tell the host's fast and slow clock states apart.
//!
//! `cargo run -p densefeat-benches --release --example conv_speed [rounds] [shape filter, e.g. 640]`; set
//! `CONV_SHAPE=h,w,c_in,c_out,stride` to time another shape.

use densefeat::ops::conv2d::{
    conv2d_direct, conv2d_direct_with, conv2d_im2col, conv2d_winograd, direct, im2col, scratch_len,
    DirectKernel, PackedConv2d, PackedWinograd, WinogradKernel, WinogradTile,
};
use densefeat::ops::{Activation, Conv2dGeometry};
use densefeat_benches::CONV_SHAPES;
use ndarray::{Array1, Array3, Array4};
use std::time::Instant;

/// Nanoseconds the calling thread has run on a CPU (Linux), or 0 where unknown.
fn thread_cpu_ns() -> u64 {
    std::fs::read_to_string("/proc/thread-self/schedstat")
        .ok()
        .and_then(|s| s.split_whitespace().next().and_then(|v| v.parse().ok()))
        .unwrap_or(0)
}

/// On-CPU nanoseconds of all of a pool's threads.
fn pool_cpu_ns(pool: &rayon::ThreadPool) -> u64 {
    pool.broadcast(|_| thread_cpu_ns()).iter().sum()
}

/// Steps of [`fma_peak`], each 28 accumulators x 16 lanes x 2 FLOP.
const PEAK_STEPS: usize = 4_000_000;

/// A register-only loop of independent zmm FMAs: the per-core peak the conv kernel is judged
/// against, measured in the same process (the host changes clock speed for minutes at a time).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
fn fma_peak(seed: f32) -> f32 {
    use std::arch::x86_64::{_mm512_fmadd_ps, _mm512_reduce_add_ps, _mm512_set1_ps};
    let (a, b) = (_mm512_set1_ps(0.999_999), _mm512_set1_ps(seed));
    let mut acc = [_mm512_set1_ps(seed); 28];
    for _ in 0..PEAK_STEPS {
        for v in acc.iter_mut() {
            *v = _mm512_fmadd_ps(*v, a, b);
        }
    }
    acc.iter().map(|&v| _mm512_reduce_add_ps(v)).sum()
}

/// GFLOP/s of [`fma_peak`] on one thread, best of three, per wall second and per on-CPU second
/// (zeros without AVX-512F).
fn peak_gflops() -> (f64, f64) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx512f") {
        let flops = (PEAK_STEPS * 28 * 16 * 2) as f64;
        let (mut wall, mut cpu) = (0.0f64, 0.0f64);
        for _ in 0..3 {
            let c0 = thread_cpu_ns();
            let t0 = Instant::now();
            // SAFETY: AVX-512F was detected above.
            std::hint::black_box(unsafe { fma_peak(std::hint::black_box(1.0)) });
            let ns = (thread_cpu_ns() - c0).max(1) as f64;
            wall = wall.max(flops / t0.elapsed().as_nanos().max(1) as f64);
            cpu = cpu.max(flops / ns);
        }
        return (wall, cpu);
    }
    (0.0, 0.0)
}

fn main() {
    let rounds: usize = std::env::args().nth(1).and_then(|a| a.parse().ok()).unwrap_or(15);
    let filter = std::env::args().nth(2).unwrap_or_default();
    let pools: Vec<_> = [1, 2]
        .iter()
        .map(|&n| rayon::ThreadPoolBuilder::new().num_threads(n).build().expect("pool"))
        .collect();
    let (wall, cpu) = peak_gflops();
    println!("zmm FMA peak, one thread, before: {wall:.0} GFLOP/s, {cpu:.0} GFLOP per CPU-s");
    println!(
        "| shape | impl | threads | median GFLOP/s | best GFLOP/s | median ms | GFLOP per CPU-s per thread |"
    );
    println!("|---|---|---|---|---|---|---|");
    // CONV_SHAPE=h,w,c_in,c_out,stride times that shape instead of the network's.
    let custom: Option<Vec<usize>> = std::env::var("CONV_SHAPE").ok().map(|v| {
        v.split(',').map(|t| t.trim().parse().expect("CONV_SHAPE: h,w,c_in,c_out,stride")).collect()
    });
    let shapes = match custom.as_deref() {
        Some(&[h, w, c_in, c_out, s]) => vec![(h, w, c_in, c_out, s)],
        Some(_) => panic!("CONV_SHAPE: h,w,c_in,c_out,stride"),
        None => CONV_SHAPES.to_vec(),
    };
    for (h, w, c_in, c_out, stride) in shapes {
        let g = Conv2dGeometry::new(h, w, c_in, c_out, stride).expect("shape");
        if !format!("{h}x{w} {c_in}->{c_out} s{stride}").contains(&filter) {
            continue;
        }
        let mut s = 1u64;
        let mut next = || {
            s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            ((s >> 40) as f32 / (1u64 << 24) as f32) - 0.5
        };
        let x = Array3::from_shape_simple_fn(g.input_shape(), &mut next);
        let wt = Array4::from_shape_simple_fn(g.weight_shape(), &mut next);
        let b = Array1::from_shape_simple_fn(c_out, &mut next);
        let packed = PackedConv2d::new(&g, wt.view(), b.view()).expect("pack");
        let xs = x.as_slice().expect("contiguous");
        let mut out = vec![0.0f32; g.output_shape().iter().product()];
        let mut scratch = vec![0.0f32; 8 * scratch_len(&g)];
        let lanes = 8.min(im2col::n_blocks(&g));
        let pack = |t| PackedWinograd::new(t, &g, wt.view(), b.view()).expect("pack");
        let winograd = (stride == 1).then(|| [pack(WinogradTile::F2x2), pack(WinogradTile::F4x4)]);
        let mut names = vec![
            "im2col".to_string(),
            format!("direct ({})", direct::kernel_name(&g)),
            "direct (portable)".into(),
        ];
        if winograd.is_some() {
            names.push(format!("winograd f2x2 ({})", WinogradKernel::select(&g).name()));
            names.push(format!("winograd f4x4 ({})", WinogradKernel::select(&g).name()));
        }
        // times[impl][pool]
        let mut times = vec![vec![Vec::new(); pools.len()]; names.len()];
        let mut cpu = vec![vec![0u64; pools.len()]; names.len()];
        for _ in 0..rounds {
            for (p, pool) in pools.iter().enumerate() {
                for (i, ti) in times.iter_mut().enumerate() {
                    let c0 = pool_cpu_ns(pool);
                    let t0 = Instant::now();
                    pool.install(|| {
                        if i == 0 {
                            let scr = &mut scratch[..lanes * scratch_len(&g)];
                            conv2d_im2col(&packed, xs, Activation::Relu, scr, &mut out).expect("run");
                        } else if i == 1 {
                            conv2d_direct(&packed, xs, Activation::Relu, &mut out).expect("run");
                        } else if i >= 3 {
                            let wp = &winograd.as_ref().expect("stride 1")[i - 3];
                            conv2d_winograd(wp, xs, Activation::Relu, &mut out).expect("run");
                        } else {
                            let portable = DirectKernel::Portable;
                            conv2d_direct_with(portable, &packed, xs, Activation::Relu, &mut out)
                                .expect("run");
                        }
                    });
                    ti[p].push(t0.elapsed().as_secs_f64());
                    cpu[i][p] += pool_cpu_ns(pool) - c0;
                    std::hint::black_box(&out);
                }
            }
        }
        for (i, ti) in times.iter_mut().enumerate() {
            for (p, t) in ti.iter_mut().enumerate() {
                t.sort_by(f64::total_cmp);
                let (med, best) = (t[t.len() / 2], t[0]);
                let per_cpu_s = g.flops() * rounds as f64 / (cpu[i][p] as f64 * 1e-9) * 1e-9;
                println!(
                    "| {h}x{w} {c_in}->{c_out} s{stride} | {} | {} | {:.0} | {:.0} | {:.2} | {:.0} |",
                    names[i],
                    p + 1,
                    g.flops() / med * 1e-9,
                    g.flops() / best * 1e-9,
                    med * 1e3,
                    per_cpu_s
                );
            }
        }
    }
    let (wall, cpu) = peak_gflops();
    println!("zmm FMA peak, one thread, after: {wall:.0} GFLOP/s, {cpu:.0} GFLOP per CPU-s");
}
