//! Keyframe reconstruction end to end on the shipped synthetic fixture (SPEC.md §11): TV improves
//! on winner-take-all, output files parse back, bad input gives clear errors, the eval table and
//! the `demo` command.

use std::path::{Path, PathBuf};
use std::process::Command;

use densefeat::error::Error;
use densefeat::mapping::evaluate::{evaluate, EvalOptions, Method};
use densefeat::mapping::features::FeatureExtractor;
use densefeat::mapping::keyframe::{
    memory_estimate, reconstruct, reconstruct_with, KeyframeConfig, Regularizer,
};
use densefeat::mapping::{write_outputs, FeatureKind};
use densefeat::sequence::{open, Sequence};

const FIXTURE: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/fixtures/synthetic/room_s1");

fn fixture() -> Sequence {
    open(Path::new(FIXTURE)).unwrap()
}

/// Keyframe 20, five frames either side, 32 bins over 0.4..10 m, RGB, TV, level 1 (160x120).
fn small_config() -> KeyframeConfig {
    let mut cfg = KeyframeConfig::new(20, 0.4, 10.0);
    cfg.past = 5;
    cfg.future = 5;
    cfg.bins = 32;
    cfg.level = 1;
    cfg
}

/// [`small_config`] cut down for the evaluation tests: 3 frames either side, 16 bins, 20 DTAM
/// iterations.
fn eval_config() -> KeyframeConfig {
    let mut cfg = small_config();
    cfg.past = 3;
    cfg.future = 3;
    cfg.bins = 16;
    cfg.dtam.iterations = 20;
    cfg
}

fn invalid_argument(e: Error) -> (String, String) {
    match e {
        Error::InvalidArgument { name, what } => (name, what),
        other => panic!("expected InvalidArgument, got {other}"),
    }
}

#[test]
fn one_extractor_serves_many_keyframes_with_the_same_bits() {
    // `map` and `eval` build the extractor once per run (issue 33): the same depth as building it
    // per keyframe, and an extractor of another kind or level is refused.
    let seq = fixture();
    let mut cfg = small_config();
    cfg.features = FeatureKind::Learned(None);
    cfg.regularizer = Regularizer::None;
    let ex = FeatureExtractor::new(cfg.features.clone(), cfg.level, cfg.backend.clone()).unwrap();
    for k in [15, 20] {
        cfg.keyframe = k;
        let a = reconstruct(&seq, &cfg, |_, _, _| {}).unwrap();
        let b = reconstruct_with(&seq, &cfg, &ex, |_, _, _| {}).unwrap();
        let bits = |r: &densefeat::mapping::KeyframeResult| {
            r.wta.depth.iter().map(|v| v.to_bits()).collect::<Vec<_>>()
        };
        assert_eq!(bits(&a), bits(&b), "keyframe {k}");
    }
    let rgb = FeatureExtractor::new(FeatureKind::Rgb, cfg.level, cfg.backend.clone()).unwrap();
    let (name, _) = invalid_argument(reconstruct_with(&seq, &cfg, &rgb, |_, _, _| {}).unwrap_err());
    assert_eq!(name, "features");
    let level0 = FeatureExtractor::new(cfg.features.clone(), 0, cfg.backend.clone()).unwrap();
    assert!(reconstruct_with(&seq, &cfg, &level0, |_, _, _| {}).is_err());
}

#[test]
fn tv_improves_on_wta_for_rgb() {
    let seq = fixture();
    let r = reconstruct(&seq, &small_config(), |_, _, _| {}).unwrap();
    assert_eq!(r.live_frames, vec![15, 16, 17, 18, 19, 21, 22, 23, 24, 25]);
    assert_eq!((r.camera.width, r.camera.height), (160, 120));
    let wta = r.metrics(&r.wta).unwrap();
    let tv = r.metrics(r.tv.as_ref().unwrap()).unwrap();
    eprintln!(
        "WTA rms {:.4} δ<1.25 {:.4}; TV rms {:.4} δ<1.25 {:.4}",
        wta.rms, wta.delta_1_25, tv.rms, tv.delta_1_25
    );
    assert!(tv.rms < wta.rms, "TV rms {} >= WTA rms {}", tv.rms, wta.rms);
    assert!(tv.delta_1_25 > wta.delta_1_25);
    let report = r.dtam.as_ref().unwrap();
    assert_eq!(report.energy.len(), report.iterations);
}

#[test]
fn ground_truth_is_level0_depth_at_scaled_pixels() {
    let seq = fixture();
    let mut cfg = small_config();
    cfg.regularizer = Regularizer::None;
    let r = reconstruct(&seq, &cfg, |_, _, _| {}).unwrap();
    let d0 = seq.load_frame(20).unwrap().depth.unwrap();
    let gt = r.gt_depth.as_ref().unwrap();
    let s = 1usize << r.level;
    for ((y, x), &z) in gt.indexed_iter() {
        assert_eq!(z.to_bits(), d0[[y * s, x * s]].to_bits());
    }
    assert!(r.tv.is_none() && r.dtam.is_none());
}

