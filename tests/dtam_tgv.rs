//! Second-order TGV in DTAM (SPEC.md §10.4): `K(d, v) = (∇d − M v/β, ∇v)` and its adjoint, the step
//! size against the operator's norm, the row-parallel f32 steps against the naive f64 reference,
//! the energy, thread-count determinism, one problem on every path, and a slanted plane that TGV
//! keeps where Huber-TV bends it.

use densefeat::dtam::tgv::{adjoint, apply, normalised_beta, step_size, Dual, Primal, Reference};
use densefeat::dtam::{solve, DtamParams, DtamProblem, HuberTv};
use ndarray::Array2;
use proptest::prelude::*;

use crate::common::dtam_cases::{
    fingerprint, plane_camera, plane_volume, random_solve_inputs, rms, stream, with_threads, PlaneVolume,
};

fn field(h: usize, w: usize, r: &mut impl FnMut() -> f64) -> Array2<f64> {
    Array2::from_shape_fn((h, w), |_| r() * 2.0 - 1.0)
}

fn dot_primal(a: &Primal, b: &Primal) -> f64 {
    (&a.d * &b.d).sum() + (&a.vx * &b.vx).sum() + (&a.vy * &b.vy).sum()
}

fn dot_dual(a: &Dual, b: &Dual) -> f64 {
    (&a.px * &b.px).sum() + (&a.py * &b.py).sum() + (0..4).map(|i| (&a.r[i] * &b.r[i]).sum()).sum::<f64>()
}

proptest! {
    #[test]
    fn tgv_operator_adjoint_identity(h in 1usize..12, w in 1usize..12, seed: u64,
                                     beta in prop_oneof![Just(0.1), Just(1.0), Just(7.5), Just(1e3)]) {
        let mut r = stream(seed);
        let x = Primal { d: field(h, w, &mut r), vx: field(h, w, &mut r), vy: field(h, w, &mut r) };
        let p = Dual {
            px: field(h, w, &mut r),
            py: field(h, w, &mut r),
            r: std::array::from_fn(|_| field(h, w, &mut r)),
        };
        let lhs = dot_dual(&apply(&x, beta), &p);
        let rhs = dot_primal(&x, &adjoint(&p, beta));
        prop_assert!((lhs - rhs).abs() <= 1e-12 * lhs.abs().max(1.0), "<K x, p> = {lhs}, <x, K^T p> = {rhs}");
    }

    #[test]
    fn tgv_step_size_bounds_the_operator(h in 1usize..10, w in 1usize..10, seed: u64,
                                         beta in prop_oneof![Just(0.1), Just(1.0), Just(7.5)]) {
        // Power iteration on KᵀK from a random start: ‖K‖ never exceeds 1/step.
        let mut r = stream(seed);
        let mut x = Primal { d: field(h, w, &mut r), vx: field(h, w, &mut r), vy: field(h, w, &mut r) };
        let mut norm = 0.0;
        for _ in 0..60 {
            let n = dot_primal(&x, &x).sqrt();
            x = Primal { d: &x.d / n, vx: &x.vx / n, vy: &x.vy / n };
            let kx = apply(&x, beta);
            norm = dot_dual(&kx, &kx).sqrt();
            x = adjoint(&kx, beta);
        }
        let bound = 1.0 / step_size(beta);
        prop_assert!(norm <= bound * (1.0 + 1e-12), "‖K‖ ≈ {norm} > {bound}");
    }

    #[test]
    fn tgv_fast_steps_match_the_f64_reference(h in 1usize..16, w in 1usize..16, seed: u64, steps in 1usize..20,
                                              theta in prop_oneof![Just(1e-3), Just(0.05), Just(1.0)],
                                              beta in prop_oneof![Just(0.25), Just(1.0), Just(4.0)]) {
        let mut r = stream(seed);
        let d0 = Array2::from_shape_fn((h, w), |_| (0.2 + 2.0 * r()) as f32);
        let a = Array2::from_shape_fn((h, w), |_| (0.2 + 2.0 * r()) as f32);
        let g = Array2::from_shape_fn((h, w), |_| (0.05 + 0.95 * r()) as f32);
        let eps = 1e-3;
        let mut fast = HuberTv::with_second_order(d0.clone(), g.clone(), eps, beta);
        let mut oracle = Reference::new(d0.view(), g.view(), eps, beta);
        for _ in 0..steps {
            fast.step(a.view(), theta);
            oracle.step(a.view(), theta);
        }
        // Budget: each step rounds d, d̄, v, v̄, p and r to f32 (2^-24 relative) and the iteration is
        // non-expansive, so the difference grows at most linearly in the steps: 4 · steps · 2^-24
        // of the values' scale (|d|, |a| <= 2.2). Measured over 500 cases: at most
        // 0.87 · steps · 2^-24 · 2.2.
        let budget = 4.0 * steps as f64 * f64::from(f32::EPSILON) / 2.0 * 2.2;
        let worst = fast.primal().iter().zip(oracle.x.d.iter())
            .map(|(&f, &o)| (f as f64 - o).abs()).fold(0.0, f64::max);
        prop_assert!(worst <= budget, "max |d_fast - d_f64| = {worst:e} > budget {budget:e}");
        let (wx, _) = fast.tgv_slope().unwrap();
        let worst_w = wx.iter().zip(oracle.x.vx.iter())
            .map(|(&f, &o)| (f as f64 - o / beta).abs()).fold(0.0, f64::max);
        prop_assert!(worst_w <= budget * 4.0 / beta.min(1.0), "max |w_fast - w_f64| = {worst_w:e}");
    }
}

