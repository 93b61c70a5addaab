//! DTAM Huber-TV invariants (SPEC.md §10): pruned search = full search, the primal-dual gap shrinks
//! and the dual stays feasible, the a-search finds the discrete minimiser, constant inputs are fixed
//! points, thread-count determinism, the fused solver equals the unfused reference bit for bit, and
//! planes rendered by the synthetic renderer are recovered.

use densefeat::costvolume::{CostVolume, UNSEEN_COST};
use densefeat::dtam::search::exhaustive_search_full;
use densefeat::dtam::{
    edge_weights, exhaustive_search, exhaustive_search_reference, exhaustive_search_with, rms_gap,
    search_with_energy, solve, solve_reference, solve_with, total_energy, CostRange, DtamParams, DtamProblem,
    HuberTv,
};
use densefeat::geometry::{relative_pose, InverseDepthBins, PinholeCamera};
use densefeat::image::to_gray;
use densefeat::runtime::CpuFeatureLevel;
use densefeat::synth::Quad;
use nalgebra::Vector3;
use ndarray::{Array2, Array3, ArrayView2};
use proptest::prelude::*;

use crate::common::dtam_cases::{fingerprint, stream, with_threads};

fn random_volume(h: usize, w: usize, k: usize, seed: u64, unseen: f64) -> Array3<f32> {
    let mut r = stream(seed);
    Array3::from_shape_fn((h, w, k), |_| if r() < unseen { UNSEEN_COST } else { (r() * 50.0) as f32 })
}

proptest! {
    #[test]
    fn pruned_search_equals_full_search(h in 1usize..6, w in 1usize..6, k in 2usize..40, seed: u64,
                                        unseen in prop_oneof![Just(0.0), Just(0.3), Just(1.0)],
                                        theta in 1e-5..0.5f64, lambda in 0.1..1000.0f64) {
        let costs = random_volume(h, w, k, seed, unseen);
        let bins = InverseDepthBins::new(0.1, 2.0, k).unwrap();
        let mut r = stream(seed.wrapping_add(1));
        let d = Array2::from_shape_fn((h, w), |_| (r() * 2.4 - 0.2) as f32);
        let range = CostRange::new(costs.view());
        let pruned = exhaustive_search(costs.view(), &range, &bins, d.view(), theta, lambda);
        let full = exhaustive_search_full(costs.view(), &bins, d.view(), theta, lambda);
        prop_assert_eq!(pruned.mapv(f32::to_bits), full.mapv(f32::to_bits));
        let portable = exhaustive_search_with(costs.view(), &range, &bins, d.view(), theta, lambda, CpuFeatureLevel::Portable);
        prop_assert_eq!(portable.mapv(f32::to_bits), full.mapv(f32::to_bits));
        let scalar = exhaustive_search_reference(costs.view(), &range, &bins, d.view(), theta, lambda);
        prop_assert_eq!(scalar.mapv(f32::to_bits), full.mapv(f32::to_bits));
    }

    #[test]
    fn search_ties_resolve_as_the_definition(h in 1usize..5, w in 1usize..20, k in 2usize..40, seed: u64,
                                             levels in 1u32..4, ulps: bool,
                                             theta in prop_oneof![Just(1e-6), Just(0.01), Just(10.0)]) {
        // Integer costs (or 10 plus a few ulps) and `d` on hypotheses or midway between them: many
        // exactly equal, or nearly equal, energies.
        let mut r = stream(seed);
        let costs = Array3::from_shape_fn((h, w, k), |_| {
            let n = (r() * f64::from(levels)).floor() as u32;
            let v = if ulps { f32::from_bits(10f32.to_bits() + n) } else { n as f32 };
            if r() < 0.1 { UNSEEN_COST } else { v }
        });
        let bins = InverseDepthBins::new(0.1, 2.0, k).unwrap();
        let d = Array2::from_shape_fn((h, w), |_| {
            let b = (r() * (k - 1) as f64 * 2.0).floor() / 2.0;
            (bins.rho_min + b * bins.step()) as f32
        });
        let range = CostRange::new(costs.view());
        let full = exhaustive_search_full(costs.view(), &bins, d.view(), theta, 1.0);
        for dispatch in [CpuFeatureLevel::get(), CpuFeatureLevel::Avx2, CpuFeatureLevel::Portable] {
            let got = exhaustive_search_with(costs.view(), &range, &bins, d.view(), theta, 1.0, dispatch);
            prop_assert_eq!(got.mapv(f32::to_bits), full.mapv(f32::to_bits), "{:?}", dispatch);
        }
    }

    #[test]
    fn fused_solve_equals_the_reference_bit_for_bit(h in 1usize..14, w in 1usize..14, k in 2usize..40,
                                                    seed: u64, unseen in prop_oneof![Just(0.0), Just(0.3), Just(1.0)],
                                                    odd in prop_oneof![Just(0.0), Just(0.05)],
                                                    theta_start in 1e-4..2.0f64, lambda in 0.1..1000.0f64,
                                                    steps in 1usize..4) {
        let costs = odd_volume(h, w, k, seed, unseen, odd);
        let bins = InverseDepthBins::new(0.1, 2.0, k).unwrap();
        let mut r = stream(seed.wrapping_add(2));
        let grey = Array2::from_shape_fn((h, w), |_| (r() * 255.0) as f32);
        let init = Array2::from_shape_fn((h, w), |_| (r() * 2.4 - 0.2) as f32);
        let params = DtamParams {
            lambda, theta_start, theta_end: theta_start * 1e-4, iterations: 12, max_iterations: 20,
            steps_per_search: steps, ..DtamParams::default()
        };
        let problem = DtamProblem::new(costs.view(), &bins, grey.view(), init.view(), &params);
        let reference = fingerprint(solve_reference(&problem).unwrap());
        for dispatch in [CpuFeatureLevel::get(), CpuFeatureLevel::Avx2, CpuFeatureLevel::Portable] {
            let got = solve_with(&problem, dispatch).unwrap();
            prop_assert_eq!(&fingerprint(got), &reference, "{:?}", dispatch);
        }
    }

    #[test]
    fn search_finds_the_discrete_minimiser(k in 3usize..40, seed: u64, theta in 1e-4..0.5f64, lambda in 1.0..1000.0f64) {
        let costs = random_volume(1, 1, k, seed, 0.0);
        let bins = InverseDepthBins::new(0.1, 2.0, k).unwrap();
        let d0 = stream(seed ^ 7)() * 1.9 + 0.1;
        let d = Array2::from_elem((1, 1), d0 as f32);
        let a = exhaustive_search(costs.view(), &CostRange::new(costs.view()), &bins, d.view(), theta, lambda)[[0, 0]];
        let e = |k: usize| {
            let diff = d0 as f32 as f64 - bins.rho(k);
            diff * diff / (2.0 * theta) + costs[[0, 0, k]] as f64 / lambda
        };
        let best = (0..k).map(e).fold(f64::INFINITY, f64::min);
        // Refinement moves at most half a bin from the winning hypothesis.
        let b = bins.bin_of(a as f64);
        let bracket = e((b.floor() as usize).min(k - 1)).min(e((b.ceil() as usize).min(k - 1)));
        prop_assert_eq!(bracket, best, "a = {} (bin {})", a, b);
    }
}