fn read_npy_shape_and_data(path: &Path) -> (String, Vec<f32>) {
    let bytes = std::fs::read(path).unwrap();
    assert_eq!(&bytes[..8], b"\x93NUMPY\x01\x00");
    let len = u16::from_le_bytes([bytes[8], bytes[9]]) as usize;
    let header = String::from_utf8(bytes[10..10 + len].to_vec()).unwrap();
    assert_eq!((10 + len) % 64, 0);
    let data = bytes[10 + len..].chunks(4).map(|c| f32::from_le_bytes(c.try_into().unwrap())).collect();
    (header, data)
}

#[test]
fn outputs_parse_back_and_leave_no_temp_files() {
    let seq = fixture();
    let r = reconstruct(&seq, &small_config(), |_, _, _| {}).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let files = write_outputs(&r, dir.path()).unwrap();
    for f in &files {
        assert!(f.exists(), "{}", f.display());
    }
    let names: Vec<String> = std::fs::read_dir(dir.path())
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    assert!(names.iter().all(|n| !n.starts_with('.') && !n.contains(".tmp")), "{names:?}");
    assert_eq!(names.len(), files.len());
    for want in ["metrics.json", "keyframe.png", "depth_tv.pfm", "depth_wta_color.png", "cloud_tv.ply"] {
        assert!(names.iter().any(|n| n == want), "{want} missing from {names:?}");
    }
    let tv = r.tv.as_ref().unwrap();
    // npy: header and values.
    let (header, data) = read_npy_shape_and_data(&dir.path().join("depth_tv.npy"));
    assert!(header.contains("'shape': (120, 160)") && header.contains("'<f4'"), "{header}");
    assert_eq!(data, tv.depth.iter().copied().collect::<Vec<_>>());
    // PFM: header, bottom row first.
    let pfm = std::fs::read(dir.path().join("depth_tv.pfm")).unwrap();
    let head = b"Pf\n160 120\n-1.0\n";
    assert_eq!(&pfm[..head.len()], head);
    assert_eq!(pfm.len(), head.len() + 160 * 120 * 4);
    let first = f32::from_le_bytes(pfm[head.len()..head.len() + 4].try_into().unwrap());
    assert_eq!(first, tv.depth[[119, 0]]);
    // 16-bit PNG in millimetres, within 1 mm.
    let mm = densefeat::image::load_depth_png(&dir.path().join("depth_tv_mm.png"), 1e-3, None).unwrap();
    for (a, b) in mm.iter().zip(tv.depth.iter()) {
        if *b > 0.0 && *b < 65.0 {
            assert!((a - b).abs() <= 1e-3, "{a} vs {b}");
        } else {
            assert_eq!(*a, 0.0);
        }
    }
    // PLY: header vertex count equals the valid pixels, body size matches.
    let ply = std::fs::read(dir.path().join("cloud_tv.ply")).unwrap();
    let end = ply.windows(11).position(|w| w == b"end_header\n").unwrap() + 11;
    let header = String::from_utf8(ply[..end].to_vec()).unwrap();
    assert!(header.starts_with("ply\nformat binary_little_endian 1.0\n"), "{header}");
    let n: usize = header.lines().find_map(|l| l.strip_prefix("element vertex ")).unwrap().parse().unwrap();
    assert_eq!(n, tv.depth.iter().filter(|z| **z > 0.0).count());
    assert!(n > 0);
    assert_eq!(ply.len() - end, n * 15);
    // metrics.json
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.path().join("metrics.json")).unwrap()).unwrap();
    assert!(json["metrics"]["tv"]["rms"].as_f64().unwrap() > 0.0);
    assert!(json["metrics"]["wta"]["rms"].as_f64().unwrap() > 0.0);
}

#[test]
fn bad_inputs_are_clear_errors() {
    let seq = fixture();
    let run = |f: &dyn Fn(&mut KeyframeConfig)| {
        let mut cfg = small_config();
        f(&mut cfg);
        invalid_argument(reconstruct(&seq, &cfg, |_, _, _| {}).unwrap_err())
    };
    let (name, what) = run(&|c| c.keyframe = 40);
    assert_eq!(name, "keyframe");
    assert!(what.contains("40 frames"), "{what}");
    let (name, _) = run(&|c| {
        c.past = 0;
        c.future = 0;
    });
    assert_eq!(name, "window");
    let (name, what) = run(&|c| {
        c.near = 5.0;
        c.far = 2.0;
    });
    assert_eq!(name, "depth range");
    assert!(what.contains("near < far"), "{what}");
    let (name, _) = run(&|c| c.bins = 1);
    assert_eq!(name, "bins");
    let (name, _) = run(&|c| c.dtam.iterations = 0);
    assert_eq!(name, "iterations");
    // A window larger than the sequence is clamped, not an error.
    let mut cfg = small_config();
    cfg.past = 1000;
    cfg.future = 1000;
    assert_eq!(cfg.live_frames(seq.len()).unwrap().len(), 39);
    // The learned features from a file that does not exist.
    let mut cfg = small_config();
    cfg.features = FeatureKind::Learned(Some(PathBuf::from("/nonexistent/w.safetensors")));
    let e = reconstruct(&seq, &cfg, |_, _, _| {}).unwrap_err();
    assert!(e.to_string().contains("/nonexistent/w.safetensors"), "{e}");
}

