//! Second-order TGV in DTAM (SPEC.md §10.4): `K(d, v) = (∇d − M v/β, ∇v)` and its adjoint, the step
//! size against the operator's norm, the row-parallel f32 steps against the naive f64 reference,
//! the energy, thread-count determinism, one problem on every path, and a slanted plane that TGV
//! keeps where Huber-TV bends it.

use densefeat::costvolume::CostVolume;
use densefeat::dtam::tgv::{adjoint, apply, normalised_beta, step_size, Dual, Primal, Reference};
use densefeat::dtam::{solve, DtamParams, DtamProblem, HuberTv};
use densefeat::geometry::{relative_pose, InverseDepthBins, PinholeCamera, Pose};
use densefeat::image::to_gray;
use densefeat::synth::{Quad, Scene, Shape, Surface, Texture};
use nalgebra::{Translation3, UnitQuaternion, Vector3};
use ndarray::{s, Array2, Array3};
use proptest::prelude::*;

/// A deterministic pseudo-random stream from a seed (tests only).
fn stream(seed: u64) -> impl FnMut() -> f64 {
    let mut s = seed ^ 0x9E37_79B9_7F4A_7C15;
    move || {
        s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        (s >> 11) as f64 / (1u64 << 53) as f64
    }
}

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
        let (wx, _) = fast.slope_field().unwrap();
        let worst_w = wx.iter().zip(oracle.x.vx.iter())
            .map(|(&f, &o)| (f as f64 - o / beta).abs()).fold(0.0, f64::max);
        prop_assert!(worst_w <= budget * 4.0 / beta.min(1.0), "max |w_fast - w_f64| = {worst_w:e}");
    }
}

