//! The photometric sub-bin refinement (SPEC.md §10.3): the fast path against its plain-loop
//! reference, thread counts, a rendered plane it must sharpen, and the inputs it must refuse.

use crate::common;
use densefeat::geometry::{InverseDepthBins, PinholeCamera, Pose};
use densefeat::mapping::refine::{
    refine_estimate, refine_level0, refine_level0_reference, select_frames, upsample, Level0, RefineParams,
    RefineView, REFINE_DEFAULTS,
};
use nalgebra::{Translation3, UnitQuaternion, Vector3};
use ndarray::Array2;
use proptest::prelude::*;

/// A slanted textured plane `n·X = c` in the keyframe's camera frame.
struct Plane {
    n: Vector3<f64>,
    c: f64,
}

impl Plane {
    /// The keyframe's true inverse depth at pixel `(x, y)`.
    fn rho(&self, cam: &PinholeCamera, x: f64, y: f64) -> f64 {
        self.n.dot(&cam.ray(x, y)) / self.c
    }

    /// The grey image of the plane seen by a camera at `t_rn` (its points to keyframe points).
    fn render(&self, cam: &PinholeCamera, t_rn: &Pose) -> Array2<f64> {
        Array2::from_shape_fn((cam.height, cam.width), |(y, x)| {
            let o = t_rn.translation.vector;
            let d = t_rn.rotation * cam.ray(x as f64, y as f64);
            let s = (self.c - self.n.dot(&o)) / self.n.dot(&d);
            let p = o + d * s;
            128.0 + 50.0 * (7.0 * p.x).sin() * (5.0 * p.y).cos() + 35.0 * (23.0 * p.x + 17.0 * p.y).sin()
        })
    }
}

fn camera(w: usize, h: usize) -> PinholeCamera {
    PinholeCamera::new(40.0, 40.0, (w as f64 - 1.0) / 2.0, (h as f64 - 1.0) / 2.0, w, h).unwrap()
}

/// `T_rn` of a camera at `t` (keyframe frame) turned by small angles.
fn pose(t: [f64; 3], angles: [f64; 3]) -> Pose {
    Pose::from_parts(
        Translation3::new(t[0], t[1], t[2]),
        UnitQuaternion::from_euler_angles(angles[0], angles[1], angles[2]),
    )
}

struct Scene {
    cam: PinholeCamera,
    key: Array2<f64>,
    truth: Array2<f64>,
    greys: Vec<Array2<f64>>,
    poses: Vec<Pose>,
}

impl Scene {
    fn new(w: usize, h: usize, centres: &[[f64; 3]]) -> Scene {
        let cam = camera(w, h);
        let plane = Plane { n: Vector3::new(0.35, -0.2, 1.0).normalize(), c: 2.0 };
        let key = plane.render(&cam, &Pose::identity());
        let truth = Array2::from_shape_fn((h, w), |(y, x)| plane.rho(&cam, x as f64, y as f64));
        let rn: Vec<Pose> = centres.iter().map(|&t| pose(t, [0.01 * t[1], -0.02 * t[0], 0.005])).collect();
        let greys = rn.iter().map(|p| plane.render(&cam, p)).collect();
        // The views carry T_nr, the inverse of the rendering pose T_rn.
        let poses = rn.iter().map(|p| p.inverse()).collect();
        Scene { cam, key, truth, greys, poses }
    }

    fn views(&self) -> Vec<RefineView<'_>> {
        self.greys
            .iter()
            .zip(&self.poses)
            .map(|(g, p)| RefineView { grey: g.view(), camera: self.cam, pose: *p })
            .collect()
    }
}

const CENTRES: [[f64; 3]; 6] = [
    [0.3, 0.0, 0.0],
    [-0.3, 0.05, 0.0],
    [0.2, 0.2, 0.05],
    [-0.15, -0.2, 0.0],
    [0.4, -0.1, -0.05],
    [-0.4, 0.1, 0.02],
];

fn bits(a: &Array2<f64>) -> Vec<u64> {
    a.iter().map(|v| v.to_bits()).collect()
}

