//! One training step (both forwards with tape, the six scale losses, both backwards) on the
//! synthetic pair of `densefeat bench train`, 256x192, K = 256, on 1 and 2 threads, and the loss of
//! one scale alone (L1, 128x96). `cargo bench -p densefeat-benches --bench train`.

use std::time::Duration;

use criterion::{criterion_group, criterion_main, Criterion};
use densefeat::backend::CpuBackend;
use densefeat::geometry::{InverseDepthBins, Warp};
use densefeat::nn::NetworkConfig;
use densefeat::train::data::{DataConfig, DataSet};
use densefeat::train::loss::{scale_loss, LossConfig};
use densefeat::train::step::{depth_at_level, pair_step, Supervision};
use densefeat::train::trainer::training_init;

fn train(c: &mut Criterion) {
    let data = DataSet::open(DataConfig {
        crop: (256, 192),
        synthetic_scenes: 1,
        synthetic_val_scenes: 0,
        ..DataConfig::default()
    })
    .expect("synthetic data");
    let pair = data.train_pair(0, 1, 0).expect("a pair");
    let config = NetworkConfig { input_mean: [110.0; 3], ..NetworkConfig::default() };
    let weights = training_init(&config, 0).expect("weights");
    let loss =
        LossConfig { bins: InverseDepthBins::new(0.0, 4.0, 256).expect("bins"), ..LossConfig::default() };
    let sup = Supervision::default();
    let (out_r, _) =
        densefeat::train::backprop::forward_with_tape(&weights, pair.ref_rgb.view(), &CpuBackend::default())
            .expect("forward");
    let (out_l, _) =
        densefeat::train::backprop::forward_with_tape(&weights, pair.live_rgb.view(), &CpuBackend::default())
            .expect("forward");
    let warp = Warp::new(&pair.ref_camera.at_level(1), &pair.live_camera.at_level(1), &pair.t_lr);
    let depth = depth_at_level(pair.ref_depth.view(), 1);
    for threads in [1, 2] {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("thread pool");
        c.bench_function(&format!("cpu_train_step_256x192_k256_t{threads}"), |b| {
            b.iter(|| {
                pool.install(|| {
                    let mut g = weights.zeros_like();
                    pair_step(&weights, &pair, &loss, &sup, &CpuBackend::default(), Some((&mut g, 1.0)))
                        .expect("step")
                })
            })
        });
        c.bench_function(&format!("cpu_train_loss_l1_128x96_k256_t{threads}"), |b| {
            b.iter(|| {
                pool.install(|| {
                    scale_loss(&loss, out_r.blocks[0].view(), out_l.blocks[0].view(), depth.view(), &warp)
                        .expect("loss")
                })
            })
        });
    }
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(10).measurement_time(Duration::from_secs(8));
    targets = train
}
criterion_main!(benches);
