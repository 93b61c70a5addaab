//! Adding one live frame to a cost volume at the size the paper's mapping runs: 320x240, K = 64
//! hypotheses, C = 32 learned channels (and RGB), on 1 and 2 threads. `cargo bench -p densefeat-benches --bench costvolume`.
//! The same inputs as `densefeat bench costvolume` (`perf::bench_inputs`). `_portable_` entries run
//! `CostVolumeImpl::FastPortable` (the same bits without the AVX-512 block kernel) on one thread.

use criterion::{criterion_group, criterion_main, Criterion};
use densefeat::costvolume::{fast_kernel_name, CostVolume, CostVolumeImpl};
use densefeat::perf::{bench_inputs, BenchInputs};

fn add_frame(c: &mut Criterion) {
    for channels in [32, 3] {
        let BenchInputs { reference, live, camera, bins, t_nr } =
            bench_inputs(320, 240, channels, 64).expect("valid bench shape");
        for threads in [1, 2] {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("thread pool");
            let mut cv = CostVolume::new(reference.clone(), camera, bins).expect("shapes match");
            let name = format!("cpu_costvolume_{}_320x240_k64_c{channels}_t{threads}", fast_kernel_name());
            c.bench_function(&name, |b| {
                b.iter(|| pool.install(|| cv.add_frame(live.view(), &t_nr).expect("shapes match")))
            });
        }
        let pool = rayon::ThreadPoolBuilder::new().num_threads(1).build().expect("thread pool");
        let mut cv = CostVolume::with_impl(reference.clone(), camera, bins, CostVolumeImpl::FastPortable)
            .expect("shapes match");
        let name = format!("cpu_costvolume_portable_320x240_k64_c{channels}_t1");
        c.bench_function(&name, |b| {
            b.iter(|| pool.install(|| cv.add_frame(live.view(), &t_nr).expect("shapes match")))
        });
    }
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(20);
    targets = add_frame
}
criterion_main!(benches);