#[test]
fn memory_limit_fails_up_front() {
    assert_eq!(
        memory_estimate(120, 160, 32, 3),
        120 * 160 * 32 * 10 + 120 * 160 * 4 * 4 + 2 * 120 * 160 * 3 * 4
    );
    let seq = fixture();
    let mut cfg = small_config();
    cfg.bins = 4096; // 120·160·4096·10 B = 750 MiB
    cfg.max_memory_mb = 100;
    let (name, what) = invalid_argument(reconstruct(&seq, &cfg, |_, _, _| {}).unwrap_err());
    assert_eq!(name, "max-memory-mb");
    assert!(what.contains("MiB") && what.contains("100"), "{what}");
}

#[test]
fn the_refinement_counts_against_the_memory_limit() {
    // SPEC.md §10.3: its images and planes are held with the volume, so they count up front.
    let seq = fixture();
    let mut cfg = small_config();
    let volume = memory_estimate(120, 160, cfg.bins, 3);
    let refine = densefeat::mapping::refine::memory_bytes(240, 320, 10); // 10 live frames, level 0
    assert!(volume < 20 << 20 && volume + refine > 20 << 20, "{volume} {refine}");
    cfg.max_memory_mb = 20;
    cfg.refine = Some(densefeat::mapping::refine::REFINE_DEFAULTS);
    let (name, what) = invalid_argument(reconstruct(&seq, &cfg, |_, _, _| {}).unwrap_err());
    assert_eq!(name, "max-memory-mb");
    let mib = refine.div_ceil(1 << 20);
    assert!(what.contains(&format!("refinement's {mib} MiB")) && what.contains("--refine off"), "{what}");
}

#[test]
fn eval_without_ground_truth_is_an_error() {
    // The fixture without its depth folder.
    let dir = tempfile::tempdir().unwrap();
    let src = Path::new(FIXTURE);
    std::fs::create_dir(dir.path().join("images")).unwrap();
    for f in ["K.txt", "poses.txt"] {
        std::fs::copy(src.join(f), dir.path().join(f)).unwrap();
    }
    for e in std::fs::read_dir(src.join("images")).unwrap() {
        let e = e.unwrap();
        std::fs::copy(e.path(), dir.path().join("images").join(e.file_name())).unwrap();
    }
    let seq = open(dir.path()).unwrap();
    let mut cfg = small_config();
    cfg.regularizer = Regularizer::None;
    let r = reconstruct(&seq, &cfg, |_, _, _| {}).unwrap();
    assert!(r.gt_depth.is_none());
    let (name, what) = invalid_argument(r.metrics(&r.wta).unwrap_err());
    assert_eq!(name, "evaluation");
    assert!(what.contains("no ground-truth"), "{what}");
    // Outputs without ground truth: no metrics.json.
    let out = tempfile::tempdir().unwrap();
    let files = write_outputs(&r, out.path()).unwrap();
    assert!(files.iter().all(|f| !f.ends_with("metrics.json")));
}

#[test]
fn a_lambda_sweep_reaches_the_normal_prior_rows_without_tv() {
    // λ per variant (issue 32): with only -normals methods the sweep solves with the normal prior
    // and is reported for them; the row at the run's own λ is that method's result.
    use densefeat::mapping::normals::NormalsSource;
    let seq = fixture();
    let mut base = eval_config();
    base.dtam.lambda = 100.0;
    base.lambda_normals = 100.0;
    base.normals = Some(NormalsSource::GroundTruth);
    let options = EvalOptions { lambda_sweep: vec![30.0, 100.0], ..EvalOptions::default() };
    let methods = [Method::RgbNormals, Method::LearnedTv, Method::LearnedNormals];
    let table = evaluate(&seq, &base, &[20], &methods, &options, |_| Ok(()), |_, _, _, _| {}).unwrap();
    let rows: Vec<(Method, f64)> = table.sweep.iter().map(|(m, l, _)| (*m, *l)).collect();
    // RGB has no -tv row: its normal-prior row gets the sweep; learned has one: only it does.
    assert_eq!(
        rows,
        vec![
            (Method::RgbNormals, 30.0),
            (Method::RgbNormals, 100.0),
            (Method::LearnedTv, 30.0),
            (Method::LearnedTv, 100.0)
        ]
    );
    let own = table.rows.iter().find(|r| r.method == Method::RgbNormals).unwrap().metrics;
    let at_100 = table.sweep.iter().find(|(m, l, _)| *m == Method::RgbNormals && *l == 100.0).unwrap().2;
    assert_eq!(own.rms.to_bits(), at_100.rms.to_bits());
    assert_eq!(own.delta_1_25.to_bits(), at_100.delta_1_25.to_bits());
    // The normal prior solves at its own λ (SPEC.md §10.1a), not the Huber-TV one.
    base.lambda_normals = 30.0;
    let methods = [Method::RgbNormals];
    let again = evaluate(&seq, &base, &[20], &methods, &options, |_| Ok(()), |_, _, _, _| {}).unwrap();
    let own = again.rows.iter().find(|r| r.method == Method::RgbNormals).unwrap().metrics;
    let at_30 = table.sweep.iter().find(|(m, l, _)| *m == Method::RgbNormals && *l == 30.0).unwrap().2;
    assert_eq!(own.rms.to_bits(), at_30.rms.to_bits());
    assert_ne!(own.rms.to_bits(), at_100.rms.to_bits());
}