#[test]
fn tgv_energy_is_the_reference_regulariser() {
    // After some steps (v no longer 0), the solver's regulariser (row sums of the f32 state)
    // equals the f64 definition evaluated on the same state within rounding.
    let (h, w) = (9, 13);
    let mut r = stream(5);
    let d0 = Array2::from_shape_fn((h, w), |_| (0.2 + 2.0 * r()) as f32);
    let a = Array2::from_shape_fn((h, w), |_| (0.2 + 2.0 * r()) as f32);
    let g = Array2::from_shape_fn((h, w), |_| (0.05 + 0.95 * r()) as f32);
    let beta = 2.0;
    let mut tv = HuberTv::with_second_order(d0.clone(), g.clone(), 1e-3, beta);
    for _ in 0..7 {
        tv.step(a.view(), 0.05);
    }
    let (wx, wy) = tv.tgv_slope().unwrap();
    let mut oracle = Reference::new(tv.primal(), g.view(), 1e-3, beta);
    // The oracle's v is β w of the fast state (w = v/β is what the fast state reports).
    oracle.x.vx = wx.mapv(|v| v as f64 * beta);
    oracle.x.vy = wy.mapv(|v| v as f64 * beta);
    let (e_fast, e_ref) = (tv.regulariser_energy(), oracle.regulariser_energy());
    assert!(e_ref > 0.0);
    assert!((e_fast - e_ref).abs() <= 1e-6 * e_ref, "{e_fast} vs {e_ref}");
}

#[test]
fn a_tgv_problem_solves_the_same_on_every_path() {
    // `dtam::solve`, the unfused `solve_reference` and the CPU backend give the same bits; TGV
    // changes the solve; a β that is not positive, or TGV together with a slope field, is refused.
    use densefeat::backend::{Backend, CpuBackend};
    use densefeat::dtam::{solve_reference, SlopeField};
    let (h, w) = (23, 31);
    let (costs, bins, grey, init) = random_solve_inputs((h, w, 40), 7);
    let params =
        DtamParams { iterations: 12, max_iterations: 16, steps_per_search: 2, ..DtamParams::default() };
    let problem =
        DtamProblem::new(costs.view(), &bins, grey.view(), init.view(), &params).with_second_order(1.5);
    let bits = fingerprint;
    let fused = bits(solve(&problem).unwrap());
    assert!(bits(solve_reference(&problem).unwrap()) == fused, "the unfused definition differs");
    assert!(bits(CpuBackend::default().dtam_solve(&problem).unwrap()) == fused, "the backend differs");
    let tv = bits(solve(&DtamProblem { second_order: None, ..problem }).unwrap());
    assert!(tv.0 != fused.0, "the second order must change the solve");
    for bad in [0.0, -1.0, f64::NAN, f64::INFINITY] {
        let e = solve(&problem.with_second_order(bad)).unwrap_err().to_string();
        assert!(e.contains("--tgv-beta"), "{e}");
    }
    let q = SlopeField::zeros(h, w);
    let e = solve(&problem.with_slope(&q)).unwrap_err().to_string();
    assert!(e.contains("--regularizer") && e.contains("TGV"), "{e}");
}

