//! COLMAP sparse models, text and binary.

use std::path::Path;

use densefeat::geometry::{Camera, RadTan};
use densefeat::image::save_rgb_png;
use densefeat::sequence::colmap::{write_model, CameraModel, ColmapExport};
use densefeat::sequence::depth_range::depth_range_of;
use densefeat::sequence::inspect::Summary;
use densefeat::sequence::{open, open_with, Format, OpenOptions};
use nalgebra::Point3;

use crate::render::{
    assert_error, assert_same_geometry, assert_warp_matches_renderer, render, reprojection_difference,
    Rendered,
};

/// Sparse points: every 6th pixel of each frame's rendered depth, observed by that frame.
fn export(r: &Rendered, model: CameraModel, camera: Camera) -> ColmapExport {
    let mut points = Vec::new();
    let mut observations = Vec::new();
    for (_, depth, pose) in &r.frames {
        let mut obs = Vec::new();
        for ((y, x), &z) in depth.indexed_iter() {
            if z > 0.0 && x % 6 == 0 && y % 6 == 0 {
                let c = r.camera.backproject(x as f64, y as f64, 1.0 / f64::from(z));
                let w = pose * Point3::from(c);
                obs.push((x as f64, y as f64, points.len()));
                points.push([w.x, w.y, w.z]);
            }
        }
        observations.push(obs);
    }
    let images = r.frames.iter().enumerate().map(|(i, f)| (format!("{i:04}.png"), f.2)).collect();
    ColmapExport { model, camera, images, points, observations }
}

/// `dir/images/*.png` and the model in `dir/sub`.
fn write(dir: &Path, r: &Rendered, sub: &str, binary: bool) {
    std::fs::create_dir_all(dir.join("images")).unwrap();
    for (i, (rgb, _, _)) in r.frames.iter().enumerate() {
        save_rgb_png(&dir.join("images").join(format!("{i:04}.png")), rgb).unwrap();
    }
    write_model(&dir.join(sub), &export(r, CameraModel::Pinhole, Camera::pinhole(r.camera)), binary).unwrap();
}

fn round_trip(binary: bool, sub: &str) {
    let r = render(96, 72, 4, None);
    let d = tempfile::tempdir().unwrap();
    write(d.path(), &r, sub, binary);
    let seq = open(d.path()).unwrap();
    assert_eq!(seq.format, Format::Colmap);
    assert!(!seq.metric, "COLMAP is not metric without --scale");
    assert_same_geometry(&seq, &r);
    for (a, b) in [(0, 1), (0, 3), (2, 1)] {
        let e = reprojection_difference(&seq, &r, a, b);
        assert!(e < crate::render::REPROJECTION_TOLERANCE_PX, "{a} -> {b}: {e:e} px");
    }
    assert_warp_matches_renderer(&seq, &r, 0, 1, Some(&r.frames[0].1));
    // The sparse range of each frame is the rule applied to the depths of its points.
    for (f, (_, depth, _)) in seq.frames.iter().zip(&r.frames) {
        let z: Vec<f64> = depth
            .indexed_iter()
            .filter(|((y, x), z)| **z > 0.0 && x % 6 == 0 && y % 6 == 0)
            .map(|(_, z)| f64::from(*z))
            .collect();
        let (want, got) = (depth_range_of(z).unwrap(), f.sparse_depth_range.unwrap());
        assert!(
            (want.0 - got.0).abs() < 1e-6 * want.0 && (want.1 - got.1).abs() < 1e-6 * want.1,
            "{want:?} {got:?}"
        );
        assert_eq!(seq.estimate_depth_range(0).unwrap(), seq.frames[0].sparse_depth_range);
    }
    let text = Summary::new(&seq).unwrap().to_string();
    eprintln!("{text}");
    for part in [
        "format       COLMAP sparse model",
        "scale        NONE",
        "COLMAP poses have no metric scale",
        "sparse depth 4 of 4 frames",
    ] {
        assert!(text.contains(part), "inspect output lacks {part:?}");
    }
    // --scale multiplies every length and makes the sequence metric.
    let scaled = open_with(d.path(), &OpenOptions { scale: Some(2.5), ..OpenOptions::default() }).unwrap();
    assert!(scaled.metric);
    let (a, b) = (scaled.frames[1].pose.translation.vector, seq.frames[1].pose.translation.vector);
    assert!((a - 2.5 * b).norm() < 1e-12);
    let (sa, sb) = (scaled.frames[1].sparse_depth_range.unwrap(), seq.frames[1].sparse_depth_range.unwrap());
    assert!((sa.1 - 2.5 * sb.1).abs() < 1e-12);
    assert!(Summary::new(&scaled).unwrap().to_string().contains("scale        metric"));
}

