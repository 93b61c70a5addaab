//! Sampling, undistortion and depth-metric tests (SPEC.md §2.1, §2.7, §3).

use crate::common;

use approx::assert_relative_eq;
use densefeat::eval::depth_metrics;
use densefeat::geometry::{PinholeCamera, RadTan};
use densefeat::image::{sample_bilinear, UndistortMap};
use ndarray::{array, Array2, Array3};
use proptest::prelude::*;

/// Plain f64 bilinear interpolation written from the definition (the reference).
fn bilinear_reference(img: &Array3<f32>, x: f64, y: f64, c: usize) -> Option<f64> {
    let (h, w, _) = img.dim();
    if x < 0.0 || y < 0.0 || x > (w - 1) as f64 || y > (h - 1) as f64 {
        return None;
    }
    let mut acc = 0.0;
    for yy in 0..h {
        for xx in 0..w {
            let wx = (1.0 - (x - xx as f64).abs()).max(0.0);
            let wy = (1.0 - (y - yy as f64).abs()).max(0.0);
            acc += wx * wy * img[[yy, xx, c]] as f64;
        }
    }
    Some(acc)
}

fn image(h: usize, w: usize, seed: u64) -> Array3<f32> {
    let mut s = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
    Array3::from_shape_fn((h, w, 2), |_| {
        s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        ((s >> 40) % 256) as f32
    })
}

proptest! {
    #[test]
    fn bilinear_matches_tent_filter_reference(h in 1usize..6, w in 1usize..6, seed: u64,
                                              fx in -0.2..1.2f64, fy in -0.2..1.2f64) {
        let img = image(h, w, seed);
        let (x, y) = (fx * (w - 1) as f64, fy * (h - 1) as f64);
        let mut out = [0.0f32; 2];
        let inside = sample_bilinear(&img.view(), x, y, &mut out);
        for (c, &got) in out.iter().enumerate() {
            let want = bilinear_reference(&img, x, y, c);
            prop_assert_eq!(inside, want.is_some());
            if let Some(want) = want {
                // 4-term convex combination of values <= 255, computed in f64 and rounded once.
                prop_assert!((got as f64 - want).abs() <= 255.0 * f32::EPSILON as f64, "{} vs {}", got, want);
            }
        }
    }
}

#[test]
fn bilinear_at_integer_coordinates_returns_the_pixel() {
    let img = image(4, 5, 3);
    let mut out = [0.0f32; 2];
    for y in 0..4 {
        for x in 0..5 {
            assert!(sample_bilinear(&img.view(), x as f64, y as f64, &mut out));
            assert_eq!(out, [img[[y, x, 0]], img[[y, x, 1]]]);
        }
    }
    assert!(!sample_bilinear(&img.view(), 4.0 + 1e-9, 0.0, &mut out));
    assert!(!sample_bilinear(&img.view(), -1e-9, 0.0, &mut out));
}

#[test]
fn undistort_map_recovers_a_pinhole_rendering() {
    // Render a smooth pattern through a distorted camera, undistort, compare with the pinhole
    // rendering of the same pattern.
    let k = PinholeCamera::new(120.0, 118.0, 63.5, 47.5, 128, 96).unwrap();
    let d = RadTan { k1: 0.2624, k2: -0.9531, p1: -0.0054, p2: 0.0026, k3: 1.1633 };
    let pattern = |x: f64, y: f64| 128.0 + 100.0 * (3.0 * x).sin() * (2.0 * y).cos();
    let (pinhole, raw) = common::pinhole_and_distorted(&k, &d, pattern);
    let out = UndistortMap::new(&k, &d).rgb(&raw);
    let mut worst = 0.0f32;
    for v in 4..92 {
        for u in 4..124 {
            worst = worst.max((out[[v, u, 0]] - pinhole[[v, u, 0]]).abs());
        }
    }
    // Bilinear interpolation error of a smooth pattern sampled at ~1 px: well under a grey level.
    assert!(worst < 0.5, "worst undistortion error {worst}");
}

#[test]
fn metrics_match_hand_computation() {
    // Two valid pixels: pred 2 vs gt 1 (ratio 2), pred 1.1 vs gt 1 (ratio 1.1); one invalid gt,
    // one missing prediction.
    let gt: Array2<f32> = array![[1.0, 1.0], [0.0, 2.0]];
    let pred: Array2<f32> = array![[2.0, 1.1], [5.0, 0.0]];
    let m = depth_metrics(pred.view(), gt.view()).unwrap();
    assert_eq!(m.count, 2);
    assert_relative_eq!(m.coverage, 2.0 / 3.0);
    let d1 = 1.0f64;
    let d2 = 1.1f32 as f64 - 1.0;
    assert_relative_eq!(m.rms, ((d1 * d1 + d2 * d2) / 2.0).sqrt(), epsilon = 1e-12);
    let l2 = (1.1f32 as f64).ln();
    assert_relative_eq!(m.log_rms, ((2f64.ln().powi(2) + l2 * l2) / 2.0).sqrt(), epsilon = 1e-12);
    assert_relative_eq!(m.abs_rel, (1.0 + d2) / 2.0, epsilon = 1e-12);
    assert_relative_eq!(m.sq_rel, (1.0 + d2 * d2) / 2.0, epsilon = 1e-12);
    // ratio 1.1f32 is slightly above 1.1, so only the 1.25-based thresholds count it.
    assert_eq!(m.delta_1_1, 0.0);
    assert_eq!(m.delta_1_25, 0.5);
    assert_eq!(m.delta_1_25_2, 0.5);
    assert_eq!(m.delta_1_25_3, 0.5);
    let perfect = depth_metrics(gt.view(), gt.view()).unwrap();
    assert_eq!((perfect.rms, perfect.delta_1_1, perfect.count), (0.0, 1.0, 3));
}

#[test]
fn metrics_reject_mismatched_or_empty_inputs() {
    let a = Array2::<f32>::zeros((2, 2));
    let b = Array2::<f32>::zeros((2, 3));
    assert!(depth_metrics(a.view(), b.view()).is_err());
    let err = depth_metrics(a.view(), a.view()).unwrap_err().to_string();
    assert!(err.contains("no pixel"), "{err}");
}