/// Cost curves with one clear valley each (plus noise, quantised to `levels` values when given, so
/// equal costs and energies are common), a fraction `unseen` of cells unseen and `odd` of them NaN,
/// -0.0, -∞ or +∞: the wide ranges where the a-search runs its block bounds (SPEC.md §10.1).
fn valley_volume(h: usize, w: usize, k: usize, seed: u64, unseen: f64, odd: f64, levels: u32) -> Array3<f32> {
    let mut r = stream(seed ^ 0x5EED);
    let mut costs = Array3::zeros((h, w, k));
    for mut curve in costs.lanes_mut(ndarray::Axis(2)) {
        let (centre, width, depth) = (r() * k as f64, 1.0 + r() * k as f64 / 4.0, r() * 40.0);
        for (i, c) in curve.iter_mut().enumerate() {
            let x = (i as f64 - centre) / width;
            let v = 50.0 - depth * (-x * x).exp() + r() * 10.0;
            let v = if levels > 0 { (v / 60.0 * f64::from(levels)).floor() } else { v };
            *c = if r() < unseen {
                UNSEEN_COST
            } else if r() < odd {
                [f32::NAN, -0.0, f32::NEG_INFINITY, f32::INFINITY][(r() * 4.0) as usize % 4]
            } else {
                v as f32
            };
        }
    }
    costs
}

