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

/// The angle between two normals by another route than `normal_edge_weights`' (`atan2` of the
/// cross product's norm and the dot product, f64), 0 where either has no normal.
fn angle_deg(a: [f64; 3], b: [f64; 3]) -> f64 {
    let ok = |n: [f64; 3]| n.iter().all(|v| v.is_finite()) && n.iter().any(|&v| v != 0.0);
    if !(ok(a) && ok(b)) {
        return 0.0;
    }
    let c = [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
    let cross = (c[0] * c[0] + c[1] * c[1] + c[2] * c[2]).sqrt();
    let dot = a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    cross.atan2(dot).to_degrees()
}

#[test]
fn normal_edge_weights_follow_the_angle_to_the_forward_neighbours() {
    // Random normals with holes (NaN, zero vectors), any length: w = exp(−(a/σ)²), a the larger
    // angle to the right and lower neighbour (0 at the last column / row and beside a hole).
    use densefeat::dtam::normal_prior::normal_edge_weights;
    let (h, w) = (9, 11);
    let mut r = stream(17);
    let mut n = Array3::<f32>::zeros((h, w, 3));
    for y in 0..h {
        for x in 0..w {
            let v = [r() * 2.0 - 1.0, r() * 2.0 - 1.0, -0.2 - r()];
            let len = 0.5 + 2.0 * r();
            for c in 0..3 {
                n[[y, x, c]] = (v[c] * len) as f32;
            }
        }
    }
    n[[2, 3, 0]] = f32::NAN;
    n.slice_mut(s![4, 5, ..]).fill(0.0);
    for sigma in [10.0, 30.0] {
        let got = normal_edge_weights(n.view(), sigma);
        let at = |y: usize, x: usize| [n[[y, x, 0]] as f64, n[[y, x, 1]] as f64, n[[y, x, 2]] as f64];
        for y in 0..h {
            for x in 0..w {
                let ax = if x + 1 < w { angle_deg(at(y, x), at(y, x + 1)) } else { 0.0 };
                let ay = if y + 1 < h { angle_deg(at(y, x), at(y + 1, x)) } else { 0.0 };
                let want = (-(ax.max(ay) / sigma).powi(2)).exp();
                assert!(
                    (got[[y, x]] as f64 - want).abs() <= 1e-6,
                    "σ {sigma} ({y}, {x}): {} vs {want}",
                    got[[y, x]]
                );
            }
        }
        assert_eq!(got[[h - 1, w - 1]], 1.0, "no forward neighbour: no edge");
        assert_eq!(got[[4, 5]], 1.0, "no normal: no edge");
    }
    // One plane (any scale of its normal): no edge anywhere.
    let flat =
        Array3::from_shape_fn((h, w, 3), |(y, x, c)| [0.3f32, -0.2, -0.9][c] * (1.0 + (y * w + x) as f32));
    assert!(normal_edge_weights(flat.view(), 30.0).iter().all(|&v| v == 1.0));
}

#[test]
fn normal_edges_switch_on_and_off_and_bad_values_are_refused() {
    let cam = camera();
    let (h, w) = (cam.height, cam.width);
    let n = Array3::from_shape_fn((h, w, 3), |(_, x, c)| {
        if x < 80 {
            [0.0f32, 0.0, -1.0][c]
        } else {
            [0.7f32, 0.0, -0.7][c]
        }
    });
    let q = SlopeField::new(n.view(), &cam).unwrap();
    assert!(q.edges.is_none(), "off unless asked");
    let off = q.clone().with_normal_edges(n.view(), 0.0).unwrap();
    assert!(off.edges.is_none() && off.qx == q.qx && off.qy == q.qy && off.max_norm == q.max_norm);
    let on = q.clone().with_normal_edges(n.view(), 30.0).unwrap();
    let e = on.edges.as_ref().unwrap();
    assert_eq!(
        (on.qx.clone(), on.qy.clone(), on.max_norm),
        (q.qx.clone(), q.qy.clone(), q.max_norm),
        "q unchanged"
    );
    assert!(
        e[[10, 79]] < 0.2 && e[[10, 78]] == 1.0 && e[[10, 80]] == 1.0,
        "{} {} {}",
        e[[10, 78]],
        e[[10, 79]],
        e[[10, 80]]
    );
    // The solver's weights: g times w, and g itself when off.
    let g = Array2::from_elem((h, w), 0.5f32);
    assert_eq!(on.solver_weights(g.clone()), &g * e);
    assert_eq!(off.solver_weights(g.clone()), g);
    // The confidence weighting keeps the edges.
    let conf = Array2::from_elem((h, w), 0.3f32);
    assert_eq!(on.weighted_by_confidence(conf.view(), 0.6).unwrap().edges.as_ref(), Some(e));
    for bad in [-1.0, f64::NAN, f64::INFINITY] {
        let msg = q.clone().with_normal_edges(n.view(), bad).unwrap_err().to_string();
        assert!(msg.contains("prior-edges"), "{bad}: {msg}");
    }
    let msg = q.clone().with_normal_edges(n.slice(s![..h - 1, .., ..]), 30.0).unwrap_err().to_string();
    assert!(msg.contains("prior-edges"), "{msg}");
}

/// A keyframe `[24, 48]` with no image edge anywhere: on the left (columns 0-15) a slanted plane
/// A, ρ = 0.7 − 0.02 (u − 15), in front of a fronto-parallel wall at ρ = 0.4 that fills the rest.
/// The data term knows A and the wall's right third (columns 32-47); the wall's middle third (B,
/// columns 16-31) has no data (every hypothesis costs the same). Returns the solve's ρ on B with
/// the normal prior (ground-truth normals) at normal-edge scale `sigma` (0: off).
fn occluded_wall_case(sigma: f64, threads: usize) -> Array2<f32> {
    use densefeat::geometry::{InverseDepthBins, PinholeCamera};
    let (h, w) = (24, 48);
    let cam = PinholeCamera::new(64.0, 64.0, 23.5, 11.5, w, h).unwrap();
    let bins = InverseDepthBins::new(0.1, 1.0, 64).unwrap();
    let truth = |x: usize| if x < 16 { 0.7 - 0.02 * (x as f64 - 15.0) } else { 0.4 };
    let costs = Array3::from_shape_fn((h, w, 64), |(_, x, k)| {
        if (16..32).contains(&x) {
            10.0
        } else {
            ((bins.rho(k) - truth(x)).abs() * 200.0).min(50.0) as f32
        }
    });
    // Normals from ρ = a + b (u − c_x): n ∝ (f_x b, 0, ρ(c_x)) (SPEC.md §10.2's `gt`).
    let n = Array3::from_shape_fn((h, w, 3), |(_, x, c)| {
        let (b, rho_c) = if x < 16 { (-0.02, truth(15) - 0.02 * (cam.cx - 15.0)) } else { (0.0, 0.4) };
        [(cam.fx * b) as f32, 0.0, rho_c as f32][c]
    });
    let q = SlopeField::new(n.view(), &cam).unwrap().with_normal_edges(n.view(), sigma).unwrap();
    let grey = Array2::from_elem((h, w), 128.0f32);
    let init =
        Array2::from_shape_fn((h, w), |(_, x)| if (16..32).contains(&x) { 0.55 } else { truth(x) as f32 });
    let params = DtamParams { lambda: 100.0, ..densefeat::dtam::MAPPING_DEFAULTS }.normalised(
        densefeat::costvolume::cost_scale(costs.view()),
        w,
        bins.rho_max - bins.rho_min,
    );
    let problem = DtamProblem::new(costs.view(), &bins, grey.view(), init.view(), &params).with_slope(&q);
    let (res, _) = with_threads(threads, || solve(&problem).unwrap());
    res.inverse_depth.slice(s![.., 16..32]).to_owned()
}

#[test]
fn normal_edges_stop_the_prior_carrying_a_plane_across_an_occlusion() {
    // Without an image edge at A's silhouette the prior couples the wall's data-free middle to A
    // as much as to the wall's own right third; with the normals' edges (A's normal turns 67.5°
    // from the wall's) it is coupled to the wall alone and takes its plane. One hypothesis is
    // 0.9/63 = 0.0143 1/m. Measured: without, a ramp from A's 0.65 down to 0.43 (rms 0.157); with,
    // 0.3955-0.3993 (rms 0.0034, the solver's schedule, not A: it lies below the wall, away from A).
    let err =
        |b: &Array2<f32>| (b.iter().map(|&v| (v as f64 - 0.4).powi(2)).sum::<f64>() / b.len() as f64).sqrt();
    let (off, on) = (occluded_wall_case(0.0, 1), occluded_wall_case(30.0, 1));
    let (e_off, e_on) = (err(&off), err(&on));
    eprintln!(
        "the wall's data-free middle, inverse-depth rms: no normal edges {e_off:.5}, σ 30° {e_on:.5} 1/m"
    );
    assert!(e_on < 0.3 * 0.0143, "with the normals' edges {e_on}");
    assert!(e_off > 20.0 * e_on && e_off > 0.0143, "without them {e_off}: the case shows nothing");
    for n in [2, 3, 8] {
        assert!(occluded_wall_case(30.0, n) == on, "threads = {n}");
    }
}