#[test]
fn colmap_text_round_trip_in_sparse_0() {
    round_trip(false, "sparse/0");
}

#[test]
fn colmap_binary_round_trip_in_sparse() {
    round_trip(true, "sparse");
}

#[test]
fn colmap_distorted_models_are_undistorted_on_load() {
    let r = render(48, 36, 2, None);
    let k = r.camera;
    for (model, d) in [
        (CameraModel::SimpleRadial, RadTan { k1: -0.05, ..RadTan::default() }),
        (CameraModel::Radial, RadTan { k1: -0.05, k2: 0.01, ..RadTan::default() }),
        (CameraModel::Opencv, RadTan { k1: -0.05, k2: 0.01, p1: 1e-3, p2: -2e-3, k3: 0.0 }),
    ] {
        for binary in [false, true] {
            let dir = tempfile::tempdir().unwrap();
            std::fs::create_dir_all(dir.path().join("images")).unwrap();
            for (i, f) in r.frames.iter().enumerate() {
                save_rgb_png(&dir.path().join("images").join(format!("{i:04}.png")), &f.0).unwrap();
            }
            let camera = Camera { pinhole: k, distortion: Some(d) };
            write_model(dir.path(), &export(&r, model, camera), binary).unwrap();
            let seq = open(dir.path()).unwrap();
            assert_eq!(seq.raw_camera.distortion, Some(d), "{model:?}");
            assert!(seq.undistorts());
            assert_eq!(seq.camera, k);
            assert!(Summary::new(&seq).unwrap().to_string().contains("undistorted on load"));
        }
    }
}

/// A written text model in a temp dir, for corrupting.
fn text_model() -> tempfile::TempDir {
    let r = render(48, 36, 2, None);
    let d = tempfile::tempdir().unwrap();
    write(d.path(), &r, "sparse/0", false);
    d
}

fn edit(path: &Path, f: impl FnOnce(String) -> String) {
    let s = std::fs::read_to_string(path).unwrap();
    std::fs::write(path, f(s)).unwrap();
}

/// Replace line `n` (1-based) of `path`.
fn set_line(path: &Path, n: usize, text: &str) {
    edit(path, |s| {
        let mut lines: Vec<String> = s.lines().map(str::to_string).collect();
        lines[n - 1] = text.to_string();
        lines.join("\n") + "\n"
    });
}

fn line(path: &Path, n: usize) -> String {
    std::fs::read_to_string(path).unwrap().lines().nth(n - 1).unwrap().to_string()
}

