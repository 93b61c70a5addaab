//! The DTAM Huber-TV solver at the mapping size: 320x240, K = 64, on 1 and 2 threads, on the
//! synthetic volume of `densefeat bench tv` (`perf::tv_inputs`). `cargo bench -p densefeat-benches --bench dtam`.
//! One iteration at θ_start (the widest pruned a-search) and its parts (the primal-dual step, the
//! a-search alone, the fused a-search with energy and gap, the reference energy), then a full
//! default solve.

use std::time::Duration;

use criterion::{criterion_group, criterion_main, Criterion};
use densefeat::dtam::{
    edge_weights, exhaustive_search, search_with_energy, solve, total_energy, CostRange, DtamParams,
    DtamProblem, HuberTv,
};
use densefeat::perf::{tv_inputs, TvInputs};
use densefeat::runtime::CpuFeatureLevel;

fn dtam(c: &mut Criterion) {
    let TvInputs { costs, bins, grey, init } = tv_inputs(320, 240, 64).expect("valid bench shape");
    let p = DtamParams::default();
    let g = edge_weights(grey.view(), p.alpha, p.beta);
    let range = CostRange::new(costs.view());
    for threads in [1, 2] {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("thread pool");
        let mut tv = HuberTv::new(init.clone(), g.clone(), p.epsilon);
        let a = init.clone();
        let mut fused_a = init.clone();
        let th = p.theta_start;
        c.bench_function(&format!("cpu_dtam_step_320x240_k64_t{threads}"), |b| {
            b.iter(|| pool.install(|| tv.step(a.view(), th)))
        });
        // One DTAM iteration's primal-dual steps (the mapping default runs 16 per a-search).
        c.bench_function(&format!("cpu_dtam_16_steps_320x240_k64_t{threads}"), |b| {
            b.iter(|| pool.install(|| tv.steps_with(a.view(), th, 16, CpuFeatureLevel::get())))
        });
        c.bench_function(&format!("cpu_dtam_search_320x240_k64_t{threads}"), |b| {
            b.iter(|| {
                pool.install(|| exhaustive_search(costs.view(), &range, &bins, tv.primal(), th, p.lambda))
            })
        });
        c.bench_function(&format!("cpu_dtam_search_energy_320x240_k64_t{threads}"), |b| {
            b.iter(|| {
                pool.install(|| {
                    search_with_energy(
                        costs.view(),
                        &range,
                        &bins,
                        &tv,
                        th,
                        p.lambda,
                        &mut fused_a,
                        CpuFeatureLevel::get(),
                    )
                })
            })
        });
        c.bench_function(&format!("cpu_dtam_energy_320x240_k64_t{threads}"), |b| {
            b.iter(|| pool.install(|| total_energy(&tv, costs.view(), &bins, a.view(), th, p.lambda)))
        });
        c.bench_function(&format!("cpu_dtam_solve_320x240_k64_t{threads}"), |b| {
            b.iter(|| {
                pool.install(|| {
                    solve(&DtamProblem::new(costs.view(), &bins, grey.view(), init.view(), &p))
                        .expect("valid")
                })
            })
        });
    }
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(10).measurement_time(Duration::from_secs(5));
    targets = dtam
}
criterion_main!(benches);