#[test]
fn refinement_sharpens_a_rendered_plane() {
    let s = Scene::new(64, 48, &CENTRES);
    let step = 0.04; // Δρ, 1/m: 1.6 px of disparity per bin over 0.4 m of baseline at f = 40
    let (h, w) = s.truth.dim();
    // The estimate off by +0.8 bin on the left half and -0.6 bin on the right.
    let rho0 =
        Array2::from_shape_fn((h, w), |(y, x)| s.truth[[y, x]] + if x < w / 2 { 0.8 } else { -0.6 } * step);
    let out = refine_level0(
        &Level0 { key: s.key.view(), camera: &s.cam, rho0: rho0.view(), views: &s.views(), step },
        &REFINE_DEFAULTS,
    )
    .unwrap();
    let r = REFINE_DEFAULTS.half_window;
    let (mut errors, mut candidates) = (Vec::new(), 0);
    for y in r..h - r {
        for x in r..w - r {
            // Windows that straddle the seam between the halves follow no one surface: not scored.
            if x + r + 1 > w / 2 && x < w / 2 + r {
                continue;
            }
            candidates += 1;
            if out[[y, x]].is_finite() {
                errors.push((out[[y, x]] - s.truth[[y, x]]).abs() / step);
            }
        }
    }
    errors.sort_by(f64::total_cmp);
    let refined = errors.len() as f64 / candidates as f64;
    let median = errors[errors.len() / 2];
    let p90 = errors[errors.len() * 9 / 10];
    // Before: every pixel 0.6-0.8 bin off.
    eprintln!("plane: refined {refined:.3}, median {median:.4} bins, 90th percentile {p90:.4} bins");
    assert!(refined > 0.9, "refined {refined}");
    assert!(median < 0.02, "median error {median} bins");
    assert!(p90 < 0.1, "90th percentile {p90} bins");
}

#[test]
fn flat_windows_and_missing_estimates_stay_put() {
    let s = Scene::new(40, 32, &CENTRES[..4]);
    let step = 0.04;
    let flat = Array2::from_elem(s.key.dim(), 90.0);
    let rho0 = s.truth.mapv(|v| v + 0.5 * step);
    let out = refine_level0(
        &Level0 { key: flat.view(), camera: &s.cam, rho0: rho0.view(), views: &s.views(), step },
        &REFINE_DEFAULTS,
    )
    .unwrap();
    assert!(out.iter().all(|v| v.is_nan()), "a flat keyframe window has nothing to match");
    // Without an estimate at a pixel, no window that contains it moves.
    let mut holed = rho0.clone();
    holed[[16, 20]] = f64::NAN;
    let out = refine_level0(
        &Level0 { key: s.key.view(), camera: &s.cam, rho0: holed.view(), views: &s.views(), step },
        &REFINE_DEFAULTS,
    )
    .unwrap();
    let r = REFINE_DEFAULTS.half_window;
    for y in 16 - r..=16 + r {
        for x in 20 - r..=20 + r {
            assert!(out[[y, x]].is_nan(), "({x}, {y}) moved with a hole in its window");
        }
    }
    assert!(out.iter().any(|v| v.is_finite()));
}

#[test]
fn faint_windows_below_the_variance_floor_stay_put() {
    // The plane's texture scaled down until no 7x7 keyframe window varies by more than 0.9 times
    // the default floor (9 grey levels²): camera noise, not texture, would decide those moves.
    let s = Scene::new(40, 32, &CENTRES[..4]);
    let step = 0.04;
    let r = REFINE_DEFAULTS.half_window;
    let (h, w) = s.key.dim();
    let mut max_var: f64 = 0.0;
    for y in r..h - r {
        for x in r..w - r {
            let win = s.key.slice(ndarray::s![y - r..=y + r, x - r..=x + r]);
            let m = win.mean().unwrap();
            max_var = max_var.max(win.mapv(|v| (v - m) * (v - m)).mean().unwrap());
        }
    }
    let k = (0.9 * REFINE_DEFAULTS.min_variance / max_var).sqrt();
    let faint = |a: &Array2<f64>| a.mapv(|v| 128.0 + k * (v - 128.0));
    let key = faint(&s.key);
    let greys: Vec<Array2<f64>> = s.greys.iter().map(faint).collect();
    let views: Vec<RefineView<'_>> = greys
        .iter()
        .zip(&s.poses)
        .map(|(g, p)| RefineView { grey: g.view(), camera: s.cam, pose: *p })
        .collect();
    let rho0 = s.truth.mapv(|v| v + 0.5 * step);
    let run = |p: &RefineParams| {
        refine_level0(&Level0 { key: key.view(), camera: &s.cam, rho0: rho0.view(), views: &views, step }, p)
            .unwrap()
    };
    assert!(run(&REFINE_DEFAULTS).iter().all(|v| v.is_nan()), "a window under the floor moved");
    // The same noiseless windows over a floor of 1 (before 2026-12-06) do move: the floor is what stops them.
    let moved = run(&RefineParams { min_variance: 1.0, ..REFINE_DEFAULTS });
    assert!(moved.iter().filter(|v| v.is_finite()).count() > 100);
}

