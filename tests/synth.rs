//! The synthetic renderer: fixture reproducibility, thread-count independence, seeds, analytic
//! depth, and multi-view consistency through the photometric warp check.

use crate::common;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use densefeat::eval::photometric_warp_check;
use densefeat::geometry::{PinholeCamera, Pose};
use densefeat::sequence::Frame;
use densefeat::synth::{random_colour, PhotometricConfig, Quad, Scene, SceneConfig, Shape, Surface, Texture};
use densefeat::util::rng::SplitMix64;
use densefeat::Error;
use nalgebra::{Translation3, UnitQuaternion, Vector3};

/// The command recorded in `fixtures/synthetic/README.md`, without the output folder.
const FIXTURE_ARGS: [&str; 7] = ["synth", "--seed", "1", "--frames", "40", "--size", "320x240"];

fn fixture_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/synthetic/room_s1")
}

#[test]
fn fixture_regenerates_byte_identical() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("room_s1");
    let mut args = FIXTURE_ARGS.to_vec();
    let out_str = out.to_str().unwrap();
    args.extend(["--out", out_str, "--quiet"]);
    crate::common::run_densefeat(&args).unwrap();
    let (want, got) = (common::files(&fixture_dir()), common::files(&out));
    let want: BTreeMap<_, _> = want.into_iter().filter(|(k, _)| !k.ends_with(".md")).collect();
    assert_eq!(want.keys().collect::<Vec<_>>(), got.keys().collect::<Vec<_>>(), "file lists differ");
    assert_eq!(want.len(), 2 * 40 + 2);
    for (name, bytes) in &want {
        assert!(bytes == &got[name], "{name} differs from the committed fixture");
    }
}

#[test]
fn demo_fixture_config_renders_the_committed_fixture() {
    // What `densefeat demo` renders when the binary runs away from its source tree.
    let tmp = tempfile::tempdir().unwrap();
    let scene = densefeat::synth::Scene::generate(&densefeat::synth::demo_fixture_config()).unwrap();
    densefeat::synth::write_scene(&scene, tmp.path(), |_, _| {}).unwrap();
    let (want, got) = (common::files(&fixture_dir()), common::files(tmp.path()));
    let want: BTreeMap<_, _> = want.into_iter().filter(|(k, _)| !k.ends_with(".md")).collect();
    assert_eq!(want.keys().collect::<Vec<_>>(), got.keys().collect::<Vec<_>>(), "file lists differ");
    for (name, bytes) in &want {
        assert!(bytes == &got[name], "{name} differs from the committed fixture");
    }
}

fn small_config(seed: u64) -> SceneConfig {
    SceneConfig { seed, width: 96, height: 72, frames: 12, ..SceneConfig::default() }
}

fn bits(f: &densefeat::synth::SynthFrame) -> (Vec<u32>, Vec<u32>) {
    (f.rgb.iter().map(|v| v.to_bits()).collect(), f.depth.iter().map(|v| v.to_bits()).collect())
}

#[test]
fn render_independent_of_thread_count() {
    let scene = Scene::generate(&SceneConfig { width: 160, height: 120, ..SceneConfig::default() }).unwrap();
    let run = |n: usize| {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(n).build().unwrap();
        pool.install(|| bits(&scene.render(7).unwrap()))
    };
    let one = run(1);
    for n in [2, 3, 8] {
        assert!(run(n) == one, "threads = {n}: output differs from 1 thread");
    }
}

#[test]
fn different_seeds_give_different_scenes() {
    let a = Scene::generate(&small_config(1)).unwrap();
    let b = Scene::generate(&small_config(2)).unwrap();
    assert_ne!(a.pose(0).unwrap(), b.pose(0).unwrap());
    assert_ne!(a.surfaces(), b.surfaces());
    let (fa, fb) = (a.render(0).unwrap(), b.render(0).unwrap());
    assert_ne!(bits(&fa), bits(&fb));
    // And the same seed gives the same scene.
    let a2 = Scene::generate(&small_config(1)).unwrap();
    assert_eq!(bits(&fa), bits(&a2.render(0).unwrap()));
}

