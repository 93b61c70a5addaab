//! The strong mapper (SPEC.md §9.10-§9.12, §10.1, §11.1): level-0 output and the feature
//! upsampling, the evidence filter, winner-take-all on a cost array, the cost scale that makes one
//! normalised λ serve every feature kind, the confidence map and its mask, DTAM's convergence stop,
//! and the 640x480 x 128 memory figure. Tiny shapes throughout.

use std::path::Path;

use densefeat::costvolume::{
    confidence, cost_scale, filter_evidence, winner_take_all_costs, CostVolume, CostVolumeImpl, UNSEEN_COST,
};
use densefeat::dtam::{solve, DtamParams, DtamProblem, MAPPING_DEFAULTS, REFERENCE_WIDTH};
use densefeat::geometry::{InverseDepthBins, PinholeCamera, Pose};
use densefeat::mapping::evaluate::{evaluate, EvalOptions, Method};
use densefeat::mapping::features::{upsample_to, upsample_to_reference};
use densefeat::mapping::keyframe::{memory_estimate, reconstruct, KeyframeConfig};
use densefeat::mapping::{FeatureExtractor, FeatureKind};
use densefeat::sequence::open;
use nalgebra::{Translation3, UnitQuaternion};
use ndarray::{Array2, Array3};

const FIXTURE: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/fixtures/synthetic/room_s1");

fn stream(seed: u64) -> impl FnMut() -> f64 {
    let mut s = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
    move || {
        s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        (s >> 11) as f64 / (1u64 << 53) as f64
    }
}

fn threads<T: Send>(n: usize, f: impl FnOnce() -> T + Send) -> T {
    rayon::ThreadPoolBuilder::new().num_threads(n).build().unwrap().install(f)
}

#[test]
fn upsampling_reproduces_bilinear_on_the_integer_centre_grid() {
    // f(i, j) = 3 i + 5 j + c (affine), so bilinear interpolation is exact: fine pixel (y, x)
    // sits at coarse (y/2, x/2), clamped to the last coarse pixel.
    let (h, w, c) = (5, 7, 3);
    let coarse = Array3::from_shape_fn((h, w, c), |(i, j, ch)| (3 * i + 5 * j + ch) as f32);
    let (oh, ow) = (2 * h - 1 + 1, 2 * w); // 10 x 14: the last row/column reach past the coarse grid
    let fine = upsample_to(coarse.view(), 1, oh, ow);
    assert_eq!(fine.dim(), (oh, ow, c));
    for ((y, x, ch), &v) in fine.indexed_iter() {
        let (cy, cx) = ((y as f64 / 2.0).min((h - 1) as f64), (x as f64 / 2.0).min((w - 1) as f64));
        let want = 3.0 * cy + 5.0 * cx + ch as f64;
        assert_eq!(v, want as f32, "({y}, {x}, {ch})");
    }
    // Even output pixels are the coarse pixels themselves, bit for bit.
    for i in 0..h {
        for j in 0..w {
            assert_eq!(fine[[2 * i, 2 * j, 1]].to_bits(), coarse[[i, j, 1]].to_bits());
        }
    }
    // Two levels: pixel 4i is coarse pixel i.
    let fine2 = upsample_to(coarse.view(), 2, 4 * h, 4 * w);
    assert_eq!(fine2[[8, 12, 0]], coarse[[2, 3, 0]]);
    let mut r = stream(3);
    let noise = Array3::from_shape_fn((6, 9, 35), |_| r() as f32);
    let a = threads(1, || upsample_to(noise.view(), 1, 12, 18));
    for n in [2, 3, 8] {
        assert_eq!(a, threads(n, || upsample_to(noise.view(), 1, 12, 18)), "{n} threads");
    }
}