#[test]
fn colmap_text_malformed_inputs_name_file_and_line() {
    // images.txt: 3 comment lines, then image 1 on line 4, its points on line 5, image 2 on line 6.
    type LineEdit = Box<dyn Fn(String) -> String>;
    let cases: Vec<(&str, usize, LineEdit, Vec<&str>)> = vec![
        ("images.txt", 4, Box::new(|l| l.replacen(' ', " x", 1)), vec!["images.txt:4:", "quaternion", "\"x"]),
        (
            "images.txt",
            4,
            Box::new(|l| {
                let mut f: Vec<String> = l.split(' ').map(str::to_string).collect();
                for v in &mut f[1..5] {
                    *v = "0".into();
                }
                f.join(" ")
            }),
            vec!["images.txt:4:", "quaternion norm is 0"],
        ),
        (
            "images.txt",
            4,
            Box::new(|l| l.replace(" 1 0000.png", " 7 0000.png")),
            vec!["images.txt:4:", "camera 7"],
        ),
        (
            "images.txt",
            4,
            Box::new(|l| l.replace("0000.png", "missing.png")),
            vec!["images.txt:4:", "missing.png", "does not exist"],
        ),
        ("images.txt", 4, Box::new(|l| l.replace(" 0000.png", "")), vec!["images.txt:4:", "10 fields"]),
        ("images.txt", 5, Box::new(|l| l + " 3.5"), vec!["images.txt:5:", "multiple of 3"]),
        ("images.txt", 5, Box::new(|l| l + " 1 2 999999"), vec!["images.txt:4:", "3D point 999999"]),
        (
            "images.txt",
            6,
            Box::new(|l| l.replace("0001.png", "0000.png")),
            vec!["images.txt:6:", "\"0000.png\" is registered twice"],
        ),
        (
            "cameras.txt",
            3,
            Box::new(|l| format!("{l}\n{l}")),
            vec!["cameras.txt:4:", "camera id 1 is defined twice"],
        ),
        (
            "cameras.txt",
            3,
            Box::new(|l| l.replace("PINHOLE", "FOO")),
            vec!["cameras.txt:3:", "unknown camera model \"FOO\""],
        ),
        (
            "cameras.txt",
            3,
            Box::new(|l| l + " 0.1"),
            vec!["cameras.txt:3:", "PINHOLE has 4 parameters, the line has 5"],
        ),
        (
            "cameras.txt",
            3,
            Box::new(|l| l.replace("PINHOLE", "OPENCV_FISHEYE") + " 0 0 0 0"),
            vec!["cameras.txt:3:", "OPENCV_FISHEYE", "supported"],
        ),
        (
            "points3D.txt",
            3,
            Box::new(|l| l.replacen(' ', " nan?", 1)),
            vec!["points3D.txt:3:", "not a number"],
        ),
    ];
    for (file, n, f, parts) in cases {
        let d = text_model();
        let p = d.path().join("sparse/0").join(file);
        set_line(&p, n, &f(line(&p, n)));
        assert_error(open(d.path()), &parts);
    }
}

#[test]
fn colmap_binary_malformed_inputs_name_record_and_offset() {
    let r = render(48, 36, 2, None);
    let d = tempfile::tempdir().unwrap();
    write(d.path(), &r, "sparse", true);
    let images = d.path().join("sparse/images.bin");
    let bytes = std::fs::read(&images).unwrap();
    // Truncated inside the second image record's quaternion: record 0 is 89 bytes from the file
    // start (count, id, pose, camera, "0000.png\0", 2D point count) plus 24 per 2D point.
    let n0 = u64::from_le_bytes(bytes[81..89].try_into().unwrap()) as usize;
    let start1 = 89 + 24 * n0;
    std::fs::write(&images, &bytes[..start1 + 10]).unwrap();
    let at = format!("image record 1 (starting at byte {start1})");
    assert_error(open(d.path()), &["images.bin", "truncated", "quaternion", &at]);
    // Truncated in its 2D points: the count promises more than is left.
    std::fs::write(&images, &bytes[..bytes.len() - 5]).unwrap();
    assert_error(open(d.path()), &["images.bin", "2D point count", &at, "bytes follow"]);
    // A count far beyond the file.
    let mut big = bytes.clone();
    big[..8].copy_from_slice(&u64::MAX.to_le_bytes());
    std::fs::write(&images, &big).unwrap();
    assert_error(open(d.path()), &["images.bin", "image count", "bytes follow"]);
    // Trailing garbage.
    let mut extra = bytes.clone();
    extra.push(7);
    std::fs::write(&images, &extra).unwrap();
    assert_error(open(d.path()), &["images.bin", "1 trailing bytes"]);
    // A zero quaternion in record 0 (qw at byte 8 + 4).
    let mut zero = bytes.clone();
    zero[12..20].copy_from_slice(&0f64.to_le_bytes());
    zero[20..28].copy_from_slice(&0f64.to_le_bytes());
    zero[28..36].copy_from_slice(&0f64.to_le_bytes());
    zero[36..44].copy_from_slice(&0f64.to_le_bytes());
    std::fs::write(&images, &zero).unwrap();
    assert_error(open(d.path()), &["images.bin", "record 0 (byte offset 8)", "quaternion norm is 0"]);
    std::fs::write(&images, &bytes).unwrap();
    // An unknown camera model id.
    let cameras = d.path().join("sparse/cameras.bin");
    let mut c = std::fs::read(&cameras).unwrap();
    c[12..16].copy_from_slice(&99i32.to_le_bytes());
    std::fs::write(&cameras, &c).unwrap();
    assert_error(open(d.path()), &["cameras.bin", "record 0 (byte offset 8)", "unknown camera model id 99"]);
}

