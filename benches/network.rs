//! Forward pass of the feature network (SPEC.md §8) at 320x240, block-1 stride 1 and 2, with the
//! fast kernels. Throughput is in elements = FLOPs (`FeatureNet::flops`), so criterion's "elem/s"
//! reads as FLOP/s. Names: `fast_featurenet_<w>x<h>_b1s<stride>`. Also the mapper's level-0
//! learned features: the network's level-1 output (32 channels) upsampled 2x to 640x480
//! (`mapping::features::upsample_to` and its per-pixel definition, SPEC.md §11.1).

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use densefeat::backend::CpuBackend;
use densefeat::nn::{FeatureNet, NetworkWeights};
use densefeat::ops::NetworkConfig;
use ndarray::Array3;
use std::hint::black_box;

/// The shapes we run: (width, height).
const SIZES: [(usize, usize); 1] = [(320, 240)];

fn bench_forward(c: &mut Criterion) {
    let mut group = c.benchmark_group("featurenet");
    group.sample_size(20);
    for (w, h) in SIZES {
        for b1_stride in [1, 2] {
            let config = NetworkConfig { b1_stride, input_mean: [128.0; 3], ..NetworkConfig::default() };
            let net =
                FeatureNet::new(NetworkWeights::xavier_uniform(&config, 0).expect("init")).expect("net");
            let image =
                Array3::from_shape_fn((h, w, 3), |(y, x, ch)| ((x * 7 + y * 13 + ch * 61) % 256) as f32);
            group.throughput(Throughput::Elements(net.flops(h, w) as u64));
            group.bench_function(format!("fast_featurenet_{w}x{h}_b1s{b1_stride}"), |bench| {
                bench.iter(|| {
                    black_box(net.forward(black_box(image.view()), &CpuBackend::default()).expect("forward"))
                })
            });
        }
    }
    group.finish();
}

fn bench_upsample(c: &mut Criterion) {
    use densefeat::mapping::features::{upsample_to, upsample_to_reference};
    let mut group = c.benchmark_group("level0_features");
    group.sample_size(20);
    let x = Array3::from_shape_fn((240, 320, 32), |(y, x, ch)| ((x * 7 + y * 13 + ch * 61) % 256) as f32);
    group.throughput(Throughput::Elements((480 * 640 * 32) as u64));
    group.bench_function("upsample_320x240x32_to_640x480", |b| {
        b.iter(|| black_box(upsample_to(black_box(x.view()), 1, 480, 640)))
    });
    group.bench_function("upsample_reference_320x240x32_to_640x480", |b| {
        b.iter(|| black_box(upsample_to_reference(black_box(x.view()), 1, 480, 640)))
    });
    group.finish();
}

criterion_group!(benches, bench_forward, bench_upsample);
criterion_main!(benches);
