//! The per-pixel descriptor baselines in the mapper (SPEC.md §9a): `--features b1` and `dsift`
//! parse, extract on the mapper's grid like the learned features and RGB, reach the volume's memory
//! estimate, and `eval --methods dsift-wta,b1-tv` runs on the rendered fixture.

use std::path::{Path, PathBuf};
use std::process::Command;

use densefeat::backend::default_backend;
use densefeat::costvolume::NO_TRUNCATION;
use densefeat::dsift::{dense_sift, DsiftImpl, DsiftParams, CHANNELS};
use densefeat::mapping::evaluate::Method;
use densefeat::mapping::features::{load_weights, upsample_to};
use densefeat::mapping::{FeatureExtractor, FeatureKind, Truncation};
use densefeat::nn::FeatureNet;
use densefeat::ops::downsample2x;
use densefeat::sequence::open;

const FIXTURE: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/fixtures/synthetic/room_s1");

fn bits(a: &ndarray::Array3<f32>) -> Vec<u32> {
    a.iter().map(|v| v.to_bits()).collect()
}

#[test]
fn feature_kinds_and_methods_parse() {
    let parse = |s: &str| s.parse::<FeatureKind>();
    assert_eq!(parse("b1").unwrap(), FeatureKind::B1(None));
    assert_eq!(parse("b1=w.safetensors").unwrap(), FeatureKind::B1(Some(PathBuf::from("w.safetensors"))));
    assert_eq!(parse("dsift").unwrap(), FeatureKind::Dsift);
    assert_eq!(parse("patch7").unwrap(), FeatureKind::Patch7);
    for bad in ["b1=", "sift", "dsift=x", "B1"] {
        let e = parse(bad).unwrap_err().to_string();
        assert!(e.contains("--features") && e.contains("dsift") && e.contains("b1"), "{bad}: {e}");
    }
    assert_eq!(FeatureKind::B1(None).name(), "b1");
    assert_eq!(FeatureKind::Dsift.name(), "dsift");
    assert_eq!(FeatureKind::Patch7.name(), "patch7");
    assert_eq!("patch7-tv".parse::<Method>().unwrap(), Method::Patch7Tv);
    for m in Method::EVERY {
        assert_eq!(m.name().parse::<Method>().unwrap(), m);
        assert!(m.name().starts_with(m.feature_name()));
    }
    assert_eq!("dsift-wta".parse::<Method>().unwrap().features(None), FeatureKind::Dsift);
    let w = Path::new("w.safetensors");
    assert_eq!(Method::B1Tv.features(Some(w)), FeatureKind::B1(Some(w.to_path_buf())));
    assert!("sift-tv".parse::<Method>().unwrap_err().to_string().contains("dsift-tv"));
    // Every kind has its own truncation, none by default (SPEC.md §9a.3).
    let t = Truncation { rgb: 1.0, learned: 2.0, b1: 3.0, dsift: 4.0, patch7: 5.0 };
    assert_eq!(t.of(&FeatureKind::B1(None)), 3.0);
    assert_eq!(t.of(&FeatureKind::Dsift), 4.0);
    assert_eq!(t.of(&FeatureKind::Patch7), 5.0);
    assert_eq!(Truncation::DEFAULT.of(&FeatureKind::Patch7), NO_TRUNCATION);
    assert_eq!(Truncation::DEFAULT.of(&FeatureKind::Dsift), NO_TRUNCATION);
    assert_eq!(Truncation::DEFAULT.of(&FeatureKind::B1(None)), NO_TRUNCATION);
}

#[test]
fn b1_extractor_gives_the_networks_block1_on_the_mapper_grid() {
    // SPEC.md §9a.1: the shipped network's block-1 output (32 channels, level 1), resampled to the
    // mapper's level exactly as the learned features are.
    let seq = open(Path::new(FIXTURE)).unwrap();
    let rgb = seq.load_frame(20).unwrap().rgb;
    let (h, w, _) = rgb.dim();
    let backend = default_backend();
    let net = FeatureNet::new(load_weights(None).unwrap()).unwrap();
    let block1 = net.block1(rgb.view(), backend.as_ref()).unwrap();
    let forward = net.forward(rgb.view(), backend.as_ref()).unwrap();
    assert_eq!(bits(&block1), bits(&forward.blocks[0]));
    let at1 = FeatureExtractor::new(FeatureKind::B1(None), 1, backend.clone()).unwrap();
    assert_eq!((at1.channels(), at1.network_output_level(), at1.name()), (32, Some(1), "b1"));
    let f1 = at1.extract(&rgb).unwrap().data;
    assert_eq!(f1.shape(), [h / 2, w / 2, 32]);
    assert_eq!(bits(&f1), bits(&block1));
    let at0 = FeatureExtractor::new(FeatureKind::B1(None), 0, backend.clone()).unwrap();
    let f0 = at0.extract(&rgb).unwrap().data;
    assert_eq!(bits(&f0), bits(&upsample_to(block1.view(), 1, h, w)));
    // Not the learned features.
    let learned = FeatureExtractor::new(FeatureKind::Learned(None), 1, backend).unwrap();
    assert_ne!(bits(&learned.extract(&rgb).unwrap().data), bits(&f1));
}