#[test]
fn generated_scenes_have_full_depth_in_range_and_stay_clear_of_the_camera() {
    for seed in 0..24 {
        let cfg = SceneConfig { seed, width: 64, height: 48, frames: 200, ..SceneConfig::default() };
        let scene = Scene::generate(&cfg).unwrap();
        for i in (0..cfg.frames).step_by(20) {
            let f = scene.render(i).unwrap();
            let (lo, hi) = f.depth.iter().fold((f32::MAX, 0.0f32), |(lo, hi), &z| (lo.min(z), hi.max(z)));
            assert!(lo >= 0.5 && hi <= 6.5, "seed {seed} frame {i}: depth range [{lo}, {hi}]");
        }
    }
}

#[test]
fn fixture_motion_gives_a_useful_baseline() {
    let scene = Scene::generate(&SceneConfig::default()).unwrap();
    let positions: Vec<Vector3<f64>> =
        (0..scene.frames()).map(|i| scene.pose(i).unwrap().translation.vector).collect();
    let path: f64 = positions.windows(2).map(|w| (w[1] - w[0]).norm()).sum();
    let chord = (positions[positions.len() - 1] - positions[0]).norm();
    let max_step = positions.windows(2).map(|w| (w[1] - w[0]).norm()).fold(0.0, f64::max);
    println!("path {path:.3} m, end-to-end {chord:.3} m, largest step {max_step:.4} m");
    let (mut lo, mut hi) = (f32::MAX, 0.0f32);
    for i in 0..scene.frames() {
        let f = scene.render(i).unwrap();
        lo = f.depth.iter().fold(lo, |a, &z| a.min(z));
        hi = f.depth.iter().fold(hi, |a, &z| a.max(z));
    }
    println!("depth range over all frames: [{lo:.3}, {hi:.3}] m");
    assert!(lo >= 0.5 && hi <= 6.0, "depth range [{lo}, {hi}]");
    assert!((0.3..=0.7).contains(&path), "path length {path}");
    assert!(chord >= 0.2, "end-to-end translation {chord}");
    assert!(max_step <= 0.04, "largest step {max_step}");
}

/// A plain grey texture.
fn plain() -> Texture {
    Texture::random(&mut SplitMix64::new(5), true, 1.0)
}

#[test]
fn depth_matches_analytic_ray_plane_distance() {
    let k = PinholeCamera::new(200.0, 200.0, 79.5, 59.5, 160, 120).unwrap();
    let d = 2.75;
    // A wall z = d facing the camera, much larger than the view.
    let wall = Quad::new(Vector3::new(-10.0, -10.0, d), Vector3::x(), Vector3::y(), [20.0, 20.0]);
    let scene =
        Scene::new(k, vec![Pose::identity()], vec![Surface { shape: Shape::Quad(wall), texture: plain() }]);
    let f = scene.render(0).unwrap();
    assert!(f.depth.iter().all(|&z| z == d as f32), "fronto-parallel wall: depth must be exactly {d}");

    // A plane through (0, 0, d) tilted by `a` about the camera's y axis, seen from a camera moved
    // and rotated: in the camera frame the plane is n·X = c, so depth z = c / (n·K⁻¹(u, v, 1)).
    let a = 0.6f64;
    let (axis_u, axis_v) = (Vector3::new(a.cos(), 0.0, a.sin()), Vector3::y());
    let origin = Vector3::new(0.0, -10.0, d) - axis_u * 10.0;
    let slanted = Quad::new(origin, axis_u, axis_v, [20.0, 20.0]);
    let n_w = slanted.normal;
    let pose = Pose::from_parts(
        Translation3::new(0.1, -0.05, 0.2),
        UnitQuaternion::from_euler_angles(0.05, -0.1, 0.02),
    );
    let scene = Scene::new(k, vec![pose], vec![Surface { shape: Shape::Quad(slanted), texture: plain() }]);
    let f = scene.render(0).unwrap();
    // Plane in the camera frame: n_c = Rᵀ n_w, c_c = n_w·(origin - t).
    let n_c = pose.rotation.inverse() * n_w;
    let c_c = n_w.dot(&(origin - pose.translation.vector));
    let mut worst = 0.0f64;
    for ((y, x), &z) in f.depth.indexed_iter() {
        let want = c_c / n_c.dot(&k.ray(x as f64, y as f64));
        worst = worst.max(((z as f64) - want).abs() / want);
    }
    let centre = f.depth[[60, 80]] as f64;
    let want_centre = c_c / n_c.dot(&k.ray(80.0, 60.0));
    println!("slanted plane: centre depth {centre} (analytic {want_centre}), worst relative error {worst:e}");
    assert!(worst < 1e-6, "worst relative depth error {worst:e}");
}