#[test]
fn tgv_solve_is_independent_of_thread_count() {
    let (h, w) = (37, 53);
    let (costs, bins, grey, init) = random_solve_inputs((h, w, 48), 41);
    let params =
        DtamParams { iterations: 20, max_iterations: 30, steps_per_search: 3, ..DtamParams::default() };
    let run = |n: usize| {
        with_threads(n, || {
            let problem = DtamProblem::new(costs.view(), &bins, grey.view(), init.view(), &params);
            fingerprint(solve(&problem.with_second_order(2.0)).unwrap())
        })
    };
    let one = run(1);
    for n in [2, 3, 8] {
        assert!(run(n) == one, "threads = {n}");
    }
}

#[test]
fn tgv_leaves_a_plane_and_its_slope_alone() {
    // An affine inverse depth with the matching slope field is a zero of K away from the border:
    // the regulariser is the border's alone, and one step with `a = d` moves nothing inside.
    let (h, w) = (20, 30);
    let d = Array2::from_shape_fn((h, w), |(y, x)| 0.5 + 0.01 * x as f64 - 0.004 * y as f64);
    let beta = 3.0;
    let x = Primal {
        d: d.clone(),
        vx: Array2::from_elem((h, w), 0.01 * beta),
        vy: Array2::from_elem((h, w), -0.004 * beta),
    };
    let k = apply(&x, beta);
    for y in 0..h - 1 {
        for xx in 0..w - 1 {
            assert!(k.px[[y, xx]].abs() < 1e-15 && k.py[[y, xx]].abs() < 1e-15);
            assert!(k.r.iter().all(|r| r[[y, xx]].abs() < 1e-15));
        }
    }
}

/// (WTA, TV, TGV, ground truth) inverse depth over the interior of [`plane_volume`]`(degrees)`
/// at `lambda`, TGV at `beta` (pixels at 640 px).
fn plane_case(degrees: f64, lambda: f64, beta: f64) -> [Vec<f64>; 4] {
    let v = plane_volume(degrees, lambda);
    let (tv, _) = solve(&v.problem()).unwrap();
    let (tgv, _) =
        solve(&v.problem().with_second_order(normalised_beta(beta, plane_camera().width))).unwrap();
    let pick = PlaneVolume::interior;
    [pick(&v.wta), pick(&tv.inverse_depth), pick(&tgv.inverse_depth), v.truth()]
}

#[test]
fn tgv_recovers_a_steep_plane_that_tv_bends() {
    // The case of tests/dtam_normals.rs's normal-prior test, without normals: at λ = 1000 (a data
    // term 10x weaker than the mapping default) TV bends the slanted plane, TGV (β = 4) keeps it. One hypothesis spacing is 0.9/63 = 0.0143 1/m.
    for degrees in [45.0, 55.0] {
        let [wta, tv, tgv, gt] = plane_case(degrees, 1000.0, 4.0);
        let (e_wta, e_tv, e_tgv) = (rms(&wta, &gt), rms(&tv, &gt), rms(&tgv, &gt));
        eprintln!(
            "plane at {degrees}°, λ 1000: inverse-depth rms WTA {e_wta:.5}, TV {e_tv:.5}, TGV {e_tgv:.5} 1/m"
        );
        assert!(e_tv > 0.1 * 0.0143, "{degrees}°: TV {e_tv} did not bend: the case shows nothing");
        assert!(e_tgv < 0.1 * 0.0143, "{degrees}°: TGV rms {e_tgv}");
        assert!(e_tgv < e_tv / 3.0, "{degrees}°: TGV {e_tgv} vs TV {e_tv}");
    }
}
