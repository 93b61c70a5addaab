//! The photometric sub-bin refinement (SPEC.md §10.3) of one keyframe at the input resolution,
//! 640x480 with 12 live frames (`map`'s default on a 640x480 sequence), on 1 and 2 threads, on the
//! synthetic plane of `densefeat bench refine` (`perf::refine_inputs`).
//! `cargo bench -p densefeat-benches --bench refine`.

use std::time::Duration;

use criterion::{criterion_group, criterion_main, Criterion};
use densefeat::mapping::refine::{refine_level0, Level0, RefineView, REFINE_DEFAULTS};
use densefeat::perf::{refine_inputs, RefineInputs};

fn refine(c: &mut Criterion) {
    let RefineInputs { camera, key, rho0, greys, poses, step } =
        refine_inputs(640, 480, 12).expect("valid bench shape");
    let views: Vec<RefineView> =
        greys.iter().zip(&poses).map(|(g, p)| RefineView { grey: g.view(), camera, pose: *p }).collect();
    let problem = Level0 { key: key.view(), camera: &camera, rho0: rho0.view(), views: &views, step };
    for threads in [1, 2] {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("thread pool");
        c.bench_function(&format!("cpu_refine_640x480_f12_t{threads}"), |b| {
            b.iter(|| pool.install(|| refine_level0(&problem, &REFINE_DEFAULTS).expect("valid problem")))
        });
    }
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(10).measurement_time(Duration::from_secs(20));
    targets = refine
}
criterion_main!(benches);
