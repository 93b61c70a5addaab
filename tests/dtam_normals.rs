//! The surface-normal prior (SPEC.md §10.2): `K_n ρ = ∇ρ − ρ q` and its adjoint, the sign of `q`
//! on a rendered plane, the row-parallel f32 steps against the naive f64 reference, thread-count
//! determinism, recovery of a steep plane where Huber-TV bends it, and the normals sources.

use densefeat::dtam::normal_prior::{adjoint, apply, slope, Reference};
use densefeat::dtam::{solve, DtamParams, DtamProblem, HuberTv, SlopeField};
use densefeat::io::write_npy_f32;
use densefeat::mapping::normals::{normals_at_level, normals_from_depth, read_normals};
use ndarray::{s, Array2, Array3};
use proptest::prelude::*;

use crate::common::dtam_cases::{
    fingerprint, plane_camera as camera, plane_frames, plane_volume, random_solve_inputs, rms, stream,
    with_threads, PlaneVolume,
};

/// A random slope field of magnitude up to `scale` per component, zero in the last column (x)
/// and row (y) as `SlopeField::new` makes it, and zero at a fifth of the pixels (fallback).
fn random_field(h: usize, w: usize, scale: f64, seed: u64) -> SlopeField {
    let mut r = stream(seed);
    let mut f = SlopeField::zeros(h, w);
    for y in 0..h {
        for x in 0..w {
            if r() < 0.2 {
                continue;
            }
            f.qx[[y, x]] = if x + 1 < w { ((r() * 2.0 - 1.0) * scale) as f32 } else { 0.0 };
            f.qy[[y, x]] = if y + 1 < h { ((r() * 2.0 - 1.0) * scale) as f32 } else { 0.0 };
        }
    }
    f.max_norm = f.qx.iter().zip(f.qy.iter()).map(|(&a, &b)| (a as f64).hypot(b as f64)).fold(0.0, f64::max);
    f
}

proptest! {
    #[test]
    fn normal_operator_adjoint_identity(h in 1usize..12, w in 1usize..12, seed: u64,
                                        scale in prop_oneof![Just(0.0), Just(0.01), Just(1.0)]) {
        let q = random_field(h, w, scale, seed);
        let mut r = stream(seed.wrapping_add(7));
        let x = Array2::from_shape_fn((h, w), |_| r() * 2.0 - 1.0);
        let py = Array2::from_shape_fn((h, w), |_| r() * 2.0 - 1.0);
        let px = Array2::from_shape_fn((h, w), |_| r() * 2.0 - 1.0);
        let (kx, ky) = apply(x.view(), &q);
        let lhs = (&kx * &px).sum() + (&ky * &py).sum();
        let rhs = (&x * &adjoint(px.view(), py.view(), &q)).sum();
        prop_assert!((lhs - rhs).abs() <= 1e-12, "<K x, p> = {lhs}, <x, K^T p> = {rhs}");
    }

    #[test]
    fn fast_steps_match_the_f64_reference(h in 1usize..16, w in 1usize..16, seed: u64, steps in 1usize..20,
                                          theta in prop_oneof![Just(1e-3), Just(0.05), Just(1.0)],
                                          scale in prop_oneof![Just(0.0), Just(0.02), Just(0.5)]) {
        let q = random_field(h, w, scale, seed);
        let mut r = stream(seed.wrapping_add(3));
        let d0 = Array2::from_shape_fn((h, w), |_| (0.2 + 2.0 * r()) as f32);
        let a = Array2::from_shape_fn((h, w), |_| (0.2 + 2.0 * r()) as f32);
        let g = Array2::from_shape_fn((h, w), |_| (0.05 + 0.95 * r()) as f32);
        let eps = 1e-3;
        let mut fast = HuberTv::with_slope(d0.clone(), g.clone(), eps, &q);
        let mut oracle = Reference::new(d0.view(), g.view(), eps, q);
        for _ in 0..steps {
            fast.step(a.view(), theta);
            oracle.step(a.view(), theta);
        }
        // Budget: each step rounds d, d̄ and p to f32 (2^-24 relative) and the iteration is
        // non-expansive, so the difference grows at most linearly: 4 · steps · 2^-24 of the
        // values' scale (|d|, |a| <= 2.2). Measured over 500 cases: at most 0.91 · steps · 2^-24 · 2.2.
        let budget = 4.0 * steps as f64 * f64::from(f32::EPSILON) / 2.0 * 2.2;
        let worst = fast.primal().iter().zip(oracle.d.iter())
            .map(|(&f, &o)| (f as f64 - o).abs()).fold(0.0, f64::max);
        prop_assert!(worst <= budget, "max |d_fast - d_f64| = {worst:e} > budget {budget:e}");
    }
}