/// `depth` with every pixel within `radius` of a depth discontinuity or crease set to 0 (invalid).
/// On a plane, inverse depth is affine in the pixel coordinates, so its second difference vanishes;
/// where it does not, the pixel's anti-aliased colour mixes surfaces and is not warpable exactly.
fn mask_discontinuities(depth: &ndarray::Array2<f32>, radius: usize) -> ndarray::Array2<f32> {
    const CURVATURE_TOL: f64 = 1e-4;
    let (h, w) = depth.dim();
    let inv = depth.mapv(|z| 1.0 / z as f64);
    let mut edge = ndarray::Array2::from_elem((h, w), false);
    for y in 0..h {
        for x in 0..w {
            let dx =
                if x > 0 && x + 1 < w { inv[[y, x - 1]] - 2.0 * inv[[y, x]] + inv[[y, x + 1]] } else { 0.0 };
            let dy =
                if y > 0 && y + 1 < h { inv[[y - 1, x]] - 2.0 * inv[[y, x]] + inv[[y + 1, x]] } else { 0.0 };
            edge[[y, x]] = dx.abs() > CURVATURE_TOL || dy.abs() > CURVATURE_TOL;
        }
    }
    let mut out = depth.clone();
    for ((y, x), &e) in edge.indexed_iter() {
        if e {
            for yy in y.saturating_sub(radius)..(y + radius + 1).min(h) {
                for xx in x.saturating_sub(radius)..(x + radius + 1).min(w) {
                    out[[yy, xx]] = 0.0;
                }
            }
        }
    }
    out
}

#[test]
fn exact_depth_warps_frames_onto_each_other() {
    let cfg = SceneConfig { photometric: PhotometricConfig::none(), ..SceneConfig::default() };
    let scene = Scene::generate(&cfg).unwrap();
    let k = scene.camera();
    let frame = |i: usize| {
        let f = scene.render(i).unwrap();
        Frame { index: i, rgb: f.rgb, depth: Some(f.depth), pose: f.pose, camera: k }
    };
    for i in [0, 17, 34] {
        let (reference, target) = (frame(i), frame(i + 5));
        let all = photometric_warp_check(&reference, &target).unwrap();
        let depth = reference.depth.as_ref().map(|d| mask_discontinuities(d, 2));
        let smooth = photometric_warp_check(&Frame { depth, ..reference }, &target).unwrap();
        for (what, c) in [("all pixels", all), ("away from depth edges", smooth)] {
            println!(
                "frames {i} <- {} ({what}): warped {:.3}, identity {:.3} grey levels, gain {:.1}, {} px",
                i + 5,
                c.warped_error,
                c.identity_error,
                c.gain(),
                c.pixels
            );
        }
        // Over all pixels, anti-aliased depth edges and disocclusions add about half a grey level.
        assert!(all.warped_error < 2.0, "{all:?}");
        assert!(all.gain() > 8.0, "{all:?}");
        // What remains is 8-bit rounding (~0.33) and bilinear resampling of sharp texture edges.
        assert!(smooth.warped_error < 1.5, "{smooth:?}");
        assert!(smooth.gain() > 10.0, "{smooth:?}");
    }
}

#[test]
fn bad_arguments_are_invalid_argument_errors() {
    let out = tempfile::tempdir().unwrap();
    let out = out.path().to_str().unwrap();
    for (size, frames) in [("0x240", "4"), ("320x0", "4"), ("320", "4"), ("axb", "4"), ("320x240", "0")] {
        let r = crate::common::run_densefeat(&[
            "synth", "--size", size, "--frames", frames, "--out", out, "--quiet",
        ]);
        // The library's Error::InvalidArgument, as the binary prints it (not a clap parse error).
        let e = r.expect_err("refused");
        assert!(e.starts_with("error: invalid --"), "--size {size} --frames {frames}: {e}");
    }
    let cfg = SceneConfig { samples_per_axis: 0, ..SceneConfig::default() };
    assert!(matches!(Scene::generate(&cfg), Err(Error::InvalidArgument { .. })));
    let scene = Scene::generate(&small_config(3)).unwrap();
    assert!(matches!(scene.render(12), Err(Error::InvalidArgument { .. })));
    let _ = random_colour(&mut SplitMix64::new(1));
}