#[test]
fn upsampling_equals_its_per_pixel_definition_bit_for_bit() {
    // The row kernel (column corners formed once, contiguous channel loop, AVX-512F build where the
    // CPU has it) against `sample_bilinear` per pixel: channel counts around the vector widths,
    // one-pixel-wide and -high maps, 1 and 2 levels, outputs reaching past the coarse grid,
    // special values.
    let mut r = stream(11);
    for (h, w, c, levels, oh, ow) in [
        (5, 7, 32, 1, 10, 14),
        (4, 6, 3, 1, 7, 11),
        (1, 5, 9, 1, 2, 10),
        (6, 1, 17, 2, 24, 3),
        (3, 4, 1, 2, 9, 13),
        (2, 2, 35, 1, 4, 4),
    ] {
        let specials = [f32::NAN, f32::INFINITY, -0.0, 1e-40, -3.0e38];
        let x = Array3::from_shape_fn((h, w, c), |_| {
            let v = r();
            if v < 0.03 {
                specials[(v * 1000.0) as usize % specials.len()]
            } else {
                (v * 200.0 - 100.0) as f32
            }
        });
        let want = upsample_to_reference(x.view(), levels, oh, ow);
        // The process's level, and each level handed in explicitly (issue 33 item 3).
        let mut runs = vec![upsample_to(x.view(), levels, oh, ow)];
        for level in densefeat::runtime::CpuFeatureLevel::ALL {
            runs.push(densefeat::mapping::features::upsample_to_at(x.view(), levels, oh, ow, level));
        }
        for got in runs {
            assert_eq!(got.dim(), want.dim());
            for (a, b) in got.iter().zip(&want) {
                assert!(a.to_bits() == b.to_bits() || (a.is_nan() && b.is_nan()), "{h}x{w}x{c}: {a} vs {b}");
            }
        }
    }
}

#[test]
fn level0_output_has_the_input_resolution_and_level0_ground_truth() {
    let seq = open(Path::new(FIXTURE)).unwrap();
    let frame = seq.load_frame(20).unwrap();
    let (h0, w0, _) = frame.rgb.dim();
    for features in [FeatureKind::Rgb, FeatureKind::Learned(None)] {
        let mut cfg = KeyframeConfig::new(20, 0.4, 10.0);
        (cfg.past, cfg.future, cfg.bins, cfg.features) = (1, 1, 8, features);
        cfg.dtam.iterations = 5;
        cfg.dtam.max_iterations = 5;
        let r = reconstruct(&seq, &cfg, |_, _, _| {}).unwrap();
        assert_eq!(r.level, 0);
        assert_eq!((r.camera.height, r.camera.width), (h0, w0));
        assert_eq!(r.wta.depth.dim(), (h0, w0));
        assert_eq!(r.tv.as_ref().unwrap().depth.dim(), (h0, w0));
        assert_eq!(r.confidence.dim(), (h0, w0));
        assert_eq!(r.camera, seq.camera);
        let gt = r.gt_depth.as_ref().unwrap();
        assert_eq!(gt, frame.depth.as_ref().unwrap(), "GT is compared at the output level");
        assert_eq!(r.colour, frame.rgb);
    }
    // Learned features at level 0 are the network's level-1 features upsampled (shipped weights
    // have block-1 stride 2).
    let l0 =
        FeatureExtractor::new(FeatureKind::Learned(None), 0, densefeat::backend::default_backend()).unwrap();
    let l1 =
        FeatureExtractor::new(FeatureKind::Learned(None), 1, densefeat::backend::default_backend()).unwrap();
    assert_eq!(l0.network_output_level(), Some(1));
    let f0 = l0.extract(&frame.rgb).unwrap().data;
    let f1 = l1.extract(&frame.rgb).unwrap().data;
    assert_eq!(f0, upsample_to(f1.view(), 1, h0, w0));
}