#[test]
fn refinement_is_independent_of_thread_count() {
    let s = Scene::new(48, 40, &CENTRES);
    let step = 0.04;
    let rho0 = s.truth.mapv(|v| v + 0.7 * step);
    let run = |n| {
        common::thread_pool(n).install(|| {
            refine_level0(
                &Level0 { key: s.key.view(), camera: &s.cam, rho0: rho0.view(), views: &s.views(), step },
                &REFINE_DEFAULTS,
            )
            .unwrap()
        })
    };
    let one = bits(&run(1));
    for n in [2, 3, 8] {
        assert_eq!(one, bits(&run(n)), "{n} threads");
    }
}

#[test]
fn level1_estimate_moves_by_the_tent_mean_of_its_pixels() {
    let s = Scene::new(48, 40, &CENTRES);
    // The refinement's step is the range over 128 bins whatever the volume's count (Δρ ≈ 0.04).
    let bins = InverseDepthBins::new(0.1, 0.1 + 0.04 * 127.0, 61).unwrap();
    let step = (bins.rho_max - bins.rho_min) / 127.0;
    let at1 = s.cam.at_level(1);
    // A level-1 estimate off by 0.7 bin, one pixel without an estimate.
    let mut inv = Array2::from_shape_fn((at1.height, at1.width), |(j, i)| {
        (s.truth[[2 * j, 2 * i]] + 0.7 * step) as f32
    });
    inv[[10, 12]] = 0.0;
    let depth = inv.mapv(|r| if r > 0.0 { 1.0 / r } else { 0.0 });
    let views = s.views();
    let (new_inv, new_depth, report) =
        refine_estimate(inv.view(), depth.view(), 1, s.key.view(), &s.cam, &views, &bins, &REFINE_DEFAULTS)
            .unwrap();
    assert_eq!(report.frames, views.len());
    assert!(report.refined > 0 && report.refined <= report.candidates);
    // The pixel without an estimate keeps none.
    assert_eq!((new_inv[[10, 12]], new_depth[[10, 12]]), (0.0, 0.0));
    // Recompute one interior level-1 pixel by hand from the level-0 moves.
    let valid = inv.mapv(|r| r > 0.0);
    let rho0 = upsample(inv.view(), valid.view(), 1, s.cam.height, s.cam.width);
    let moved = refine_level0(
        &Level0 { key: s.key.view(), camera: &s.cam, rho0: rho0.view(), views: &views, step },
        &REFINE_DEFAULTS,
    )
    .unwrap();
    let (j, i) = (8, 9);
    let (mut num, mut den) = (0.0, 0.0);
    for y in 2 * j - 1..=2 * j + 1 {
        for x in 2 * i - 1..=2 * i + 1 {
            let wt = (1.0 - (y as f64 / 2.0 - j as f64).abs()) * (1.0 - (x as f64 / 2.0 - i as f64).abs());
            den += wt;
            if moved[[y, x]].is_finite() {
                num += wt * (moved[[y, x]] - rho0[[y, x]]);
            }
        }
    }
    let expect = (f64::from(inv[[j, i]]) + num / den) as f32;
    assert_eq!(new_inv[[j, i]].to_bits(), expect.to_bits());
    assert_eq!(new_depth[[j, i]].to_bits(), (1.0 / expect).to_bits());
    // And the level-1 estimate is closer to the truth than before.
    let err = |a: &Array2<f32>| {
        let mut e = 0.0;
        for j in 3..at1.height - 3 {
            for i in 3..at1.width - 3 {
                e += (f64::from(a[[j, i]]) - s.truth[[2 * j, 2 * i]]).abs();
            }
        }
        e
    };
    assert!(err(&new_inv) < 0.25 * err(&inv), "{} vs {}", err(&new_inv), err(&inv));
    // The volume's bin count does not change the refinement: the same range over 128 or 256 bins
    // refines bit for bit alike.
    for k in [128, 256] {
        let other = InverseDepthBins::new(bins.rho_min, bins.rho_max, k).unwrap();
        let (inv_k, _, _) = refine_estimate(
            inv.view(),
            depth.view(),
            1,
            s.key.view(),
            &s.cam,
            &views,
            &other,
            &REFINE_DEFAULTS,
        )
        .unwrap();
        assert!(inv_k.iter().zip(new_inv.iter()).all(|(a, b)| a.to_bits() == b.to_bits()), "{k} bins");
    }
}