proptest! {
    #[test]
    fn bounded_search_equals_the_definition(h in 1usize..4, w in 1usize..20, k in 40usize..300, seed: u64,
                                              unseen in prop_oneof![Just(0.0), Just(0.3), Just(0.97)],
                                              odd in prop_oneof![Just(0.0), Just(0.0), Just(0.002)],
                                              levels in prop_oneof![Just(0u32), Just(3), Just(40)],
                                              theta in prop_oneof![1e-3..0.05f64, 0.05..50.0f64],
                                              lambda in 0.1..1000.0f64) {
        let costs = valley_volume(h, w, k, seed, unseen, odd, levels);
        let bins = InverseDepthBins::new(0.1, 2.0, k).unwrap();
        let mut r = stream(seed.wrapping_add(3));
        let d = Array2::from_shape_fn((h, w), |_| (r() * 2.4 - 0.2) as f32);
        let range = CostRange::new(costs.view());
        // The scalar definition (pruned: with a NaN in the pruned range it can differ from the
        // unpruned scan, which starts elsewhere); without odd values both are the same.
        let definition = exhaustive_search_reference(costs.view(), &range, &bins, d.view(), theta, lambda);
        if odd == 0.0 {
            let full = exhaustive_search_full(costs.view(), &bins, d.view(), theta, lambda);
            prop_assert_eq!(definition.mapv(f32::to_bits), full.mapv(f32::to_bits));
        }
        for dispatch in [CpuFeatureLevel::get(), CpuFeatureLevel::Avx2, CpuFeatureLevel::Portable] {
            let got = exhaustive_search_with(costs.view(), &range, &bins, d.view(), theta, lambda, dispatch);
            prop_assert_eq!(got.mapv(f32::to_bits), definition.mapv(f32::to_bits), "{:?}", dispatch);
        }
    }

    #[test]
    fn fused_solve_with_wide_ranges_equals_the_reference(h in 1usize..8, w in 1usize..20, k in 40usize..200,
                                                         seed: u64, odd in prop_oneof![Just(0.0), Just(0.01)],
                                                         theta_start in 0.5..20.0f64, lambda in 0.1..100.0f64) {
        let costs = valley_volume(h, w, k, seed, 0.2, odd, 0);
        let bins = InverseDepthBins::new(0.1, 2.0, k).unwrap();
        let mut r = stream(seed.wrapping_add(4));
        let grey = Array2::from_shape_fn((h, w), |_| (r() * 255.0) as f32);
        let init = Array2::from_shape_fn((h, w), |_| (r() * 2.4 - 0.2) as f32);
        let params = DtamParams {
            lambda, theta_start, theta_end: theta_start * 1e-4, iterations: 8, max_iterations: 10,
            ..DtamParams::default()
        };
        let problem = DtamProblem::new(costs.view(), &bins, grey.view(), init.view(), &params);
        let reference = fingerprint(solve_reference(&problem).unwrap());
        for dispatch in [CpuFeatureLevel::get(), CpuFeatureLevel::Avx2, CpuFeatureLevel::Portable] {
            let got = solve_with(&problem, dispatch).unwrap();
            prop_assert_eq!(&fingerprint(got), &reference, "{:?}", dispatch);
        }
    }
}

/// [`random_volume`] with a fraction `odd` of cells replaced by NaN, -0.0, -∞ or +∞ (unseen).
fn odd_volume(h: usize, w: usize, k: usize, seed: u64, unseen: f64, odd: f64) -> Array3<f32> {
    let mut costs = random_volume(h, w, k, seed, unseen);
    let mut r = stream(seed ^ 0xABCD);
    for c in costs.iter_mut() {
        if r() < odd {
            *c = [f32::NAN, -0.0, f32::NEG_INFINITY, f32::INFINITY][(r() * 4.0) as usize % 4];
        }
    }
    costs
}

#[test]
fn fused_solve_equals_the_reference_on_every_thread_count() {
    // A bench-like volume (smooth valleys, an unseen band) and a random one with odd values, with
    // the normalised mapping schedule's wide first searches (K = 96: wider than the lane scan's 48
    // hypotheses, so the block-bounded search runs too) and the raw defaults.
    let (h, w, k) = (37, 53, 96);
    let bench = densefeat::perf::tv_inputs(w, h, k).unwrap();
    let odd = odd_volume(h, w, k, 21, 0.2, 0.02);
    let mut r = stream(22);
    let grey = Array2::from_shape_fn((h, w), |_| (r() * 255.0) as f32);
    let init = Array2::from_shape_fn((h, w), |_| (0.1 + 2.3 * r()) as f32);
    let raw = DtamParams { iterations: 30, max_iterations: 60, ..DtamParams::default() };
    let range = bench.bins.rho_max - bench.bins.rho_min;
    let mapping = DtamParams { iterations: 30, max_iterations: 60, ..densefeat::dtam::MAPPING_DEFAULTS }
        .normalised(10.0, w, range);
    let cases = [
        (&bench.costs, &bench.bins, &bench.grey, &bench.init, raw),
        (&bench.costs, &bench.bins, &bench.grey, &bench.init, mapping),
        (&odd, &bench.bins, &grey, &init, raw),
        (&odd, &bench.bins, &grey, &init, mapping),
    ];
    for (i, (costs, bins, grey, init, params)) in cases.into_iter().enumerate() {
        let problem = DtamProblem::new(costs.view(), bins, grey.view(), init.view(), &params);
        let reference = rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build()
            .unwrap()
            .install(|| fingerprint(solve_reference(&problem).unwrap()));
        for n in [1, 2, 3, 8] {
            for dispatch in [CpuFeatureLevel::get(), CpuFeatureLevel::Avx2, CpuFeatureLevel::Portable] {
                let got = rayon::ThreadPoolBuilder::new()
                    .num_threads(n)
                    .build()
                    .unwrap()
                    .install(|| solve_with(&problem, dispatch).unwrap());
                assert!(fingerprint(got) == reference, "case {i}, {n} threads, {dispatch:?}");
            }
        }
    }
}

