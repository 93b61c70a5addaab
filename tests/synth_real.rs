//! The realistic style of the synthetic renderer (`--style real`, SPEC.md §4b): determinism, random
//! intrinsics, the photo atlas's provenance, the sensor's ranges, and multi-view consistency of
//! its frames with the exact depth and poses.

use densefeat::eval::photometric_warp_check;
use densefeat::sequence::Frame;
use densefeat::synth::{
    atlas_tile_count, Scene, SceneConfig, Style, ATLAS_CROPS, FOCAL_RANGE_640, JPEG_QUALITY, MAX_SHUTTER,
    PRINCIPAL_JITTER, TRAINING_SCENES,
};

fn real(seed: u64, width: usize, height: usize, frames: usize) -> SceneConfig {
    SceneConfig { seed, width, height, frames, style: Style::Real, ..SceneConfig::default() }
}

fn bits(f: &densefeat::synth::SynthFrame) -> (Vec<u32>, Vec<u32>) {
    (f.rgb.iter().map(|v| v.to_bits()).collect(), f.depth.iter().map(|v| v.to_bits()).collect())
}

#[test]
fn real_style_is_deterministic_for_any_thread_count() {
    let scene = Scene::generate(&real(100_007, 96, 72, 8)).unwrap();
    let run = |n: usize| {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(n).build().unwrap();
        pool.install(|| bits(&scene.render(5).unwrap()))
    };
    let one = run(1);
    for n in [2, 3, 8] {
        assert!(run(n) == one, "threads = {n}: output differs from 1 thread");
    }
    let again = Scene::generate(&real(100_007, 96, 72, 8)).unwrap();
    assert!(bits(&again.render(5).unwrap()) == one, "same seed, different frame");
    let other = Scene::generate(&real(100_008, 96, 72, 8)).unwrap();
    assert!(bits(&other.render(5).unwrap()) != one, "different seeds gave the same frame");
    // The classic style of the same seed is a different scene.
    let classic =
        Scene::generate(&SceneConfig { style: Style::Classic, ..real(100_007, 96, 72, 8) }).unwrap();
    assert!(bits(&classic.render(5).unwrap()) != one);
}

#[test]
fn real_intrinsics_are_random_and_in_range() {
    for (w, h) in [(640usize, 480usize), (320, 240), (256, 192)] {
        let scale = w as f64 / 640.0;
        let (mut lo, mut hi) = (f64::MAX, 0.0f64);
        for seed in 0..60 {
            let k = real(seed, w, h, 1).camera().unwrap();
            assert_eq!(k.fx, k.fy);
            assert!(
                k.fx >= FOCAL_RANGE_640.0 * scale && k.fx <= FOCAL_RANGE_640.1 * scale,
                "{w}x{h} seed {seed}: {k:?}"
            );
            assert!((k.cx - (w as f64 - 1.0) / 2.0).abs() <= PRINCIPAL_JITTER * w as f64, "{k:?}");
            assert!((k.cy - (h as f64 - 1.0) / 2.0).abs() <= PRINCIPAL_JITTER * h as f64, "{k:?}");
            assert_eq!(Scene::generate(&real(seed, w, h, 1)).unwrap().camera(), k);
            (lo, hi) = (lo.min(k.fx), hi.max(k.fx));
        }
        // 60 uniform draws cover most of the range.
        assert!(hi - lo > 0.7 * (FOCAL_RANGE_640.1 - FOCAL_RANGE_640.0) * scale, "{w}x{h}: focal {lo}..{hi}");
    }
}

#[test]
fn atlas_is_cut_from_training_scenes_only() {
    let tiles = atlas_tile_count();
    let lines: Vec<&str> =
        ATLAS_CROPS.lines().filter(|l| !l.starts_with('#') && !l.trim().is_empty()).collect();
    assert!(tiles >= 16, "atlas has {tiles} tiles");
    assert_eq!(lines.len(), tiles, "crops.txt lists {} crops for {tiles} tiles", lines.len());
    for (i, line) in lines.iter().enumerate() {
        let f: Vec<&str> = line.split_whitespace().collect();
        assert_eq!(f.len(), 7, "{line}");
        assert_eq!(f[0].parse::<usize>().unwrap(), i, "{line}");
        assert!(TRAINING_SCENES.contains(&f[1]), "tile {i} comes from {}, not a training scene", f[1]);
        for banned in ["sun3d", "tum", "middlebury"] {
            assert!(!line.contains(banned), "{line}");
        }
    }
    for scene in TRAINING_SCENES {
        assert!(lines.iter().any(|l| l.contains(scene)), "no tile from {scene}");
    }
}