#[test]
fn memory_estimate_of_640x480_with_128_bins() {
    // f32 sums + f32 costs + u16 counts per cell, DTAM's block minima (one f32 per 8 cells) and two
    // 32-channel feature maps.
    let b = memory_estimate(480, 640, 128, 32);
    assert_eq!(b, 480 * 640 * 128 * 10 + 480 * 640 * 16 * 4 + 2 * 480 * 640 * 32 * 4);
    assert_eq!(b, 491_520_000); // 468.75 MiB, under the 2048 MiB default limit
}

#[test]
fn evidence_filter_drops_thinly_seen_cells() {
    let counts = Array3::from_shape_vec((1, 2, 4), vec![10u16, 4, 3, 0, 2, 2, 1, 0]).unwrap();
    let base =
        Array3::from_shape_vec((1, 2, 4), vec![5.0f32, 1.0, 2.0, UNSEEN_COST, 3.0, 1.0, 0.5, UNSEEN_COST])
            .unwrap();
    let mut c = base.clone();
    filter_evidence(&mut c, counts.view(), 0.0);
    assert_eq!(c, base, "fraction 0 keeps every seen cell");
    let mut c = base.clone();
    filter_evidence(&mut c, counts.view(), 0.35);
    // Pixel 0: N_u = 10, threshold ceil(3.5) = 4: count 3 drops. Pixel 1: N_u = 2, threshold 1.
    assert_eq!(c.as_slice().unwrap(), &[5.0, 1.0, UNSEEN_COST, UNSEEN_COST, 3.0, 1.0, 0.5, UNSEEN_COST]);
    let mut c = base.clone();
    filter_evidence(&mut c, counts.view(), 1.0);
    assert_eq!(
        c.as_slice().unwrap(),
        &[5.0, UNSEEN_COST, UNSEEN_COST, UNSEEN_COST, 3.0, 1.0, UNSEEN_COST, UNSEEN_COST]
    );
    // The WTA of the filtered array: pixel 0 picks bin 0 (the only cell left), pixel 1 bin 1.
    let bins = InverseDepthBins::new(0.1, 1.0, 4).unwrap();
    let w = winner_take_all_costs(c.view(), &bins);
    assert_eq!(w.bin[[0, 0]], 0.0);
    assert!(w.valid[[0, 1]] && w.bin[[0, 1]] < 1.5);
}

fn small_volume(seed: u64, scale: f32) -> CostVolume {
    let (h, w, c, k) = (9, 12, 3, 10);
    let cam = PinholeCamera::new(10.0, 10.0, 5.5, 4.0, w, h).unwrap();
    let mut r = stream(seed);
    let img = Array3::from_shape_fn((h, w, c), |_| (r() * 255.0) as f32 * scale);
    let bins = InverseDepthBins::new(0.2, 2.0, k).unwrap();
    let mut cv = CostVolume::with_impl(img.clone(), cam, bins, CostVolumeImpl::Fast).unwrap();
    for i in 1..=3 {
        let t = Translation3::new(0.05 * i as f64, -0.02, 0.01);
        let q = UnitQuaternion::from_euler_angles(0.0, 0.01 * i as f64, 0.0);
        let live = Array3::from_shape_fn((h, w, c), |(y, x, ch)| {
            img[[y, (x + i) % w, ch]] + (r() * 10.0) as f32 * scale
        });
        cv.add_frame(live.view(), &Pose::from_parts(t, q)).unwrap();
    }
    cv
}

#[test]
fn wta_on_the_cost_array_matches_the_volume() {
    let cv = small_volume(1, 1.0);
    let a = cv.winner_take_all();
    let b = winner_take_all_costs(cv.costs().view(), cv.bins());
    assert_eq!(a.inverse_depth, b.inverse_depth);
    assert_eq!(a.valid, b.valid);
    assert_eq!(a.bin, b.bin);
    assert_eq!(a.depth, b.depth);
}