#[test]
fn fused_pass_equals_the_reference_functions() {
    let (h, w, k) = (19, 23, 32);
    let bins = InverseDepthBins::new(0.1, 2.0, k).unwrap();
    for (seed, unseen, odd) in [(31, 0.0, 0.0), (32, 0.3, 0.0), (33, 0.1, 0.05), (34, 1.0, 0.0)] {
        let costs = odd_volume(h, w, k, seed, unseen, odd);
        let range = CostRange::new(costs.view());
        let mut r = stream(seed + 100);
        let grey = Array2::from_shape_fn((h, w), |_| (r() * 255.0) as f32);
        let init = Array2::from_shape_fn((h, w), |_| (0.1 + 1.9 * r()) as f32);
        let mut tv = HuberTv::new(init.clone(), edge_weights(grey.view(), 10.0, 1.0), 1e-3);
        let mut a = init.clone();
        for (n, theta) in [0.5, 0.05, 1e-3, 1e-5].into_iter().enumerate() {
            tv.step(a.view(), theta);
            let lambda = 30.0 * (n + 1) as f64;
            let reference =
                exhaustive_search_reference(costs.view(), &range, &bins, tv.primal(), theta, lambda);
            let e = total_energy(&tv, costs.view(), &bins, reference.view(), theta, lambda);
            let g = rms_gap(tv.primal(), reference.view());
            for dispatch in [CpuFeatureLevel::get(), CpuFeatureLevel::Avx2, CpuFeatureLevel::Portable] {
                let m = search_with_energy(costs.view(), &range, &bins, &tv, theta, lambda, &mut a, dispatch);
                assert_eq!(a.mapv(f32::to_bits), reference.mapv(f32::to_bits), "seed {seed}, θ {theta}");
                assert_eq!(m.energy.to_bits(), e.to_bits(), "seed {seed}, θ {theta}: {} vs {e}", m.energy);
                assert_eq!(m.gap.to_bits(), g.to_bits(), "seed {seed}, θ {theta}");
            }
        }
    }
}

/// Both fast builds' primal `d` and primal-dual gap (hence `q`) equal the reference's bit for bit.
fn assert_builds_match(
    reference: &HuberTv,
    builds: [&HuberTv; 2],
    a: ArrayView2<f32>,
    theta: f64,
    what: &str,
) {
    let bits = |tv: &HuberTv| tv.primal().mapv(f32::to_bits);
    for (tv, name) in builds.into_iter().zip(["auto", "portable"]) {
        assert_eq!(bits(tv), bits(reference), "{what}, {name}");
        assert_eq!(tv.gap(a, theta), reference.gap(a, theta), "{what}, {name}: dual differs");
    }
}

#[test]
fn step_equals_the_reference_step() {
    for (h, w) in [(1, 1), (1, 7), (6, 1), (2, 2), (17, 29)] {
        let mut r = stream((h * 100 + w) as u64);
        let init = Array2::from_shape_fn((h, w), |_| (0.1 + 1.9 * r()) as f32);
        let a = Array2::from_shape_fn((h, w), |_| (0.1 + 1.9 * r()) as f32);
        let grey = Array2::from_shape_fn((h, w), |_| (r() * 255.0) as f32);
        let g = edge_weights(grey.view(), 10.0, 1.0);
        let mut reference = HuberTv::new(init.clone(), g.clone(), 1e-3);
        let mut auto = reference.clone();
        let mut portable = reference.clone();
        for n in 0..50 {
            let theta = 0.5 * 0.8f64.powi(n);
            reference.step_reference(a.view(), theta);
            auto.step_with(a.view(), theta, CpuFeatureLevel::get());
            portable.step_with(a.view(), theta, CpuFeatureLevel::Portable);
            assert_builds_match(
                &reference,
                [&auto, &portable],
                a.view(),
                theta,
                &format!("{h}x{w}, step {n}"),
            );
        }
    }
}