/// Random DTAM inputs `[h, w, k]` from `seed`: costs in [0, 50), bins over [0.1, 2] 1/m, grey levels
/// in [0, 255), initial inverse depth in [0.1, 2].
fn random_solve_inputs(
    (h, w, k): (usize, usize, usize),
    seed: u64,
) -> (Array3<f32>, InverseDepthBins, Array2<f32>, Array2<f32>) {
    let mut r = stream(seed);
    let costs = Array3::from_shape_fn((h, w, k), |_| (r() * 50.0) as f32);
    let bins = InverseDepthBins::new(0.1, 2.0, k).unwrap();
    let grey = Array2::from_shape_fn((h, w), |_| (r() * 255.0) as f32);
    let init = Array2::from_shape_fn((h, w), |_| (0.1 + 1.9 * r()) as f32);
    (costs, bins, grey, init)
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
    let (wx, wy) = tv.slope_field().unwrap();
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
    let bits = |(res, rep): (densefeat::dtam::DtamResult, densefeat::dtam::DtamReport)| {
        (
            res.inverse_depth.mapv(f32::to_bits),
            res.auxiliary.mapv(f32::to_bits),
            rep.energy.iter().map(|e| e.to_bits()).collect::<Vec<_>>(),
        )
    };
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
        rayon::ThreadPoolBuilder::new().num_threads(n).build().unwrap().install(|| {
            let (res, rep) = solve(
                &DtamProblem::new(costs.view(), &bins, grey.view(), init.view(), &params)
                    .with_second_order(2.0),
            )
            .unwrap();
            (
                res.inverse_depth.mapv(f32::to_bits),
                res.auxiliary.mapv(f32::to_bits),
                rep.energy.iter().map(|e| e.to_bits()).collect::<Vec<_>>(),
                rep.gap.iter().map(|e| e.to_bits()).collect::<Vec<_>>(),
            )
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

const PLANE_CAMERA: (f64, f64, f64, f64, usize, usize) = (128.0, 128.0, 79.5, 59.5, 160, 120);

fn camera() -> PinholeCamera {
    let (fx, fy, cx, cy, w, h) = PLANE_CAMERA;
    PinholeCamera::new(fx, fy, cx, cy, w, h).unwrap()
}

/// (WTA, TV, TGV, ground truth) inverse depth over the interior of a plane through `(0, 0, 2)`
/// turned `degrees` about the vertical axis, seen by 5 cameras on a horizontal line (faint
/// texture), the mapping's normalised schedule at `lambda`, TGV at `beta` (pixels at 640 px).
fn plane_case(degrees: f64, lambda: f64, beta: f64) -> [Vec<f64>; 4] {
    let (s, c) = degrees.to_radians().sin_cos();
    let axis_u = Vector3::new(c, 0.0, s);
    let plane = Quad::new(Vector3::new(0.0, -10.0, 2.0) - axis_u * 6.0, axis_u, Vector3::y(), [12.0, 20.0]);
    let texture =
        Texture::Noise { a: [0.45, 0.45, 0.45], b: [0.55, 0.55, 0.55], scale: 0.05, octaves: 2, key: 3 };
    let poses: Vec<Pose> = (0..5)
        .map(|i| {
            Pose::from_parts(Translation3::new(0.1 * (i as f64 - 2.0), 0.0, 0.0), UnitQuaternion::identity())
        })
        .collect();
    let scene = Scene::new(camera(), poses.clone(), vec![Surface { shape: Shape::Quad(plane), texture }]);
    let frames: Vec<_> = (0..5).map(|i| scene.render(i).unwrap()).collect();
    let cam = camera();
    let bins = InverseDepthBins::new(0.1, 1.0, 64).unwrap();
    let mut cv = CostVolume::new(frames[2].rgb.clone(), cam, bins).unwrap();
    for i in [0, 1, 3, 4] {
        cv.add_frame(frames[i].rgb.view(), &relative_pose(&poses[2], &poses[i])).unwrap();
    }
    let wta = cv.winner_take_all();
    let costs = cv.costs();
    let grey = to_gray(&frames[2].rgb);
    let params = DtamParams { lambda, ..densefeat::dtam::MAPPING_DEFAULTS }.normalised(
        densefeat::costvolume::cost_scale(costs.view()),
        cam.width,
        bins.rho_max - bins.rho_min,
    );
    let problem = DtamProblem::new(costs.view(), &bins, grey.view(), wta.inverse_depth.view(), &params);
    let (tv, _) = solve(&problem).unwrap();
    let (tgv, _) = solve(&problem.with_second_order(normalised_beta(beta, cam.width))).unwrap();
    let gt = frames[2].depth.mapv(|z| 1.0 / z);
    let pick = |m: &Array2<f32>| m.slice(s![10..110, 10..110]).iter().map(|&v| v as f64).collect::<Vec<_>>();
    [pick(&wta.inverse_depth), pick(&tv.inverse_depth), pick(&tgv.inverse_depth), pick(&gt)]
}

fn rms(a: &[f64], b: &[f64]) -> f64 {
    (a.iter().zip(b).map(|(x, y)| (x - y) * (x - y)).sum::<f64>() / a.len() as f64).sqrt()
}

#[test]
fn tgv_recovers_a_steep_plane_that_tv_bends() {
    // The case of tests/dtam_normals.rs's normal-prior test, without normals: at λ = 1000 (a data
    // term 10x weaker than the mapping default) TV bends the slanted plane, TGV (β = 4, the
    // default) keeps it. One hypothesis spacing is 0.9/63 = 0.0143 1/m.
    for degrees in [45.0, 55.0] {
        let [wta, tv, tgv, gt] = plane_case(degrees, 1000.0, densefeat::dtam::tgv::DEFAULT_BETA);
        let (e_wta, e_tv, e_tgv) = (rms(&wta, &gt), rms(&tv, &gt), rms(&tgv, &gt));
        eprintln!(
            "plane at {degrees}°, λ 1000: inverse-depth rms WTA {e_wta:.5}, TV {e_tv:.5}, TGV {e_tgv:.5} 1/m"
        );
        assert!(e_tv > 0.1 * 0.0143, "{degrees}°: TV {e_tv} did not bend: the case shows nothing");
        assert!(e_tgv < 0.1 * 0.0143, "{degrees}°: TGV rms {e_tgv}");
        assert!(e_tgv < e_tv / 3.0, "{degrees}°: TGV {e_tgv} vs TV {e_tv}");
    }
}
