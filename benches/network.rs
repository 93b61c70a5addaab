//! Forward pass of the feature network (SPEC.md §8) at 320x240, block-1 stride 1 and 2, with the
//! fast kernels. Throughput is in elements = FLOPs (`FeatureNet::flops`), so criterion's "elem/s"
//! reads as FLOP/s. Names: `fast_featurenet_<w>x<h>_b1s<stride>`.

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use densefeat::backend::CpuBackend;
use densefeat::nn::{FeatureNet, NetworkConfig, NetworkWeights};
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

criterion_group!(benches, bench_forward);
criterion_main!(benches);