#[test]
fn a_normal_problem_solves_the_same_on_every_path_and_a_wrong_slope_is_refused() {
    // One `DtamProblem` (issue 33 item 2): `dtam::solve`, the unfused `solve_reference` and the CPU
    // backend give the same bits; a slope field of another size is refused before any work.
    use densefeat::backend::{Backend, CpuBackend};
    use densefeat::dtam::solve_reference;
    let (h, w) = (23, 31);
    let (costs, bins, grey, init) = random_solve_inputs((h, w, 40), 7);
    let q = random_field(h, w, 0.05, 8);
    let params =
        DtamParams { iterations: 12, max_iterations: 16, steps_per_search: 2, ..DtamParams::default() };
    let problem = DtamProblem::new(costs.view(), &bins, grey.view(), init.view(), &params).with_slope(&q);
    let bits = |(res, _): (densefeat::dtam::DtamResult, densefeat::dtam::DtamReport)| {
        (res.inverse_depth.mapv(f32::to_bits), res.auxiliary.mapv(f32::to_bits))
    };
    let fused = bits(solve(&problem).unwrap());
    assert!(bits(solve_reference(&problem).unwrap()) == fused, "the unfused definition differs");
    assert!(bits(CpuBackend::default().dtam_solve(&problem).unwrap()) == fused, "the backend differs");
    let tv = bits(solve(&DtamProblem { slope: None, ..problem }).unwrap());
    assert!(tv != fused, "the slope field must change the solve");

    let small = random_field(h - 1, w, 0.05, 8);
    let e = solve(&problem.with_slope(&small)).unwrap_err().to_string();
    assert!(e.contains("normals") && e.contains("slope field"), "{e}");
}

#[test]
fn normal_solve_is_independent_of_thread_count() {
    let (h, w) = (37, 53);
    let (costs, bins, grey, init) = random_solve_inputs((h, w, 48), 41);
    let q = random_field(h, w, 0.05, 42);
    let params =
        DtamParams { iterations: 20, max_iterations: 30, steps_per_search: 3, ..DtamParams::default() };
    let run = |n: usize| {
        with_threads(n, || {
            fingerprint(
                solve(
                    &DtamProblem::new(costs.view(), &bins, grey.view(), init.view(), &params).with_slope(&q),
                )
                .unwrap(),
            )
        })
    };
    let one = run(1);
    for n in [2, 3, 8] {
        assert!(run(n) == one, "threads = {n}");
    }
}

#[test]
fn normal_energy_is_the_reference_regulariser() {
    // The solver's regulariser (row sums of the fast path) equals the f64 definition's within
    // rounding, and the solve's reported energy uses it.
    let (h, w) = (9, 13);
    let mut r = stream(5);
    let d0 = Array2::from_shape_fn((h, w), |_| (0.2 + 2.0 * r()) as f32);
    let g = Array2::from_shape_fn((h, w), |_| (0.05 + 0.95 * r()) as f32);
    let q = random_field(h, w, 0.3, 6);
    let tv = HuberTv::with_slope(d0.clone(), g.clone(), 1e-3, &q);
    let oracle = Reference::new(d0.view(), g.view(), 1e-3, q);
    let (a, b) = (tv.regulariser_energy(), oracle.regulariser_energy());
    assert!((a - b).abs() <= 1e-12 * b.abs(), "{a} vs {b}");
}