#[test]
fn several_steps_equal_as_many_reference_steps() {
    // `steps_with` forms `(τ a) / θ` once for its n steps: it must leave the reference's bits.
    // Maps with steep jumps (the dual projection active) and a smooth one, tall maps (many
    // row-parallel tasks), n = 1, 2, 3, 5 and 16.
    let shapes =
        [(3, 40, 5.0), (17, 29, 0.2), (1, 9, 3.0), (5, 17, 0.0), (9, 8, 2.0), (65, 5, 2.0), (150, 9, 5.0)];
    for (h, w, jump) in shapes {
        let mut r = stream((h * 1000 + w) as u64);
        let init = Array2::from_shape_fn((h, w), |(y, x)| {
            (0.5 + jump * (((x / 5 + y / 3) % 2) as f64) + 0.1 * r()) as f32
        });
        let a = Array2::from_shape_fn((h, w), |_| (0.1 + 1.9 * r()) as f32);
        let grey = Array2::from_shape_fn((h, w), |_| (r() * 255.0) as f32);
        let g = edge_weights(grey.view(), 10.0, 1.0);
        let mut reference = HuberTv::new(init.clone(), g, 1e-3);
        let mut auto = reference.clone();
        let mut portable = reference.clone();
        for (i, n) in [1usize, 2, 3, 5, 16, 16].into_iter().enumerate() {
            let theta = 0.5 * 0.3f64.powi(i as i32);
            for _ in 0..n {
                reference.step_reference(a.view(), theta);
            }
            auto.steps_with(a.view(), theta, n, CpuFeatureLevel::get());
            portable.steps_with(a.view(), theta, n, CpuFeatureLevel::Portable);
            let what = format!("{h}x{w}, {n} steps at θ {theta}");
            assert_builds_match(&reference, [&auto, &portable], a.view(), theta, &what);
        }
    }
}

#[test]
fn several_steps_are_independent_of_thread_count() {
    // Rows are rayon tasks: 1, 2, 3 and 8 threads give the same bits over 16 steps.
    let (h, w) = (200, 23);
    let mut r = stream(77);
    let init = Array2::from_shape_fn((h, w), |(y, x)| {
        (0.5 + 2.0 * (((x / 4 + y / 7) % 2) as f64) + 0.1 * r()) as f32
    });
    let a = Array2::from_shape_fn((h, w), |_| (0.1 + 1.9 * r()) as f32);
    let grey = Array2::from_shape_fn((h, w), |_| (r() * 255.0) as f32);
    let tv = HuberTv::new(init, edge_weights(grey.view(), 10.0, 1.0), 1e-3);
    let run = |threads: usize| {
        let mut tv = tv.clone();
        rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap().install(|| {
            tv.steps_with(a.view(), 0.05, 16, CpuFeatureLevel::get());
        });
        tv.primal().iter().map(|v| v.to_bits()).collect::<Vec<_>>()
    };
    let one = run(1);
    for threads in [2, 3, 8] {
        assert!(run(threads) == one, "{threads} threads");
    }
}

#[test]
fn primal_dual_gap_shrinks_and_dual_stays_feasible() {
    let (h, w) = (24, 32);
    let mut r = stream(3);
    let a = Array2::from_shape_fn((h, w), |(y, x)| {
        (0.5 + 0.3 * ((x / 8 + y / 8) % 2) as f64 + 0.05 * r()) as f32
    });
    let grey = Array2::from_shape_fn((h, w), |_| (r() * 255.0) as f32);
    let g = edge_weights(grey.view(), 10.0, 1.0);
    let theta = 0.01;
    let mut tv = HuberTv::new(a.clone(), g, 1e-3);
    let mut gaps = Vec::new();
    let mut primals = Vec::new();
    for n in 1..=2000 {
        tv.step(a.view(), theta);
        if [1, 10, 50, 200, 2000].contains(&n) {
            let rep = tv.gap(a.view(), theta);
            eprintln!("step {n}: primal {:.6e}, dual {:.6e}, gap {:.3e}", rep.primal, rep.dual, rep.gap());
            assert!(rep.gap() >= -1e-6 * rep.primal.abs().max(1.0), "negative gap {}", rep.gap());
            gaps.push(rep.gap());
            primals.push(rep.primal);
        }
        assert!(tv.dual_max_norm() <= 1.0 + 1e-6, "dual left the unit ball: {}", tv.dual_max_norm());
    }
    for pair in gaps.windows(2) {
        assert!(pair[1] < pair[0], "gap did not shrink: {gaps:?}");
    }
    for pair in primals.windows(2).skip(1) {
        assert!(pair[1] <= pair[0] * (1.0 + 1e-9), "primal energy increased: {primals:?}");
    }
    // Plain Chambolle-Pock converges as O(1/n) in the gap: measured 2.2 -> 0.17 after 400 steps.
    assert!(gaps[gaps.len() - 1] < 0.02 * gaps[0], "gap {gaps:?}");
}