#[test]
fn colmap_cli_inspect_warns_and_map_needs_scale_then_runs_with_auto_range() {
    use std::process::Command;
    let r = render(96, 72, 4, None);
    let d = tempfile::tempdir().unwrap();
    write(d.path(), &r, "sparse/0", false);
    let exe = env!("CARGO_BIN_EXE_densefeat");
    let out = Command::new(exe).arg("inspect").arg(d.path()).output().unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert!(stdout.contains("WARNING      COLMAP poses have no metric scale"), "{stdout}");
    let o = d.path().join("out");
    let map = |extra: &[&str]| {
        Command::new(exe)
            .args([
                "map",
                "--features",
                "rgb",
                "--regularizer",
                "none",
                "--bins",
                "16",
                "--voxel-size",
                "0.1",
            ])
            .arg("--sequence")
            .arg(d.path())
            .arg("--out")
            .arg(&o)
            .args(extra)
            .output()
            .unwrap()
    };
    let refused = map(&[]);
    let stderr = String::from_utf8_lossy(&refused.stderr);
    assert!(!refused.status.success());
    assert!(stderr.contains("invalid --scale") && stderr.contains("has no metric scale"), "{stderr}");
    let ran = map(&["--scale", "1", "--depth-range", "auto"]);
    assert!(ran.status.success(), "{}", String::from_utf8_lossy(&ran.stderr));
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(o.join("map.json")).unwrap()).unwrap();
    let text = json.to_string();
    assert!(text.contains("\"depth_range_auto\":true"), "{text}");
    assert!(text.contains("\"depth_range\":["), "map.json lists each keyframe's estimated range: {text}");
}

#[test]
fn colmap_opencv_images_are_undistorted_onto_the_pinhole_rendering() {
    // A smooth pattern seen through a distorted camera (`common::pinhole_and_distorted`, as `tests/image_ops.rs` uses it), written as
    // 8-bit PNGs with an OPENCV model: loading undistorts it onto the pinhole rendering within half
    // a grey level of quantisation plus half of interpolation, in the interior.
    use densefeat::geometry::PinholeCamera;
    use densefeat::sequence::open_with;
    let k = PinholeCamera::new(120.0, 118.0, 63.5, 47.5, 128, 96).unwrap();
    let d = RadTan { k1: -0.2, k2: 0.05, p1: 2e-3, p2: -1e-3, k3: 0.0 };
    let pattern = |x: f64, y: f64| 128.0 + 100.0 * (8.0 * x).sin() * (6.0 * y).cos();
    let (pinhole, raw) = crate::common::pinhole_and_distorted(&k, &d, pattern);
    let dir = tempfile::tempdir().unwrap();
    std::fs::create_dir_all(dir.path().join("images")).unwrap();
    let mut images = Vec::new();
    for i in 0..2 {
        save_rgb_png(&dir.path().join("images").join(format!("{i:04}.png")), &raw).unwrap();
        images.push((format!("{i:04}.png"), nalgebra::Isometry3::translation(0.1 * i as f64, 0.0, 0.0)));
    }
    let e = ColmapExport {
        model: CameraModel::Opencv,
        camera: Camera { pinhole: k, distortion: Some(d) },
        images,
        points: Vec::new(),
        observations: vec![Vec::new(), Vec::new()],
    };
    write_model(&dir.path().join("sparse/0"), &e, true).unwrap();
    let worst = |undistort: bool| {
        let seq = open_with(dir.path(), &OpenOptions { undistort, ..OpenOptions::default() }).unwrap();
        let rgb = seq.load_frame(1).unwrap().rgb;
        let mut w = 0.0f32;
        for v in 6..90 {
            for u in 6..122 {
                w = w.max((rgb[[v, u, 0]] - pinhole[[v, u, 0]]).abs());
            }
        }
        w
    };
    let (on, off) = (worst(true), worst(false));
    eprintln!("worst grey error against the pinhole rendering: undistorted {on:.3}, raw {off:.3}");
    assert!(on < 1.0, "undistorted worst error {on}");
    assert!(off > 10.0 * on, "distortion must matter in this test: raw worst error {off}");
}