#[test]
fn normal_prior_annihilates_a_rendered_plane() {
    // The sign check: on a rendered slanted plane, ρ = 1/z is affine in u and K_n ρ = ∇ρ − ρ q
    // vanishes for the ground-truth normal, while ∇ρ + ρ q (the opposite sign) does not.
    let (_, frames) = plane_frames(50.0);
    let depth = &frames[2].depth;
    let cam = camera();
    let normals = normals_from_depth(depth, &cam);
    let truth = {
        let (s, c) = 50f64.to_radians().sin_cos();
        [-s, 0.0, c]
    };
    // Oriented towards the camera (nᵀX < 0 for X in front): n_z < 0.
    for y in 10..110 {
        for x in 10..150 {
            let n = [normals[[y, x, 0]] as f64, normals[[y, x, 1]] as f64, normals[[y, x, 2]] as f64];
            let dot: f64 = (0..3).map(|k| n[k] * truth[k]).sum();
            assert!((dot.abs() - 1.0).abs() < 1e-4, "normal {n:?} at ({x}, {y}) vs {truth:?}");
            assert!(n[2] < 0.0, "normal {n:?} at ({x}, {y}) faces away from the camera");
        }
    }
    let q = SlopeField::new(normals.view(), &cam).unwrap();
    let rho = depth.mapv(|z| 1.0 / z as f64);
    let (kx, ky) = apply(rho.view(), &q);
    let (mut worst, mut grad, mut wrong) = (0.0f64, 0.0f64, 0.0f64);
    for y in 10..110 {
        for x in 10..150 {
            worst = worst.max(kx[[y, x]].abs()).max(ky[[y, x]].abs());
            let gx = rho[[y, x + 1]] - rho[[y, x]];
            grad = grad.max(gx.abs());
            wrong = wrong.max((gx + rho[[y, x]] * q.qx[[y, x]] as f64).abs());
        }
    }
    eprintln!("plane at 50°: max |∇ρ| {grad:.3e}, max |K_n ρ| {worst:.3e}, max |∇ρ + ρq| {wrong:.3e}");
    assert!(grad > 1e-3, "the plane must be slanted: |∇ρ| = {grad}");
    assert!(worst < 1e-3 * grad, "K_n ρ = {worst} on a plane (|∇ρ| {grad})");
    assert!(wrong > 1.5 * grad, "the opposite sign would predict {wrong}");
    // The formula by hand at one pixel: q = (n_x/f_x, n_y/f_y) / (nᵀK⁻¹ũ).
    let (u, v) = (100.0, 40.0);
    let (sx, sy) = slope(truth, u, v, &cam).unwrap();
    let den = truth[0] * (u - cam.cx) / cam.fx + truth[1] * (v - cam.cy) / cam.fy + truth[2];
    assert_eq!((sx, sy), (truth[0] / cam.fx / den, truth[1] / cam.fy / den));
}

/// (WTA, TV, normal prior with the rendered depth's normals, ground truth) over the interior of
/// [`plane_volume`]`(degrees)` at `lambda`.
fn rgb_plane_case(degrees: f64, lambda: f64) -> [Vec<f64>; 4] {
    let v = plane_volume(degrees, lambda);
    let cam = camera();
    let (tv, _) = solve(&v.problem()).unwrap();
    let q = SlopeField::new(normals_from_depth(&v.depth, &cam).view(), &cam).unwrap();
    let (nm, _) = solve(&v.problem().with_slope(&q)).unwrap();
    let pick = PlaneVolume::interior;
    [pick(&v.wta), pick(&tv.inverse_depth), pick(&nm.inverse_depth), v.truth()]
}