#[test]
fn constant_cost_volume_and_constant_depth_are_a_fixed_point() {
    let (h, w, k) = (9, 11, 16);
    let bins = InverseDepthBins::new(0.2, 1.0, k).unwrap();
    let costs = Array3::from_elem((h, w, k), 7.0f32);
    let mut r = stream(5);
    let grey = Array2::from_shape_fn((h, w), |_| (r() * 255.0) as f32); // any image
    let init = Array2::from_elem((h, w), bins.rho(5) as f32);
    let (res, report) =
        solve(&DtamProblem::new(costs.view(), &bins, grey.view(), init.view(), &DtamParams::default()))
            .unwrap();
    assert_eq!(res.inverse_depth, init);
    assert_eq!(res.auxiliary, init);
    assert_eq!(report.iterations, DtamParams::default().iterations);
}

#[test]
fn constant_image_with_data_at_the_current_depth_is_a_fixed_point() {
    // A constant image (g = 1) whose cost minimum everywhere is the current depth.
    let (h, w, k) = (8, 8, 12);
    let bins = InverseDepthBins::new(0.2, 1.0, k).unwrap();
    let k0 = 4;
    let costs = Array3::from_shape_fn((h, w, k), |(_, _, kk)| (kk as f32 - k0 as f32).abs() * 3.0);
    let grey = Array2::from_elem((h, w), 100.0f32);
    let init = Array2::from_elem((h, w), bins.rho(k0) as f32);
    let (res, _) =
        solve(&DtamProblem::new(costs.view(), &bins, grey.view(), init.view(), &DtamParams::default()))
            .unwrap();
    for &d in res.inverse_depth.iter() {
        assert!((d as f64 - bins.rho(k0)).abs() < 1e-6, "{d} vs {}", bins.rho(k0));
    }
}

#[test]
fn solve_is_independent_of_thread_count() {
    let (h, w, k) = (30, 40, 24);
    let costs = random_volume(h, w, k, 9, 0.1);
    let bins = InverseDepthBins::new(0.1, 2.0, k).unwrap();
    let mut r = stream(10);
    let grey = Array2::from_shape_fn((h, w), |_| (r() * 255.0) as f32);
    let init = Array2::from_shape_fn((h, w), |_| (0.1 + 1.9 * r()) as f32);
    let params = DtamParams { iterations: 40, ..DtamParams::default() };
    let run = |n: usize| {
        with_threads(n, || {
            fingerprint(
                solve(&DtamProblem::new(costs.view(), &bins, grey.view(), init.view(), &params)).unwrap(),
            )
        })
    };
    let one = run(1);
    for n in [2, 3, 8] {
        assert_eq!(run(n), one, "threads = {n}");
    }
}

#[test]
fn bad_parameters_are_rejected() {
    let bins = InverseDepthBins::new(0.2, 1.0, 4).unwrap();
    let costs = Array3::<f32>::zeros((2, 2, 4));
    let img = Array2::<f32>::zeros((2, 2));
    for p in [
        DtamParams { lambda: 0.0, ..DtamParams::default() },
        DtamParams { theta_end: 1.0, theta_start: 0.1, ..DtamParams::default() },
        DtamParams { iterations: 0, ..DtamParams::default() },
        DtamParams { epsilon: f64::NAN, ..DtamParams::default() },
    ] {
        assert!(solve(&DtamProblem::new(costs.view(), &bins, img.view(), img.view(), &p)).is_err(), "{p:?}");
    }
    let wrong = Array2::<f32>::zeros((3, 2));
    assert!(solve(&DtamProblem::new(costs.view(), &bins, wrong.view(), img.view(), &DtamParams::default()))
        .is_err());
}