#[test]
fn normalised_dtam_does_not_depend_on_the_feature_scale() {
    // Features x4 (a power of two: every cost and the scale are exactly x4): the normalised
    // solve gives the same bits.
    let run = |scale: f32| {
        let cv = small_volume(2, scale);
        let costs = cv.costs();
        let s = cost_scale(costs.view());
        let w = winner_take_all_costs(costs.view(), cv.bins());
        let grey = Array2::from_elem(w.inverse_depth.dim(), 100.0f32);
        let p = DtamParams { iterations: 30, max_iterations: 40, ..MAPPING_DEFAULTS }.normalised(
            s,
            12,
            cv.bins().rho_max - cv.bins().rho_min,
        );
        let (res, report) =
            solve(&DtamProblem::new(costs.view(), cv.bins(), grey.view(), w.inverse_depth.view(), &p))
                .unwrap();
        (s, res.inverse_depth, report.iterations)
    };
    let (s1, d1, n1) = run(1.0);
    let (s4, d4, n4) = run(4.0);
    assert!(s1 > 0.0);
    assert_eq!(s4, 4.0 * s1);
    assert_eq!(d1, d4);
    assert_eq!(n1, n4);
}

#[test]
fn normalised_parameters_follow_the_stated_formulas() {
    let p = DtamParams { lambda: 10.0, theta_start: 0.5, theta_end: 1e-4, epsilon: 2e-3, ..MAPPING_DEFAULTS };
    let q = p.normalised(3.0, 320, 2.0);
    let r = 320.0 / REFERENCE_WIDTH;
    assert_eq!(q.lambda, 10.0 * 3.0 * r);
    assert_eq!(q.theta_start, 0.5 * 4.0 * 10.0 * r);
    assert_eq!(q.theta_end, 1e-4 * 4.0 * 10.0 * r);
    assert_eq!(q.epsilon, 2e-3 / r);
    assert_eq!((q.iterations, q.alpha, q.beta), (p.iterations, p.alpha, p.beta));
    assert!(DtamParams { steps_per_search: 0, ..MAPPING_DEFAULTS }.validate().is_err());
    assert!(DtamParams { max_iterations: 10, iterations: 20, ..MAPPING_DEFAULTS }.validate().is_err());
    assert!(DtamParams { tolerance: -1.0, ..MAPPING_DEFAULTS }.validate().is_err());
}

#[test]
fn dtam_stops_on_convergence_after_the_schedule() {
    let cv = small_volume(4, 1.0);
    let costs = cv.costs();
    let w = winner_take_all_costs(costs.view(), cv.bins());
    let grey = Array2::from_elem(w.inverse_depth.dim(), 50.0f32);
    let base = DtamParams { iterations: 20, max_iterations: 400, ..MAPPING_DEFAULTS };
    let p = base.normalised(cost_scale(costs.view()), 12, 1.8);
    let (_, report) =
        solve(&DtamProblem::new(costs.view(), cv.bins(), grey.view(), w.inverse_depth.view(), &p)).unwrap();
    assert!(report.converged);
    assert!(report.iterations >= 20 && report.iterations < 400, "{}", report.iterations);
    assert_eq!(report.gap.len(), report.iterations);
    assert!(*report.gap.last().unwrap() <= 0.1 * cv.bins().step());
    let n = report.iterations;
    let e = &report.energy;
    assert!((e[n - 1] - e[n - 2]).abs() <= 1e-3 * e[n - 1].abs().max(e[n - 2].abs()));
    // A cap below convergence: stops there, not converged.
    let capped = DtamParams { max_iterations: 20, ..base }.normalised(cost_scale(costs.view()), 12, 1.8);
    let (_, r2) =
        solve(&DtamProblem::new(costs.view(), cv.bins(), grey.view(), w.inverse_depth.view(), &capped))
            .unwrap();
    assert_eq!(r2.iterations, 20);
    // More primal-dual steps per search also converge, and the result is thread-independent.
    let steps = DtamParams { steps_per_search: 3, ..p };
    let a = threads(1, || {
        solve(&DtamProblem::new(costs.view(), cv.bins(), grey.view(), w.inverse_depth.view(), &steps))
            .unwrap()
    });
    let b = threads(3, || {
        solve(&DtamProblem::new(costs.view(), cv.bins(), grey.view(), w.inverse_depth.view(), &steps))
            .unwrap()
    });
    assert_eq!(a.0.inverse_depth, b.0.inverse_depth);
    assert_eq!(a.1.energy, b.1.energy);
}