#[test]
fn dsift_extractor_gives_level0_descriptors_downsampled_like_rgb() {
    let seq = open(Path::new(FIXTURE)).unwrap();
    let rgb = seq.load_frame(10).unwrap().rgb;
    let (h, w, _) = rgb.dim();
    let d0 = dense_sift(rgb.view(), &DsiftParams::DEFAULT, DsiftImpl::Fast).unwrap();
    assert_eq!(d0.shape(), [h, w, CHANNELS]);
    let backend = default_backend();
    let at0 = FeatureExtractor::new(FeatureKind::Dsift, 0, backend.clone()).unwrap();
    assert_eq!((at0.channels(), at0.network_output_level()), (CHANNELS, None));
    assert_eq!(bits(&at0.extract(&rgb).unwrap().data), bits(&d0));
    let at1 = FeatureExtractor::new(FeatureKind::Dsift, 1, backend).unwrap();
    let f1 = at1.extract(&rgb).unwrap().data;
    assert_eq!(bits(&f1), bits(&downsample2x(d0.view()).unwrap()));
    // A textured render: most descriptors are at full strength (unit length x 512 after the clip).
    let full = f1
        .outer_iter()
        .flat_map(|row| {
            row.outer_iter()
                .map(|px| px.iter().map(|v| f64::from(*v).powi(2)).sum::<f64>().sqrt())
                .collect::<Vec<_>>()
        })
        .filter(|n| *n > 400.0)
        .count();
    assert!(full * 2 > f1.shape()[0] * f1.shape()[1], "{full} of {} pixels", f1.shape()[0] * f1.shape()[1]);
}

#[test]
fn memory_estimate_counts_128_channels_and_the_extraction() {
    // SPEC.md §11.2, §14.3: dense SIFT's features are H·W·128·4 bytes a frame (two of them in the
    // estimate) and its extraction holds 676 bytes a level-0 pixel.
    use densefeat::mapping::features::feature_memory;
    let (c, bytes) = feature_memory(&FeatureKind::Dsift, 240, 320).unwrap();
    assert_eq!((c, bytes), (128, 240 * 320 * 676));
    assert_eq!(densefeat::dsift::extraction_bytes(240, 320), 240 * 320 * (4 + 32 + 128 + 512));
    let (c, _) = feature_memory(&FeatureKind::B1(None), 240, 320).unwrap();
    assert_eq!(c, 32);
    let volume = densefeat::memory::cost_volume_bytes(240, 320, 128, 128);
    assert_eq!(volume, 240 * 320 * 128 * 10 + 240 * 320 * 16 * 4 + 2 * 240 * 320 * 128 * 4);
    // 320x240 at level 0, 128 bins: RGB about 100 MiB, dense SIFT about 223 MiB. A 150 MiB limit
    // runs RGB's preflight and refuses dense SIFT's before any work, naming the flags.
    let run = |features: &str| {
        Command::new(env!("CARGO_BIN_EXE_densefeat"))
            .args(["reconstruct", "--sequence", FIXTURE, "--keyframe", "20", "--window", "1,1"])
            .args(["--regularizer", "none", "--max-memory-mb", "150", "--features", features])
            .arg("--out")
            .arg(tempfile::tempdir().unwrap().path().join("o"))
            .output()
            .unwrap()
    };
    let o = run("dsift");
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(err.contains("128 feature channels (dsift)") && err.contains("--max-memory-mb"), "{err}");
    assert!(err.contains("--level"), "{err}");
    let o = run("rgb");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
}

