//! Convolution and transposed-convolution benches over the network's shapes (SPEC.md §7). Names:
//! `<impl>_<op>_<shape>`.
//! Throughput is reported in elements = FLOPs (`2 · 9 c_in · h_out · w_out · c_out`), so criterion's
//! "elem/s" reads as FLOP/s. Threads: rayon's global pool, so `RAYON_NUM_THREADS=1 cargo bench
//! -p densefeat-benches --bench conv` measures one thread. Winograd (stride-1 shapes) multiplies 2.25x (F2) or 4x (F4)
//! less; its "elem/s" uses the same direct count, so it reads as an effective rate. Transposed
//! convolutions (`deconv2d`, with the U-Net sum as the decoder runs them) count `2 · 25 c_in c_out h w`
//! for an `h x w` input.

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use densefeat::ops::conv2d::{
    conv2d_direct, conv2d_im2col, conv2d_winograd, direct, im2col, scratch_len, PackedConv2d, PackedWinograd,
    WinogradKernel, WinogradTile,
};
use densefeat::ops::{
    conv2d, deconv2d_into, Activation, Conv2dGeometry, Conv2dImpl, Deconv2dGeometry, Deconv2dImpl,
};
use densefeat::testing::within_budget;
use densefeat_benches::CONV_SHAPES;
use ndarray::{Array1, Array3, Array4};
use std::hint::black_box;

fn pattern(n: usize, seed: u64) -> impl FnMut() -> f32 {
    let mut s = seed.wrapping_add(n as u64);
    move || {
        s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        ((s >> 40) as f32 / (1u64 << 24) as f32) - 0.5
    }
}

/// Correctness first: Direct and Im2colGemm agree within twice the §7.5 budget (each is within one
/// budget of the reference; Σ|x||w| + |b| comes from Im2colGemm on the absolute values).
fn check_direct_against_im2col(g: &Conv2dGeometry, x: &Array3<f32>, w: &Array4<f32>, b: &Array1<f32>) {
    let run = |imp, x: &Array3<f32>, w: &Array4<f32>, b: &Array1<f32>, act| {
        conv2d(imp, g, x.view(), w.view(), b.view(), act).expect("run")
    };
    let direct = run(Conv2dImpl::Direct, x, w, b, Activation::Relu);
    let gemm = run(Conv2dImpl::Im2colGemm, x, w, b, Activation::Relu);
    let abs = |a: f32| a.abs();
    let magnitude = run(Conv2dImpl::Im2colGemm, &x.mapv(abs), &w.mapv(abs), &b.mapv(abs), Activation::None);
    // 1.01: the magnitude itself is an f32 sum, slightly below Σ|x||w| + |b| at worst.
    let budget = 2.0 * 2.0 * g.k() as f32 * f32::EPSILON * 1.01;
    if let Err(e) = within_budget(direct.view(), gemm.view(), magnitude.view(), budget) {
        panic!("direct disagrees with im2col on {g:?}: {e}");
    }
}

fn bench_conv(c: &mut Criterion) {
    let mut group = c.benchmark_group("conv2d");
    group.sample_size(20);
    for (h, w, c_in, c_out, stride) in CONV_SHAPES {
        let g = Conv2dGeometry::new(h, w, c_in, c_out, stride).expect("valid shape");
        let mut next = pattern(h * w, 1);
        let x = Array3::from_shape_simple_fn(g.input_shape(), &mut next);
        let wt = Array4::from_shape_simple_fn(g.weight_shape(), &mut next);
        let b = Array1::from_shape_simple_fn(c_out, &mut next);
        let packed = PackedConv2d::new(&g, wt.view(), b.view()).expect("packed");
        let lanes = (4 * rayon::current_num_threads()).min(im2col::n_blocks(&g));
        let mut scratch = vec![0.0; lanes * scratch_len(&g)];
        let mut out = vec![0.0; g.output_shape().iter().product()];
        let xs = x.as_slice().expect("contiguous");
        check_direct_against_im2col(&g, &x, &wt, &b);
        group.throughput(Throughput::Elements(g.flops() as u64));
        group.bench_function(format!("im2col_conv2d_{h}x{w}_c{c_in}to{c_out}_s{stride}"), |bench| {
            bench.iter(|| {
                conv2d_im2col(&packed, black_box(xs), Activation::Relu, &mut scratch, &mut out).expect("run");
                black_box(&out);
            })
        });
        let kernel = direct::kernel_name(&g);
        group.bench_function(format!("direct_conv2d_{h}x{w}_c{c_in}to{c_out}_s{stride}_{kernel}"), |bench| {
            bench.iter(|| {
                conv2d_direct(&packed, black_box(xs), Activation::Relu, &mut out).expect("run");
                black_box(&out);
            })
        });
        for tile in [WinogradTile::F2x2, WinogradTile::F4x4].into_iter().filter(|_| stride == 1) {
            let wp = PackedWinograd::new(tile, &g, wt.view(), b.view()).expect("packed");
            let (t, kernel) = (tile.name(), WinogradKernel::select(&g).name());
            group.bench_function(
                format!("winograd_{t}_conv2d_{h}x{w}_c{c_in}to{c_out}_s1_{kernel}"),
                |bench| {
                    bench.iter(|| {
                        conv2d_winograd(&wp, black_box(xs), Activation::Relu, &mut out).expect("run");
                        black_box(&out);
                    })
                },
            );
        }
    }
    group.finish();
}

/// The decoder's largest transposed-convolution inputs: 640x480 and 1280x960 at B1 stride 2 (the
/// latter the 640x480 network at B1 stride 1).
const DECONV_SHAPES: [(usize, usize, usize, usize); 2] = [(120, 160, 32, 32), (240, 320, 32, 32)];

fn bench_deconv(c: &mut Criterion) {
    let mut group = c.benchmark_group("deconv2d");
    group.sample_size(20);
    for (h, w, c_in, c_out) in DECONV_SHAPES {
        let g = Deconv2dGeometry::new(h, w, c_in, c_out).expect("valid shape");
        let mut next = pattern(h * w, 2);
        let x = Array3::from_shape_simple_fn(g.input_shape(), &mut next);
        let wt = Array4::from_shape_simple_fn(g.weight_shape(), &mut next);
        let b = Array1::from_shape_simple_fn(c_out, &mut next);
        let skip: Vec<f32> = (0..g.output_shape().iter().product()).map(|_| next()).collect();
        let mut out = vec![0.0; skip.len()];
        group.throughput(Throughput::Elements((2 * 25 * c_in * c_out * h * w) as u64));
        for imp in [Deconv2dImpl::Direct, Deconv2dImpl::WinogradF2, Deconv2dImpl::WinogradF4] {
            group.bench_function(
                format!("{imp:?}_deconv2d_add_{h}x{w}_c{c_in}to{c_out}").to_lowercase(),
                |bench| {
                    bench.iter(|| {
                        deconv2d_into(
                            imp,
                            &g,
                            black_box(x.view()),
                            wt.view(),
                            b.view(),
                            Some(&skip),
                            &mut out,
                        )
                        .expect("run");
                        black_box(&out);
                    })
                },
            );
        }
    }
    group.finish();
}

criterion_group!(benches, bench_conv, bench_deconv);
criterion_main!(benches);