#[test]
fn confidence_is_sharpness_times_evidence() {
    // Pixel 0: sharp curve seen by all 4 frames; pixel 1: flat; pixel 2: one seen cell.
    let costs = Array3::from_shape_vec(
        (1, 3, 4),
        vec![0.0f32, 4.0, 4.0, 8.0, 2.0, 2.0, 2.0, 2.0, 1.0, UNSEEN_COST, UNSEEN_COST, UNSEEN_COST],
    )
    .unwrap();
    let counts = Array3::from_shape_vec((1, 3, 4), vec![4u16, 4, 4, 4, 2, 2, 2, 2, 4, 0, 0, 0]).unwrap();
    let c = confidence(costs.view(), counts.view(), 4);
    assert_eq!(c[[0, 0]], 1.0); // min 0, median 4
    assert_eq!(c[[0, 1]], 0.0); // flat
    assert_eq!(c[[0, 2]], 0.0); // fewer than two seen cells
    let counts_half = Array3::from_shape_vec((1, 3, 4), vec![2u16, 4, 4, 4, 2, 2, 2, 2, 4, 0, 0, 0]).unwrap();
    assert_eq!(confidence(costs.view(), counts_half.view(), 4)[[0, 0]], 0.5);
    let cv = small_volume(5, 1.0);
    let c = confidence(cv.costs().view(), cv.counts_view(), cv.frames());
    assert!(c.iter().all(|v| (0.0..=1.0).contains(v)));
    assert_eq!(c, threads(3, || confidence(cv.costs().view(), cv.counts_view(), cv.frames())));
}

#[test]
fn min_confidence_masks_depth_and_lowers_coverage_and_eval_sweeps_run() {
    let seq = open(Path::new(FIXTURE)).unwrap();
    let mut cfg = KeyframeConfig::new(20, 0.4, 10.0);
    (cfg.past, cfg.future, cfg.bins, cfg.level) = (2, 2, 16, 1);
    (cfg.dtam.iterations, cfg.dtam.max_iterations) = (10, 10);
    let r = reconstruct(&seq, &cfg, |_, _, _| {}).unwrap();
    let median = {
        let mut v: Vec<f32> = r.confidence.iter().copied().collect();
        v.sort_by(f32::total_cmp);
        v[v.len() / 2]
    };
    let masked = r.masked(&r.wta, median);
    for ((y, x), &z) in masked.depth.indexed_iter() {
        let want = if r.confidence[[y, x]] < median { 0.0 } else { r.wta.depth[[y, x]] };
        assert_eq!(z, want);
    }
    let full = r.metrics(&r.wta).unwrap();
    let conf = r.metrics_at(&r.wta, median).unwrap();
    assert!(conf.coverage < full.coverage && conf.count < full.count);
    let options = EvalOptions {
        lambda_sweep: vec![10.0, 1000.0],
        confidence_sweep: vec![0.0, median],
        min_confidence: median,
        ..EvalOptions::default()
    };
    let t =
        evaluate(&seq, &cfg, &[20], &[Method::RgbWta, Method::RgbTv], &options, |_| Ok(()), |_, _, _, _| {})
            .unwrap();
    assert_eq!(t.sweep.len(), 2);
    assert!(t.sweep.iter().all(|(m, _, _)| *m == Method::RgbTv));
    assert_eq!(t.confidence_sweep.len(), 4);
    assert!(t.rows[0].confident.coverage < t.rows[0].metrics.coverage);
    assert!(t.markdown().contains(&format!("rgb-wta@{median}")));
}