#[test]
fn normal_prior_recovers_a_steep_plane_that_tv_bends() {
    // Planes slanted 45° and 55°, faint texture, the mapping's normalised schedule. At λ = 1000
    // (a data term 10x weaker than the mapping default) TV bends the plane (it flattens towards
    // the borders and plateaus where the data is ambiguous) while the normal prior, whose null
    // space is the plane, keeps it. One hypothesis spacing is 0.9/63 = 0.0143 1/m. Measured
    // (inverse-depth rms, 1/m): 45° TV 0.00205, normals 0.00030; 55° TV 0.00599, normals 0.00050;
    // at λ = 10000 (55°) TV 0.223, normals 0.00034; at the default λ = 100 both are within 0.0014
    // (normals 0.00100 / 0.00116, TV 0.00102 / 0.00138).
    for degrees in [45.0, 55.0] {
        let [wta, tv, nm, gt] = rgb_plane_case(degrees, 1000.0);
        let (e_wta, e_tv, e_nm) = (rms(&wta, &gt), rms(&tv, &gt), rms(&nm, &gt));
        eprintln!("plane at {degrees}°, λ 1000: inverse-depth rms WTA {e_wta:.5}, TV {e_tv:.5}, normals {e_nm:.5} 1/m");
        assert!(e_nm < 0.1 * 0.0143, "{degrees}°: normal prior rms {e_nm}");
        assert!(e_nm < e_tv / 3.0, "{degrees}°: normals {e_nm} vs TV {e_tv}");
        assert!(e_tv > 0.1 * 0.0143, "{degrees}°: TV {e_tv} did not bend: the case shows nothing");
    }
}

#[test]
fn normals_files_are_checked_and_resampled() {
    let dir = tempfile::tempdir().unwrap();
    let (h, w) = (6, 8);
    let mut good = Array3::<f32>::zeros((h, w, 3));
    good.slice_mut(s![.., .., 2]).fill(-1.0);
    good[[1, 1, 2]] = 0.0; // the zero vector: no normal
    let p = dir.path().join("00003.npy");
    write_npy_f32(&p, good.view()).unwrap();
    let n = read_normals(&p, h, w).unwrap();
    assert_eq!(n[[0, 0, 2]], -1.0);
    assert!(n[[1, 1, 0]].is_nan(), "a zero vector is no normal");
    let coarse = normals_at_level(n.view(), 1);
    assert_eq!(coarse.dim(), (3, 4, 3));
    assert_eq!(coarse[[1, 2, 2]], n[[2, 4, 2]]);
    // Wrong shape, non-finite values, non-unit normals: errors naming the file.
    let err = read_normals(&p, h + 1, w).unwrap_err().to_string();
    assert!(err.contains("00003.npy") && err.contains("shape"), "{err}");
    let mut bad = good.clone();
    bad[[2, 3, 0]] = f32::NAN;
    write_npy_f32(&p, bad.view()).unwrap();
    let err = read_normals(&p, h, w).unwrap_err().to_string();
    assert!(err.contains("00003.npy") && err.contains("non-finite"), "{err}");
    let mut long = good.clone();
    long[[2, 3, 2]] = -1.5;
    write_npy_f32(&p, long.view()).unwrap();
    let err = read_normals(&p, h, w).unwrap_err().to_string();
    assert!(err.contains("00003.npy") && err.contains("norm"), "{err}");
}

#[test]
fn slope_falls_back_at_grazing_views_and_without_normals() {
    let cam = camera();
    // A normal perpendicular to the central ray (grazing) and a missing one.
    assert_eq!(slope([1.0, 0.0, 0.0], cam.cx, cam.cy, &cam), None);
    assert_eq!(slope([f64::NAN, 0.0, -1.0], 10.0, 10.0, &cam), None);
    assert_eq!(slope([0.0, 0.0, 0.0], 10.0, 10.0, &cam), None);
    let mut n = Array3::<f32>::from_elem((cam.height, cam.width, 3), f32::NAN);
    n.slice_mut(s![.., ..80, 2]).fill(-1.0);
    n.slice_mut(s![.., ..80, 0]).fill(0.0);
    n.slice_mut(s![.., ..80, 1]).fill(0.0);
    let q = SlopeField::new(n.view(), &cam).unwrap();
    assert_eq!(q.fallback, cam.height * (cam.width - 80));
    assert!(q.qx.iter().all(|&v| v == 0.0), "a fronto-parallel normal predicts a zero slope");
    assert!(SlopeField::new(n.slice(s![..10, .., ..]), &cam).is_err(), "the grid must match");
}