/// Render a weakly textured plane from five cameras on a horizontal line, build the RGB cost
/// volume of the middle one, and return (WTA, TV, ground-truth) inverse depth over the interior.
fn plane_case(plane: Quad) -> (Vec<f64>, Vec<f64>, Vec<f64>) {
    let cam = crate::common::dtam_cases::plane_camera();
    let (poses, frames) = crate::common::dtam_cases::render_plane(plane);
    let bins = InverseDepthBins::new(0.2, 1.0, 64).unwrap();
    let mut cv = CostVolume::new(frames[2].rgb.clone(), cam, bins).unwrap();
    for i in [0, 1, 3, 4] {
        cv.add_frame(frames[i].rgb.view(), &relative_pose(&poses[2], &poses[i])).unwrap();
    }
    let wta = cv.winner_take_all();
    let grey = to_gray(&frames[2].rgb);
    // λ = 300: a sweep over {3, 10, 30, 100, 300, 1000} on these two planes gave TV inverse-depth rms
    // 0.032, 0.031, 0.030, 0.018, 0.0021, 0.0029 1/m (fronto-parallel); it is fixed here, not tuned
    // per run.
    let params = DtamParams { lambda: 300.0, ..DtamParams::default() };
    let (tv, report) =
        solve(&DtamProblem::new(cv.costs().view(), &bins, grey.view(), wta.inverse_depth.view(), &params))
            .unwrap();
    eprintln!(
        "TV: {} iterations, {:.3} s, energy {:.4e} -> {:.4e}",
        report.iterations,
        report.seconds,
        report.energy[0],
        report.energy[report.energy.len() - 1]
    );
    let gt = frames[2].depth.mapv(|z| 1.0 / z);
    let pick = |m: &Array2<f32>| {
        m.slice(ndarray::s![10..110, 40..120]).iter().map(|&v| v as f64).collect::<Vec<_>>()
    };
    (pick(&wta.inverse_depth), pick(&tv.inverse_depth), pick(&gt))
}

fn rms(a: &[f64], b: &[f64]) -> f64 {
    (a.iter().zip(b).map(|(x, y)| (x - y) * (x - y)).sum::<f64>() / a.len() as f64).sqrt()
}

#[test]
fn fronto_parallel_and_slanted_planes_are_recovered() {
    let front = Quad::new(Vector3::new(-10.0, -10.0, 2.0), Vector3::x(), Vector3::y(), [20.0, 20.0]);
    // Slanted 35 degrees about the vertical axis, through (0, 0, 2).
    let (s, c) = 35f64.to_radians().sin_cos();
    let axis_u = Vector3::new(c, 0.0, s);
    let slanted = Quad::new(Vector3::new(0.0, -10.0, 2.0) - axis_u * 3.0, axis_u, Vector3::y(), [6.0, 20.0]);
    for (name, plane) in [("fronto-parallel", front), ("slanted", slanted)] {
        let (wta, tv, gt) = plane_case(plane);
        let (e_wta, e_tv) = (rms(&wta, &gt), rms(&tv, &gt));
        eprintln!("{name}: inverse-depth rms WTA {e_wta:.4} 1/m, TV {e_tv:.4} 1/m");
        assert!(e_tv < e_wta, "{name}: TV {e_tv} did not improve on WTA {e_wta}");
        // One hypothesis spacing is 0.8/63 = 0.0127 1/m. Measured: WTA 0.032 / 0.046, TV 0.0021 /
        // 0.0047 (fronto-parallel / slanted at 35 degrees).
        assert!(e_tv < 0.5 * 0.0127, "{name}: TV inverse-depth rms {e_tv}");
        assert!(e_tv < e_wta / 3.0, "{name}: TV {e_tv} vs WTA {e_wta}");
    }
}

#[test]
fn shipped_weights_are_built_in_and_rgb_matches_their_grid() {
    use densefeat::mapping::{FeatureExtractor, FeatureKind};
    let level = FeatureExtractor::network_level().unwrap();
    let learned =
        FeatureExtractor::new(FeatureKind::Learned(None), level, densefeat::backend::default_backend())
            .unwrap();
    assert_eq!(learned.network_output_level(), Some(level));
    let rgb = FeatureExtractor::new(FeatureKind::Rgb, level, densefeat::backend::default_backend()).unwrap();
    let img = Array3::from_shape_fn((24, 33, 3), |(y, x, c)| ((y * 7 + x * 3 + c * 50) % 256) as f32);
    let (fl, fr) = (learned.extract(&img).unwrap(), rgb.extract(&img).unwrap());
    assert_eq!((fl.level, fr.level), (level, level));
    // At level 0 both kinds have the input's size (learned features upsampled, SPEC §11.1).
    let l0 = FeatureExtractor::new(FeatureKind::Learned(None), 0, densefeat::backend::default_backend())
        .unwrap()
        .extract(&img)
        .unwrap();
    let r0 = FeatureExtractor::new(FeatureKind::Rgb, 0, densefeat::backend::default_backend())
        .unwrap()
        .extract(&img)
        .unwrap();
    assert_eq!((l0.data.dim().0, l0.data.dim().1, r0.data.dim().0, r0.data.dim().1), (24, 33, 24, 33));
    assert_eq!((fl.data.dim().0, fl.data.dim().1), (fr.data.dim().0, fr.data.dim().1));
    assert_eq!(fl.data.dim().2, 32);
    let k = PinholeCamera::new(30.0, 30.0, 16.0, 11.5, 33, 24).unwrap();
    assert_eq!(learned.camera(&k).width, fl.data.dim().1);
    assert!("learned=x.safetensors".parse::<FeatureKind>().is_ok());
    assert!("sift".parse::<FeatureKind>().is_err());
}