#[test]
fn the_normal_prior_has_its_own_default_lambda_per_feature_kind() {
    use densefeat::mapping::features::{LAMBDA_LEARNED_NORMALS, LAMBDA_RGB_NORMALS};
    assert_eq!(FeatureKind::Rgb.default_lambda_normals(), LAMBDA_RGB_NORMALS);
    assert_eq!(FeatureKind::Learned(None).default_lambda_normals(), LAMBDA_LEARNED_NORMALS);
    // Kinds without a normal-prior sweep keep their smoothness λ.
    for k in [FeatureKind::B1(None), FeatureKind::Dsift, FeatureKind::Patch7] {
        assert_eq!(k.default_lambda_normals(), k.default_lambda());
    }
    // A non-positive prior λ is refused naming λ, before any work, only when the prior runs.
    let seq = fixture();
    let mut cfg = eval_config();
    cfg.lambda_normals = -1.0;
    assert!(reconstruct(&seq, &cfg, |_, _, _| {}).is_ok());
    cfg.regularizer = densefeat::mapping::keyframe::Regularizer::Normals;
    cfg.normals = Some(densefeat::mapping::normals::NormalsSource::GroundTruth);
    let (name, what) = invalid_argument(reconstruct(&seq, &cfg, |_, _, _| {}).unwrap_err());
    assert!(name.contains("lambda"), "{name}: {what}");
}

#[test]
fn eval_table_contains_every_method() {
    let seq = fixture();
    let base = eval_config();
    let mut seen = Vec::new();
    let table = evaluate(
        &seq,
        &base,
        &[10, 20],
        &Method::ALL,
        &EvalOptions::default(),
        |r| {
            seen.push((r.keyframe, r.features));
            Ok(())
        },
        |_, _, _, _| {},
    )
    .unwrap();
    // One volume per keyframe and feature kind: WTA and TV share it.
    assert_eq!(seen, vec![(10, "rgb"), (20, "rgb"), (10, "learned"), (20, "learned")]);
    assert_eq!(table.rows.len(), 4);
    assert_eq!(table.per_keyframe.len(), 8);
    let md = table.markdown();
    let csv = table.csv();
    for m in Method::ALL {
        assert!(md.contains(&format!("| {} |", m.name())), "{md}");
        assert!(csv.lines().any(|l| l.starts_with(&format!("{},", m.name()))), "{csv}");
    }
    assert!(md.contains("δ<1.25³"));
    assert_eq!(csv.lines().count(), 5);
}

#[test]
fn demo_runs_on_the_fixture() {
    let dir = tempfile::tempdir().unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_densefeat"))
        .args(["demo", "--bins", "16", "--window", "3,3", "--iterations", "30", "--out"])
        .arg(dir.path())
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{}\n{}", stdout, String::from_utf8_lossy(&out.stderr));
    for m in Method::ALL {
        assert!(stdout.contains(m.name()), "{stdout}");
    }
    for f in ["table.md", "table.csv", "kf_00020_rgb/depth_tv_color.png", "kf_00020_learned/cloud_wta.ply"] {
        assert!(dir.path().join(f).exists(), "{f} missing");
    }
}

#[test]
fn cli_reconstruct_rejects_bad_flags() {
    let run = |args: &[&str]| {
        Command::new(env!("CARGO_BIN_EXE_densefeat"))
            .args(["reconstruct", "--sequence", FIXTURE, "--out", "/tmp/unused-densefeat-out"])
            .args(args)
            .output()
            .unwrap()
    };
    let out = run(&["--keyframe", "99"]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("keyframe"));
    let out = run(&["--keyframe", "1", "--features", "sift"]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("sift"));
    let out = run(&["--keyframe", "1", "--window", "3"]);
    assert!(!out.status.success());
    for bad in ["0", "-5", "nan", "lots"] {
        let out = run(&["--keyframe", "1", &format!("--truncate-rgb={bad}")]);
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success() && err.contains("--truncate-rgb") && err.contains("positive"), "{err}");
    }
}