#[test]
fn eval_runs_dsift_wta_and_b1_tv_on_the_rendered_fixture() {
    // SPEC.md §9a.4: the descriptor baselines through `eval`, on the fixture (synthetic seed 1, no
    // test or validation scene), 160x120 grid, 32 bins, 3 live frames either side.
    let dir = tempfile::tempdir().unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_densefeat"))
        .args(["eval", "--sequence", FIXTURE, "--keyframes", "20:1:20", "--window", "3,3"])
        .args(["--bins", "32", "--level", "1", "--iterations", "60", "--methods", "dsift-wta,b1-tv"])
        .args(["--truncate-dsift", "none", "--figure", "--out"])
        .arg(dir.path())
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{stdout}\n{}", String::from_utf8_lossy(&out.stderr));
    // The feature figure (issue 32 item 2): keyframe, ground truth and the two methods, 160x120
    // each, in one row of four cells of (160 + 6) x (120 + 22 + 6) pixels under a 40 pixel title.
    let fig = image::open(dir.path().join("figure_kf00020.png")).unwrap().to_rgb8();
    assert_eq!(fig.dimensions(), (4 * 166 + 6, 148 + 40));
    // The ground-truth tile is coloured (the fixture's depth is valid everywhere): no black pixel.
    let gt_black = (0..160u32)
        .flat_map(|x| (0..120u32).map(move |y| (x, y)))
        .filter(|&(x, y)| fig.get_pixel(6 + 166 + x, 40 + 22 + y).0 == [0, 0, 0]);
    assert_eq!(gt_black.count(), 0);
    let csv = std::fs::read_to_string(dir.path().join("table.csv")).unwrap();
    let header: Vec<&str> = csv.lines().next().unwrap().split(',').collect();
    let col = header.iter().position(|c| *c == "delta_1.25").unwrap();
    for method in ["dsift-wta", "b1-tv"] {
        let row: Vec<&str> = csv
            .lines()
            .find(|l| l.starts_with(&format!("{method},")))
            .unwrap_or_else(|| panic!("{csv}"))
            .split(',')
            .collect();
        let delta: f64 = row[col].parse().unwrap();
        eprintln!("{method}: δ<1.25 = {delta}");
        assert!(delta > 0.6, "{method}: δ<1.25 = {delta}\n{csv}");
        assert!(stdout.contains(&format!("| {method} |")), "{stdout}");
    }
    assert!(!csv.contains("rgb-") && !csv.contains("learned-"), "{csv}");
    // A bad value of the new flags names the flag.
    let out = Command::new(env!("CARGO_BIN_EXE_densefeat"))
        .args(["eval", "--sequence", FIXTURE, "--keyframes", "20:1:20", "--methods", "dsift-wta"])
        .args(["--truncate-dsift", "0", "--out"])
        .arg(dir.path().join("x"))
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && err.contains("--truncate-dsift"), "{err}");
}

#[test]
fn patch7_extractor_gives_the_level_grey_image() {
    // SPEC.md §9a.5: the features of `patch7` are the tent-downsampled colour's grey (1 channel);
    // the patch volume compares warped patches of it.
    let seq = open(Path::new(FIXTURE)).unwrap();
    let rgb = seq.load_frame(10).unwrap().rgb;
    let ex = FeatureExtractor::new(FeatureKind::Patch7, 1, default_backend()).unwrap();
    assert_eq!((ex.channels(), ex.name()), (1, "patch7"));
    let got = ex.extract(&rgb).unwrap().data;
    let colour = densefeat::mapping::features::downsample_to(rgb.view(), 1).unwrap();
    let want = densefeat::image::to_gray(&colour).insert_axis(ndarray::Axis(2));
    assert_eq!(bits(&got), bits(&want));
    // The volume builder is the patch volume on the host.
    let upload = ex.upload(got.clone()).unwrap();
    assert!(upload.as_host().is_some());
}

#[test]
fn eval_runs_patch7_on_the_rendered_fixture() {
    // SPEC.md §9a.5: `eval --methods patch7-wta,patch7-tv` on the fixture at level 2 (80x60), 16 bins,
    // 3 live frames either side: both rows, δ<1.25 > 0.6 (measured 0.841 and 0.857).
    let dir = tempfile::tempdir().unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_densefeat"))
        .args(["eval", "--sequence", FIXTURE, "--keyframes", "20:1:20", "--window", "3,3"])
        .args(["--bins", "16", "--level", "2", "--iterations", "60", "--methods", "patch7-wta,patch7-tv"])
        .arg("--out")
        .arg(dir.path())
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let csv = std::fs::read_to_string(dir.path().join("table.csv")).unwrap();
    let col = csv.lines().next().unwrap().split(',').position(|c| c == "delta_1.25").unwrap();
    for method in ["patch7-wta", "patch7-tv"] {
        let line =
            csv.lines().find(|l| l.starts_with(&format!("{method},"))).unwrap_or_else(|| panic!("{csv}"));
        let delta: f64 = line.split(',').nth(col).unwrap().parse().unwrap();
        assert!(delta > 0.6, "{method}: δ<1.25 = {delta}\n{csv}");
    }
}