/// Runs the test `name` of this module again, alone, in a child process of this test binary with
/// `var=value` set (the CPU level is read once per process), and asserts that it passed.
fn rerun_in_child(name: &str, var: &str, value: &str) {
    // The harness names a test by its module path inside the test crate (`dtam::NAME`).
    let full = match module_path!().split_once("::") {
        Some((_, module)) => format!("{module}::{name}"),
        None => name.to_string(),
    };
    let out = std::process::Command::new(std::env::current_exe().unwrap())
        .args([full.as_str(), "--exact", "--test-threads", "1"])
        .env(var, value)
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success() && stdout.contains("1 passed"), "child run with {var}={value}: {stdout}");
}

/// `DENSEFEAT_NO_AVX512` reaches every AVX-512 dispatch, DTAM's and the feature upsampling's
/// included (issue 33): every AVX-512F probe in the library is `runtime::has_avx512f`, which the
/// variable switches off. Checked in a child process of this test binary (the variable is read
/// once per process) and on the source.
#[test]
fn no_avx512_env_switches_every_avx512_dispatch() {
    use densefeat::runtime::{has_avx512f, NO_AVX512_ENV};
    const NAME: &str = "no_avx512_env_switches_every_avx512_dispatch";
    if std::env::var_os(NO_AVX512_ENV).is_some() {
        assert!(!has_avx512f());
        assert!(!densefeat::runtime::CpuFeatureLevel::get().avx512f());
        return;
    }
    rerun_in_child(NAME, NO_AVX512_ENV, "1");
    // The source: no other AVX-512F probe.
    let mut stack = vec![std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("src")];
    let mut files = 0;
    while let Some(dir) = stack.pop() {
        for entry in std::fs::read_dir(&dir).unwrap() {
            let path = entry.unwrap().path();
            if path.is_dir() {
                stack.push(path);
            } else if path.extension().is_some_and(|e| e == "rs") && !path.ends_with("runtime.rs") {
                files += 1;
                let text = std::fs::read_to_string(&path).unwrap();
                for feature in ["avx512f", "avx512bw", "avx512vl", "avx512dq", "avx2", "fma"] {
                    assert!(
                        !text.contains(&format!("is_x86_feature_detected!({feature:?})")),
                        "{} probes {feature} itself; use runtime::has_avx512f / has_avx2_fma",
                        path.display()
                    );
                }
            }
        }
    }
    assert!(files > 50, "read {files} source files");
}

/// `DENSEFEAT_CPU_LEVEL` caps the one CPU-feature level every kernel reads (issue 33 item 3): with
/// `portable` no kernel may use AVX2 or AVX-512 (a child process of this test binary, as above),
/// and the binary refuses an unknown level up front, naming the variable.
#[test]
fn cpu_level_env_caps_every_dispatch_and_bad_values_are_refused() {
    use densefeat::runtime::{has_avx2_fma, has_avx512f, CpuFeatureLevel, CPU_LEVEL_ENV};
    const NAME: &str = "cpu_level_env_caps_every_dispatch_and_bad_values_are_refused";
    if std::env::var(CPU_LEVEL_ENV).as_deref() == Ok("portable") {
        assert_eq!(CpuFeatureLevel::get(), CpuFeatureLevel::Portable);
        assert!(!has_avx512f() && !has_avx2_fma());
        assert!(!densefeat::runtime::CpuFeatureLevel::get().avx512f());
        return;
    }
    assert!(CpuFeatureLevel::get() <= CpuFeatureLevel::detected());
    for l in CpuFeatureLevel::ALL {
        assert_eq!(CpuFeatureLevel::parse(l.name()), Some(l));
    }
    assert_eq!(CpuFeatureLevel::parse("sse2"), None);
    rerun_in_child(NAME, CPU_LEVEL_ENV, "portable");
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_densefeat"))
        .args(["synth", "--seed", "3", "--frames", "2", "--out"])
        .arg(std::env::temp_dir().join("densefeat_cpu_level_never_written"))
        .env(CPU_LEVEL_ENV, "sse9")
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success() && err.contains(CPU_LEVEL_ENV) && err.contains("portable, avx2 or avx512"),
        "{err}"
    );
    assert!(!std::env::temp_dir().join("densefeat_cpu_level_never_written").exists());
}