/// SPEC.md §9.13: a per-frame truncation is recorded in the result and in metrics.json, changes the
/// volume (the fixture has occlusions), and `none` / the default is the plain L1.
#[test]
fn truncation_reaches_the_volume_and_the_outputs() {
    let seq = fixture();
    let mut cfg = small_config();
    let plain = reconstruct(&seq, &cfg, |_, _, _| {}).unwrap();
    assert_eq!(plain.truncation, densefeat::costvolume::NO_TRUNCATION, "the default is none");
    cfg.truncation.rgb = 30.0;
    let cut = reconstruct(&seq, &cfg, |_, _, _| {}).unwrap();
    assert_eq!(cut.truncation, 30.0);
    assert_ne!(cut.wta.inverse_depth, plain.wta.inverse_depth, "a 30-grey-level cap changes some winners");
    cfg.truncation.rgb = 0.0;
    let (name, _) = invalid_argument(reconstruct(&seq, &cfg, |_, _, _| {}).unwrap_err());
    assert_eq!(name, "truncate-rgb");

    let dir = tempfile::tempdir().unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_densefeat"))
        .args(["reconstruct", "--sequence", FIXTURE, "--keyframe", "20", "--window", "2,2", "--bins", "16"])
        .args(["--level", "2", "--regularizer", "none", "--truncate-rgb", "80", "--out"])
        .arg(dir.path())
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.path().join("metrics.json")).unwrap()).unwrap();
    assert_eq!(json["truncation"], 80.0, "{json}");
}

#[test]
fn cli_eval_writes_tables_for_the_requested_methods() {
    let dir = tempfile::tempdir().unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_densefeat"))
        .args(["eval", "--sequence", FIXTURE, "--keyframes", "10:10:20", "--window", "2,2", "--bins", "16"])
        .args(["--iterations", "20", "--methods", "rgb-wta,rgb-tv", "--out"])
        .arg(dir.path())
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let md = std::fs::read_to_string(dir.path().join("table.md")).unwrap();
    let csv = std::fs::read_to_string(dir.path().join("table.csv")).unwrap();
    assert!(md.contains("| rgb-wta |") && md.contains("| rgb-tv |") && !md.contains("learned"), "{md}");
    // Full coverage rows, then the rows at the default confidence threshold 0.1.
    assert!(md.contains("| rgb-wta@0.1 |") && md.contains("| rgb-tv@0.1 |"), "{md}");
    assert_eq!(csv.lines().count(), 5, "{csv}");
    let per = std::fs::read_to_string(dir.path().join("per_keyframe.csv")).unwrap();
    assert_eq!(per.lines().count(), 5, "{per}");
}

#[test]
fn cli_eval_lambda_sweep_writes_csv_and_plot() {
    let dir = tempfile::tempdir().unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_densefeat"))
        .args(["eval", "--sequence", FIXTURE, "--keyframes", "20:10:20", "--window", "2,2", "--bins", "16"])
        .args(["--iterations", "20", "--methods", "rgb-wta,rgb-tv", "--lambda-sweep", "1000,10,100", "--out"])
        .arg(dir.path())
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let csv = std::fs::read_to_string(dir.path().join("lambda_sweep.csv")).unwrap();
    let lines: Vec<&str> = csv.lines().collect();
    assert_eq!(lines[0], "method,lambda,rms,delta_1.25,abs_rel,coverage");
    // Sorted by λ, one row each, finite positive rms, δ in [0, 1].
    let lambdas: Vec<f64> =
        lines[1..].iter().map(|l| l.split(',').nth(1).unwrap().parse().unwrap()).collect();
    assert_eq!(lambdas, vec![10.0, 100.0, 1000.0]);
    for l in &lines[1..] {
        assert!(l.starts_with("rgb-tv,"), "{l}");
        let rms: f64 = l.split(',').nth(2).unwrap().parse().unwrap();
        let delta: f64 = l.split(',').nth(3).unwrap().parse().unwrap();
        assert!(rms.is_finite() && rms > 0.0 && (0.0..=1.0).contains(&delta), "{l}");
    }
    for f in ["lambda_sweep.png", "lambda_sweep_delta.png"] {
        let png = image::open(dir.path().join(f)).unwrap();
        assert!(png.width() > 100 && png.height() > 100);
    }
    // A sweep needs a TV or normal-prior method.
    let bad = Command::new(env!("CARGO_BIN_EXE_densefeat"))
        .args(["eval", "--sequence", FIXTURE, "--keyframes", "20:10:20", "--methods", "rgb-wta"])
        .args(["--lambda-sweep", "10", "--out"])
        .arg(dir.path())
        .output()
        .unwrap();
    assert!(!bad.status.success());
    assert!(String::from_utf8_lossy(&bad.stderr).contains("--lambda-sweep"));
}