#[test]
fn bad_inputs_are_refused() {
    let s = Scene::new(32, 24, &CENTRES[..2]);
    let rho0 = s.truth.clone();
    let views = s.views();
    let wrong = Array2::<f64>::zeros((24, 31));
    let e = refine_level0(
        &Level0 { key: wrong.view(), camera: &s.cam, rho0: rho0.view(), views: &views, step: 0.04 },
        &REFINE_DEFAULTS,
    )
    .unwrap_err();
    assert!(e.to_string().contains("refine"), "{e}");
    for p in [
        RefineParams { samples: 32, ..REFINE_DEFAULTS },
        RefineParams { samples: 1, ..REFINE_DEFAULTS },
        RefineParams { radius_bins: 0.0, ..REFINE_DEFAULTS },
        RefineParams { half_window: 0, ..REFINE_DEFAULTS },
        RefineParams { frames: 0, ..REFINE_DEFAULTS },
        RefineParams { best_fraction: 0.0, ..REFINE_DEFAULTS },
        RefineParams { min_curvature: f64::NAN, ..REFINE_DEFAULTS },
    ] {
        assert!(
            refine_level0(
                &Level0 { key: s.key.view(), camera: &s.cam, rho0: rho0.view(), views: &views, step: 0.04 },
                &p
            )
            .is_err(),
            "{p:?}"
        );
    }
    let small = RefineView { grey: wrong.view(), camera: s.cam, pose: Pose::identity() };
    assert!(refine_level0(
        &Level0 { key: s.key.view(), camera: &s.cam, rho0: rho0.view(), views: &[small], step: 0.04 },
        &REFINE_DEFAULTS
    )
    .is_err());
}

#[test]
fn frames_are_taken_evenly_from_the_window() {
    let live: Vec<usize> = (0..37).collect();
    assert_eq!(select_frames(&live, 12), (0..37).step_by(4).collect::<Vec<_>>());
    assert_eq!(select_frames(&live[..5], 12), vec![0, 1, 2, 3, 4]);
    assert_eq!(select_frames(&[], 12), Vec::<usize>::new());
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(24))]
    /// The fast path equals the plain-loop reference bit for bit on random scenes, estimates with
    /// holes, and small parameter sets.
    #[test]
    fn fast_path_equals_the_reference(
        seed in 0u64..1_000_000,
        w in 9usize..16, h in 9usize..14,
        samples in prop::sample::select(vec![3usize, 5, 9]),
        half_window in 1usize..3,
        frames in 1usize..4,
        best_fraction in prop::sample::select(vec![0.34, 0.5, 1.0]),
        min_curvature in prop::sample::select(vec![0.0, 0.002, 0.5]),
        offset_bins in -1.5f64..1.5,
    ) {
        let mut rnd = common::lcg(seed);
        let cam = camera(w, h);
        let key = Array2::from_shape_fn((h, w), |_| f64::from(rnd()) * 255.0);
        let greys: Vec<Array2<f64>> =
            (0..frames).map(|_| Array2::from_shape_fn((h, w), |_| f64::from(rnd()) * 255.0)).collect();
        let poses: Vec<Pose> = (0..frames)
            .map(|_| {
                let t = [f64::from(rnd()) - 0.5, f64::from(rnd()) - 0.5, 0.2 * (f64::from(rnd()) - 0.5)];
                pose(t, [0.05 * f64::from(rnd()), -0.05 * f64::from(rnd()), 0.02]).inverse()
            })
            .collect();
        let views: Vec<RefineView> =
            greys.iter().zip(&poses).map(|(g, p)| RefineView { grey: g.view(), camera: cam, pose: *p }).collect();
        let rho0 = Array2::from_shape_fn((h, w), |_| {
            let v = f64::from(rnd());
            if v < 0.05 { f64::NAN } else { 0.2 + 0.6 * v }
        });
        let p = RefineParams { samples, half_window, frames, best_fraction, min_curvature, radius_bins: 1.0 + offset_bins.abs(), ..REFINE_DEFAULTS };
        let fast_path = refine_level0(&Level0 { key: key.view(), camera: &cam, rho0: rho0.view(), views: &views, step: 0.05 }, &p).unwrap();
        let reference = refine_level0_reference(&Level0 { key: key.view(), camera: &cam, rho0: rho0.view(), views: &views, step: 0.05 }, &p).unwrap();
        prop_assert_eq!(bits(&fast_path), bits(&reference));
    }
}
