//! Interleaved A/B timing of the transposed-convolution implementations (SPEC.md §7.3) on the
//! network's `32 -> 32` shapes, U-Net sum included (`deconv2d_into` with a skip map, as the
//! decoder runs it): each round runs every (shape, implementation) once, in turn, one thread; the
//! report gives the median and best ms and the effective GFLOP/s (`2 · 25 c_in c_out h w / time`,
//! the direct transposed convolution's count, also for Winograd).
//!
//! `cargo run -p densefeat-benches --release --example deconv_speed [rounds]`; set `DECONV_SHAPE=h,w,c_in,c_out` to time
//! another input shape.

use densefeat::ops::{deconv2d_into, Deconv2dGeometry, Deconv2dImpl};
use ndarray::{Array1, Array3, Array4};
use std::time::Instant;

/// Input `(h, w, c_in, c_out)`: the decoder's inputs at 640x480 and 320x240 (B1 stride 2), and a
/// stride-1 network's largest.
const SHAPES: [(usize, usize, usize, usize); 4] =
    [(30, 40, 32, 32), (60, 80, 32, 32), (120, 160, 32, 32), (240, 320, 32, 32)];

const IMPS: [Deconv2dImpl; 3] = [Deconv2dImpl::Direct, Deconv2dImpl::WinogradF2, Deconv2dImpl::WinogradF4];

fn main() {
    let rounds: usize = std::env::args().nth(1).and_then(|a| a.parse().ok()).unwrap_or(5);
    let shapes: Vec<(usize, usize, usize, usize)> = match std::env::var("DECONV_SHAPE") {
        Ok(s) => {
            let v: Vec<usize> =
                s.split(',').map(|p| p.trim().parse().expect("DECONV_SHAPE=h,w,c_in,c_out")).collect();
            assert_eq!(v.len(), 4, "DECONV_SHAPE=h,w,c_in,c_out");
            vec![(v[0], v[1], v[2], v[3])]
        }
        Err(_) => SHAPES.to_vec(),
    };
    let pool = rayon::ThreadPoolBuilder::new().num_threads(1).build().expect("a one-thread pool");
    let mut times = vec![vec![Vec::new(); IMPS.len()]; shapes.len()];
    let cases: Vec<_> = shapes
        .iter()
        .map(|&(h, w, ci, co)| {
            let g = Deconv2dGeometry::new(h, w, ci, co).expect("a valid shape");
            let mut s = 1u32;
            let mut next = move || {
                s = s.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
                (s >> 8) as f32 / (1u32 << 24) as f32 - 0.5
            };
            let x = Array3::from_shape_simple_fn(g.input_shape(), &mut next);
            let wt = Array4::from_shape_simple_fn(g.weight_shape(), &mut next);
            let b = Array1::from_shape_simple_fn(co, &mut next);
            let skip = Array3::from_shape_simple_fn(g.output_shape(), &mut next);
            (g, x, wt, b, skip)
        })
        .collect();
    for _ in 0..rounds {
        for (si, (g, x, wt, b, skip)) in cases.iter().enumerate() {
            let mut out = vec![0.0f32; g.output_shape().iter().product()];
            for (ii, &imp) in IMPS.iter().enumerate() {
                let run = |out: &mut [f32]| {
                    pool.install(|| {
                        deconv2d_into(imp, g, x.view(), wt.view(), b.view(), skip.as_slice(), out)
                            .expect("valid shapes")
                    })
                };
                run(&mut out); // warm-up: packing, caches
                let reps = (2_000_000 / (g.h() * g.w())).clamp(1, 50);
                let t0 = Instant::now();
                for _ in 0..reps {
                    run(&mut out);
                }
                times[si][ii].push(t0.elapsed().as_secs_f64() * 1e3 / reps as f64);
            }
        }
    }
    println!(
        "| input h x w | c_in -> c_out | implementation | median ms | best ms | effective GFLOP/s (median) |"
    );
    println!("|---|---|---|---|---|---|");
    for (si, &(h, w, ci, co)) in shapes.iter().enumerate() {
        for (ii, imp) in IMPS.iter().enumerate() {
            let mut t = times[si][ii].clone();
            t.sort_by(f64::total_cmp);
            let (med, best) = (t[t.len() / 2], t[0]);
            let gflop = 2.0 * 25.0 * (ci * co * h * w) as f64 / 1e9;
            println!(
                "| {h}x{w} | {ci} -> {co} | {imp:?} | {med:.3} | {best:.3} | {:.1} |",
                gflop / (med / 1e3)
            );
        }
    }
}