#[test]
fn normal_prior_without_normals_is_refused_naming_the_missing_predictor() {
    use densefeat::mapping::normals::NormalsSource;
    use densefeat::mapping::{reconstruct, KeyframeConfig, Regularizer};
    assert_eq!("normals".parse::<Regularizer>().unwrap(), Regularizer::Normals);
    let e = "smooth".parse::<Regularizer>().unwrap_err().to_string();
    assert!(e.contains("--regularizer") && e.contains("normals"), "{e}");
    assert_eq!("gt".parse::<NormalsSource>().unwrap(), NormalsSource::GroundTruth);
    let e = "/no/such/normals".parse::<NormalsSource>().unwrap_err().to_string();
    assert!(e.contains("--normals") && e.contains("/no/such/normals"), "{e}");
    let seq = densefeat::sequence::open(concat!(env!("CARGO_MANIFEST_DIR"), "/fixtures/synthetic/room_s1"))
        .unwrap();
    let mut cfg = KeyframeConfig::new(2, 0.5, 10.0);
    cfg.regularizer = Regularizer::Normals;
    let e = reconstruct(&seq, &cfg, |_, _, _| ()).unwrap_err().to_string();
    assert!(e.contains("--normals learned") && e.contains("--normals gt"), "{e}");
    // A folder without the keyframe's file: the error names both candidate files.
    let dir = tempfile::tempdir().unwrap();
    cfg.normals = Some(NormalsSource::Dir(dir.path().to_path_buf()));
    let e = reconstruct(&seq, &cfg, |_, _, _| ()).unwrap_err().to_string();
    assert!(e.contains("00002.npy"), "{e}");
}

/// SPEC.md §10.2, "Confidence weighting": `q ← clamp(conf / c₀, 0, 1) q` per pixel, the product in
/// f64 rounded to f32 once; `c₀ = 0` is off (the same bits); `Q` recomputed, `fallback` kept; a bad
/// `c₀` or a confidence map on another grid is refused naming the flag.
#[test]
fn confidence_weighting_scales_the_slope_where_the_volume_is_unsure() {
    let (h, w) = (7, 9);
    let mut q = random_field(h, w, 0.02, 5);
    q.fallback = 11;
    let mut conf = Array2::<f32>::zeros((h, w));
    let mut r = stream(9);
    conf.iter_mut().for_each(|c| *c = r() as f32);
    conf[[0, 0]] = 0.0;
    conf[[1, 1]] = 1.0;
    let off = q.weighted_by_confidence(conf.view(), 0.0).unwrap();
    assert_eq!(
        (off.qx.clone(), off.qy.clone(), off.max_norm, off.fallback),
        (q.qx.clone(), q.qy.clone(), q.max_norm, 11)
    );
    let c0 = 0.4;
    let got = q.weighted_by_confidence(conf.view(), c0).unwrap();
    for y in 0..h {
        for x in 0..w {
            let wt = (f64::from(conf[[y, x]]) / c0).clamp(0.0, 1.0);
            assert_eq!(got.qx[[y, x]], (f64::from(q.qx[[y, x]]) * wt) as f32, "({y}, {x})");
            assert_eq!(got.qy[[y, x]], (f64::from(q.qy[[y, x]]) * wt) as f32, "({y}, {x})");
            if conf[[y, x]] as f64 >= c0 {
                assert_eq!(
                    (got.qx[[y, x]], got.qy[[y, x]]),
                    (q.qx[[y, x]], q.qy[[y, x]]),
                    "confident: unchanged"
                );
            }
        }
    }
    assert_eq!((got.qx[[0, 0]], got.qy[[0, 0]]), (0.0, 0.0), "no confidence: plain TV");
    let want_q =
        got.qx.iter().zip(got.qy.iter()).map(|(&a, &b)| (a as f64).hypot(b as f64)).fold(0.0, f64::max);
    assert_eq!(got.max_norm, want_q);
    assert!(got.max_norm <= q.max_norm);
    assert_eq!(got.fallback, 11);
    for bad in [-0.1, f64::NAN, f64::INFINITY] {
        let e = q.weighted_by_confidence(conf.view(), bad).unwrap_err().to_string();
        assert!(e.contains("prior-confidence"), "{bad}: {e}");
    }
    let e = q.weighted_by_confidence(conf.slice(s![..3, ..]), c0).unwrap_err().to_string();
    assert!(e.contains("prior-confidence"), "{e}");
}