/// `eval --depth-range auto` estimates a range per keyframe (not the first keyframe's for all): each
/// keyframe's metrics.json states the range estimated at that keyframe.
#[test]
fn eval_auto_depth_range_is_estimated_per_keyframe() {
    let seq = fixture();
    let want: Vec<(f64, f64)> =
        [10, 30].iter().map(|&k| seq.estimate_depth_range(k).unwrap().unwrap()).collect();
    assert_ne!(want[0], want[1], "the fixture's keyframes 10 and 30 see different depth ranges");
    let dir = tempfile::tempdir().unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_densefeat"))
        .args(["eval", "--sequence", FIXTURE, "--keyframes", "10:20:30", "--window", "2,2", "--bins", "16"])
        .args(["--level", "2", "--depth-range", "auto", "--methods", "rgb-wta", "--save-depth", "--out"])
        .arg(dir.path())
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    for (k, (near, far)) in [10, 30].iter().zip(want) {
        let path = dir.path().join(format!("kf_{k:05}_rgb/metrics.json"));
        let json: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap();
        let got = (json["depth_range_m"][0].as_f64().unwrap(), json["depth_range_m"][1].as_f64().unwrap());
        assert!(
            (got.0 - near).abs() < 1e-9 * near && (got.1 - far).abs() < 1e-9 * far,
            "keyframe {k}: {got:?} vs {:?}",
            (near, far)
        );
    }
}

/// One CPU-feature level handed to every mapping kernel through the backend (issue 33 item 3):
/// a keyframe reconstructed on `CpuBackend`s at the portable, AVX2 and AVX-512 levels gives the same
/// bits (cost volume, winner-take-all, Huber-TV, the normal prior, the feature maps' resampling and
/// the colour pyramid), in this process, with no environment variable. The network runs the GEMM
/// kernels at every level here: its fastest kernels differ by level (Winograd with SIMD, the GEMM
/// without; `network::every_cpu_level_of_the_backend_runs_its_own_kernels_within_the_budget`).
#[test]
fn every_cpu_level_of_the_backend_gives_the_same_keyframe() {
    use densefeat::backend::{Backend, CpuBackend};
    use densefeat::mapping::normals::NormalsSource;
    use densefeat::runtime::CpuFeatureLevel;
    let seq = fixture();
    let mut cfg = eval_config();
    cfg.features = FeatureKind::Learned(None);
    cfg.regularizer = Regularizer::TvAndNormals;
    cfg.normals = Some(NormalsSource::GroundTruth);
    cfg.level = 0;
    let run = |level: CpuFeatureLevel| {
        let network = densefeat::ops::NetworkImpl {
            conv: densefeat::ops::Conv2dImpl::Im2colGemm,
            deconv: densefeat::ops::Deconv2dImpl::ParityGemm,
        };
        let backend = CpuBackend { level, network, ..CpuBackend::default() };
        assert_eq!(backend.cpu_level(), level);
        let mut c = cfg.clone();
        c.backend = std::sync::Arc::new(backend);
        reconstruct(&seq, &c, |_, _, _| {}).unwrap()
    };
    let want = run(CpuFeatureLevel::Portable);
    for level in [CpuFeatureLevel::Avx2, CpuFeatureLevel::Avx512, CpuFeatureLevel::get()] {
        let got = run(level);
        assert_eq!(got.wta.inverse_depth, want.wta.inverse_depth, "{level:?}: WTA");
        assert_eq!(
            got.tv.as_ref().unwrap().inverse_depth,
            want.tv.as_ref().unwrap().inverse_depth,
            "{level:?}: TV"
        );
        assert_eq!(
            got.normals.as_ref().unwrap().inverse_depth,
            want.normals.as_ref().unwrap().inverse_depth,
            "{level:?}: the normal prior"
        );
        assert_eq!(got.colour, want.colour, "{level:?}: the keyframe's colour");
    }
}

#[test]
fn the_learned_features_default_to_their_border_taper_and_the_others_to_none() {
    use densefeat::mapping::features::BORDER_TAPER_LEARNED;
    // SPEC.md §10.1c: the taper is chosen per feature kind on validation; `None` means the kind's.
    assert_eq!(FeatureKind::Learned(None).default_border_taper(), BORDER_TAPER_LEARNED);
    assert_eq!(FeatureKind::Rgb.default_border_taper(), 0.0);
    assert_eq!(FeatureKind::Dsift.default_border_taper(), 0.0);
    let seq = fixture();
    let mut cfg = eval_config();
    cfg.features = FeatureKind::Learned(None);
    assert_eq!(cfg.border_taper, None, "unset by default");
    assert_eq!(cfg.border_taper_px(), BORDER_TAPER_LEARNED);
    let default = reconstruct(&seq, &cfg, |_, _, _| {}).unwrap();
    cfg.border_taper = Some(BORDER_TAPER_LEARNED);
    let explicit = reconstruct(&seq, &cfg, |_, _, _| {}).unwrap();
    cfg.border_taper = Some(0.0);
    let off = reconstruct(&seq, &cfg, |_, _, _| {}).unwrap();
    let tv = |r: &densefeat::mapping::keyframe::KeyframeResult| r.tv.as_ref().unwrap().inverse_depth.clone();
    assert_eq!(tv(&default), tv(&explicit), "the default is the learned kind's taper");
    assert_ne!(tv(&default), tv(&off), "and it is on");
    cfg.features = FeatureKind::Rgb;
    cfg.border_taper = None;
    let rgb_default = reconstruct(&seq, &cfg, |_, _, _| {}).unwrap();
    cfg.border_taper = Some(0.0);
    let rgb_off = reconstruct(&seq, &cfg, |_, _, _| {}).unwrap();
    assert_eq!(tv(&rgb_default), tv(&rgb_off), "RGB is not tapered by default");
}