#[test]
fn sensor_parameters_stay_in_their_ranges() {
    for seed in 0..20 {
        let scene = Scene::generate(&real(seed, 32, 24, 1)).unwrap();
        let s = scene.sensor().expect("the realistic style has a sensor");
        assert!((0.0..MAX_SHUTTER).contains(&s.shutter));
        let q: Vec<u8> = (0..200).map(|i| s.jpeg_quality(i)).collect();
        assert!(q.iter().all(|q| (JPEG_QUALITY.0..=JPEG_QUALITY.1).contains(q)));
        assert!(q.iter().any(|&q| q < 78) && q.iter().any(|&q| q > 87), "qualities {q:?}");
        let p = scene.photometric().config;
        assert!(p.gain_amplitude < 1.0 && p.vignetting <= 1.0 && p.noise_sigma >= 0.0);
    }
    let classic =
        Scene::generate(&SceneConfig { width: 32, height: 24, frames: 1, ..SceneConfig::default() });
    assert!(classic.unwrap().sensor().is_none());
}

#[test]
fn real_scenes_keep_depth_in_range_and_clear_of_the_camera() {
    for seed in 0..16 {
        let scene = Scene::generate(&real(seed, 64, 48, 200)).unwrap();
        for i in (0..200).step_by(40) {
            let f = scene.render(i).unwrap();
            let (lo, hi) = f.depth.iter().fold((f32::MAX, 0.0f32), |(lo, hi), &z| (lo.min(z), hi.max(z)));
            assert!(lo >= 0.4 && hi <= 8.0, "seed {seed} frame {i}: depth range [{lo}, {hi}]");
            assert!(f.rgb.iter().all(|v| (0.0..=255.0).contains(v) && v.fract() == 0.0));
        }
    }
}

#[test]
fn real_frames_warp_onto_each_other_after_a_brightness_fit() {
    let scene = Scene::generate(&real(100_003, 160, 120, 40)).unwrap();
    let k = scene.camera();
    let frame = |i: usize| {
        let f = scene.render(i).unwrap();
        Frame { index: i, rgb: f.rgb, depth: Some(f.depth), pose: f.pose, camera: k }
    };
    for i in [0, 20] {
        let (reference, target) = (frame(i), frame(i + 4));
        let good = photometric_warp_check(&reference, &target).unwrap();
        // The same pixels warped with a wrong pose (frame i + 12's) must match much worse.
        let wrong = Frame { pose: scene.pose(i + 12).unwrap(), ..target.clone() };
        let bad = photometric_warp_check(&reference, &wrong).unwrap();
        println!(
            "frames {i} <- {}: warped {:.2}, after affine fit {:.2} (a {:.3}, b {:.1}), identity {:.2}, wrong pose {:.2}, {} px",
            i + 4,
            good.warped_error,
            good.affine_error,
            good.affine.0,
            good.affine.1,
            good.identity_error,
            bad.affine_error,
            good.pixels
        );
        assert!(good.affine_error < 6.0, "{good:?}");
        assert!(good.affine_error * 2.0 < bad.affine_error, "good {good:?} wrong pose {bad:?}");
        // Better than no warp too (by less where the view is mostly a plain wall).
        assert!(good.affine_error * 1.5 < good.identity_error, "{good:?}");
    }
}

#[test]
fn unknown_style_is_an_invalid_argument() {
    let out = tempfile::tempdir().unwrap();
    let out = out.path().to_str().unwrap();
    // The library's Error::InvalidArgument, as the binary prints it (not a clap parse error).
    let e = crate::common::run_densefeat(&["synth", "--style", "fancy", "--out", out, "--quiet"])
        .expect_err("refused");
    assert!(e.starts_with("error: invalid --style"), "{e}");
    assert_eq!("real".parse::<Style>().unwrap(), Style::Real);
    assert_eq!(Style::Classic.to_string(), "classic");
}