#[test]
fn border_taper_weights_the_data_term_towards_the_edge_and_leaves_wta_alone() {
    use densefeat::costvolume::{border_weight, taper_border, BORDER_WEIGHT_FLOOR};
    // SPEC.md §10.1c: clamp((d + 0.5) / r, 0.05, 1), d the distance to the nearest edge.
    assert_eq!(border_weight(0, 0, 10, 12, 4.0), 0.125);
    assert_eq!(border_weight(1, 6, 10, 12, 4.0), 0.375);
    assert_eq!(border_weight(9, 6, 10, 12, 4.0), 0.125, "the bottom row is on the edge too");
    assert_eq!(border_weight(5, 6, 10, 12, 4.0), 1.0);
    assert_eq!(border_weight(0, 0, 10, 12, 100.0), BORDER_WEIGHT_FLOOR);
    assert_eq!(border_weight(0, 0, 10, 12, 0.0), 1.0, "0 is off");
    // Unseen cells are UNSEEN_COST (f32::MAX, finite): they must stay unseen in the strip, also where
    // a whole pixel is unseen (until 2026-12-05 they became seen cells of cost w · f32::MAX).
    let unseen = densefeat::costvolume::UNSEEN_COST;
    let mut costs = ndarray::Array3::<f32>::from_elem((4, 5, 2), 2.0);
    costs[[0, 0, 1]] = unseen;
    costs[[0, 1, 0]] = unseen;
    costs[[0, 1, 1]] = unseen;
    let before = costs.clone();
    taper_border(&mut costs, 0.0);
    assert_eq!(costs, before);
    taper_border(&mut costs, 2.0);
    assert_eq!(costs[[0, 0, 0]], 0.5, "2 x 0.25");
    assert_eq!(costs[[0, 0, 1]], unseen, "an unseen cell stays unseen");
    assert_eq!((costs[[0, 1, 0]], costs[[0, 1, 1]]), (unseen, unseen), "an unseen pixel stays unseen");
    assert_eq!(costs[[1, 2, 0]], 2.0 * 0.75);
    assert_eq!(costs[[2, 2, 1]], 2.0 * 0.75, "row 2 of 4 is 1 from the bottom edge");

    // In the mapper: WTA unchanged, the regularised depth changed, and bad values refused.
    let seq = fixture();
    let mut cfg = small_config();
    let plain = reconstruct(&seq, &cfg, |_, _, _| {}).unwrap();
    cfg.border_taper = Some(16.0);
    let tapered = reconstruct(&seq, &cfg, |_, _, _| {}).unwrap();
    assert_eq!(plain.wta.inverse_depth, tapered.wta.inverse_depth);
    assert_ne!(plain.tv.as_ref().unwrap().inverse_depth, tapered.tv.as_ref().unwrap().inverse_depth);
    cfg.border_taper = Some(-1.0);
    let (name, _) = invalid_argument(reconstruct(&seq, &cfg, |_, _, _| {}).unwrap_err());
    assert_eq!(name, "border-taper");
}

/// SPEC.md §10.4: `--regularizer tgv` writes its estimate as `tgv` (a TGV solve, not TV's), and
/// `--tgv-beta` is refused without it or when not positive, naming the flag.
#[test]
fn cli_reconstruct_runs_tgv_and_checks_its_weight() {
    let run = |extra: &[&str], dir: &Path| {
        Command::new(env!("CARGO_BIN_EXE_densefeat"))
            .args([
                "reconstruct",
                "--sequence",
                FIXTURE,
                "--keyframe",
                "20",
                "--window",
                "2,2",
                "--bins",
                "16",
            ])
            .args(["--level", "2", "--iterations", "20"])
            .args(extra)
            .arg("--out")
            .arg(dir)
            .output()
            .unwrap()
    };
    let tgv = tempfile::tempdir().unwrap();
    let out = run(&["--regularizer", "tgv", "--tgv-beta", "2"], tgv.path());
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert!(String::from_utf8_lossy(&out.stdout).contains("tgv:"));
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(tgv.path().join("metrics.json")).unwrap()).unwrap();
    assert!(json["metrics"]["tgv"]["rms"].is_number() && json["metrics"]["tv"].is_null(), "{json}");
    let tv = tempfile::tempdir().unwrap();
    assert!(run(&["--regularizer", "tv"], tv.path()).status.success());
    let a = std::fs::read(tgv.path().join("depth_tgv.npy")).unwrap();
    let b = std::fs::read(tv.path().join("depth_tv.npy")).unwrap();
    assert_ne!(a, b, "TGV must not be TV's solve");
    for bad in [
        &["--tgv-beta", "4"][..],
        &["--regularizer", "tgv", "--tgv-beta", "0"],
        &["--regularizer", "tgv", "--tgv-beta", "nan"],
    ] {
        let d = tempfile::tempdir().unwrap();
        let out = run(bad, &d.path().join("o"));
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success() && err.contains("--tgv-beta"), "{bad:?}: {err}");
        assert!(!d.path().join("o").exists(), "{bad:?}: nothing is written");
    }
}

/// SPEC.md §10.2, "Confidence weighting" in the mapper: it changes the normal prior's estimate and
/// nothing else (WTA, the TV solve), `None` resolves to the kind's default, and a bad `c₀` is refused
/// naming the flag before any work.
#[test]
fn prior_confidence_weights_only_the_normal_prior() {
    use densefeat::mapping::features::PRIOR_CONFIDENCE_RGB;
    use densefeat::mapping::normals::NormalsSource;
    assert_eq!(FeatureKind::Rgb.default_prior_confidence(), PRIOR_CONFIDENCE_RGB);
    for k in [FeatureKind::Learned(None), FeatureKind::B1(None), FeatureKind::Dsift, FeatureKind::Patch7] {
        assert_eq!(k.default_prior_confidence(), 0.0, "{k:?}");
    }
    let seq = fixture();
    let mut cfg = eval_config();
    cfg.regularizer = Regularizer::TvAndNormals;
    cfg.normals = Some(NormalsSource::GroundTruth);
    assert_eq!(cfg.prior_confidence_c0(), PRIOR_CONFIDENCE_RGB);
    cfg.prior_confidence = Some(0.0);
    let off = reconstruct(&seq, &cfg, |_, _, _| {}).unwrap();
    cfg.prior_confidence = Some(0.5);
    let on = reconstruct(&seq, &cfg, |_, _, _| {}).unwrap();
    assert_eq!(off.wta.inverse_depth, on.wta.inverse_depth);
    assert_eq!(off.tv.as_ref().unwrap().inverse_depth, on.tv.as_ref().unwrap().inverse_depth);
    assert_ne!(off.normals.as_ref().unwrap().inverse_depth, on.normals.as_ref().unwrap().inverse_depth);
    for bad in [-1.0, f64::NAN] {
        cfg.prior_confidence = Some(bad);
        let (name, what) = invalid_argument(reconstruct(&seq, &cfg, |_, _, _| {}).unwrap_err());
        assert_eq!(name, "prior-confidence", "{what}");
    }
}

/// SPEC.md §10.2, "Normal edges" in the mapper: the kinds' defaults, `σ` changes the normal prior's
/// estimate and nothing else, and a bad `σ` is refused naming the flag before any work.
#[test]
fn prior_edges_change_only_the_normal_prior() {
    use densefeat::mapping::features::PRIOR_EDGES_LEARNED;
    use densefeat::mapping::normals::NormalsSource;
    assert_eq!(FeatureKind::Learned(None).default_prior_edges(), PRIOR_EDGES_LEARNED);
    for k in [FeatureKind::Rgb, FeatureKind::B1(None), FeatureKind::Dsift, FeatureKind::Patch7] {
        assert_eq!(k.default_prior_edges(), 0.0, "{k:?}");
    }
    let seq = fixture();
    let mut cfg = eval_config();
    cfg.regularizer = Regularizer::TvAndNormals;
    cfg.normals = Some(NormalsSource::GroundTruth);
    assert_eq!(cfg.prior_edges_deg(), cfg.features.default_prior_edges());
    cfg.prior_edges = Some(0.0);
    let off = reconstruct(&seq, &cfg, |_, _, _| {}).unwrap();
    cfg.prior_edges = Some(20.0);
    let on = reconstruct(&seq, &cfg, |_, _, _| {}).unwrap();
    assert_eq!(off.wta.inverse_depth, on.wta.inverse_depth);
    assert_eq!(off.tv.as_ref().unwrap().inverse_depth, on.tv.as_ref().unwrap().inverse_depth);
    assert_ne!(off.normals.as_ref().unwrap().inverse_depth, on.normals.as_ref().unwrap().inverse_depth);
    for bad in [-1.0, f64::NAN] {
        cfg.prior_edges = Some(bad);
        let (name, what) = invalid_argument(reconstruct(&seq, &cfg, |_, _, _| {}).unwrap_err());
        assert_eq!(name, "prior-edges", "{what}");
    }
}
