//! COLMAP sparse models, text and binary.

use std::path::Path;

use densefeat::geometry::{Camera, RadTan};
use densefeat::image::save_rgb_png;
use densefeat::sequence::colmap::{write_model, CameraModel, ColmapExport};
use densefeat::sequence::depth_range::depth_range_of;
use densefeat::sequence::inspect::Summary;
use densefeat::sequence::{open, open_with, Format, Frame, OpenOptions};
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

/// A COLMAP text model written by hand, as COLMAP's undistorter writes one: a `PINHOLE` camera per
/// image, principal points in COLMAP's convention (top-left pixel centre at `(0.5, 0.5)`), images of
/// two sizes, and 2D observations made by projecting the world points with a projection written
/// here (not by our COLMAP writer). Images 0 and 2 have identical parameters under different ids.
struct PerImageModel {
    dir: tempfile::TempDir,
    cameras: Vec<densefeat::geometry::PinholeCamera>,
    depth0: densefeat::image::DepthMap,
}

fn per_image_model(frames: usize) -> PerImageModel {
    use densefeat::geometry::PinholeCamera;
    use std::fmt::Write as _;
    let shapes = [
        (80.0, 80.0, 47.5, 35.5, 96, 72),
        (62.0, 63.0, 39.0, 29.0, 80, 60),
        (80.0, 80.0, 47.5, 35.5, 96, 72),
        (70.0, 70.0, 40.0, 31.0, 80, 60),
    ];
    let cameras: Vec<PinholeCamera> = (0..frames)
        .map(|i| {
            let (fx, fy, cx, cy, w, h) = shapes[i % shapes.len()];
            PinholeCamera::new(fx, fy, cx, cy, w, h).unwrap()
        })
        .collect();
    // Frame i of the same scene (seed and trajectory), rendered through camera i.
    let renders: Vec<Rendered> = cameras.iter().map(|&c| render(96, 72, frames, Some(c))).collect();
    let dir = tempfile::tempdir().unwrap();
    std::fs::create_dir_all(dir.path().join("images")).unwrap();
    std::fs::create_dir_all(dir.path().join("sparse/0")).unwrap();
    // World points: every 5th pixel of frame 0's rendered depth.
    let (_, depth0, pose0) = &renders[0].frames[0];
    let k0 = cameras[0];
    let mut points = Vec::new();
    for ((y, x), &z) in depth0.indexed_iter() {
        if z > 0.0 && x % 5 == 0 && y % 5 == 0 {
            let c = nalgebra::Vector3::new(
                (x as f64 - k0.cx) / k0.fx * f64::from(z),
                (y as f64 - k0.cy) / k0.fy * f64::from(z),
                f64::from(z),
            );
            points.push(pose0 * Point3::from(c));
        }
    }
    let (mut cams, mut imgs, mut pts) = (String::new(), String::new(), String::new());
    cams.push_str("# Camera list with one line of data per camera:\n");
    imgs.push_str("# Image list with two lines of data per image:\n");
    for (i, k) in cameras.iter().enumerate() {
        let (rgb, _, pose) = &renders[i].frames[i];
        let name = format!("{i:04}.png");
        save_rgb_png(&dir.path().join("images").join(&name), rgb).unwrap();
        // COLMAP: principal point with the top-left pixel centre at (0.5, 0.5).
        writeln!(
            cams,
            "{} PINHOLE {} {} {} {} {} {}",
            i + 1,
            k.width,
            k.height,
            k.fx,
            k.fy,
            k.cx + 0.5,
            k.cy + 0.5
        )
        .unwrap();
        let t_cw = pose.inverse();
        let q = t_cw.rotation.quaternion();
        let t = t_cw.translation.vector;
        writeln!(imgs, "{} {} {} {} {} {} {} {} {} {name}", i + 1, q.w, q.i, q.j, q.k, t.x, t.y, t.z, i + 1)
            .unwrap();
        let mut obs = Vec::new();
        for (id, p) in points.iter().enumerate() {
            let c = t_cw * p;
            if c.z <= 0.0 {
                continue;
            }
            let (u, v) = (k.fx * c.x / c.z + k.cx + 0.5, k.fy * c.y / c.z + k.cy + 0.5);
            if u >= 0.0 && v >= 0.0 && u < k.width as f64 && v < k.height as f64 {
                obs.push(format!("{u} {v} {}", id + 1));
            }
        }
        writeln!(imgs, "{}", obs.join(" ")).unwrap();
    }
    for (id, p) in points.iter().enumerate() {
        writeln!(pts, "{} {} {} {} 128 128 128 0.5", id + 1, p.x, p.y, p.z).unwrap();
    }
    let sparse = dir.path().join("sparse/0");
    std::fs::write(sparse.join("cameras.txt"), cams).unwrap();
    std::fs::write(sparse.join("images.txt"), imgs).unwrap();
    std::fs::write(sparse.join("points3D.txt"), pts).unwrap();
    PerImageModel { dir, cameras, depth0: depth0.clone() }
}

#[test]
fn colmap_one_camera_per_image_of_two_sizes_loads_with_each_frames_camera() {
    let m = per_image_model(4);
    let seq = open(m.dir.path()).unwrap();
    assert_eq!(seq.raw_cameras.len(), 3, "ids 1 and 3 have identical parameters: merged");
    for (i, want) in m.cameras.iter().enumerate() {
        let got = seq.frame_camera(i);
        assert_eq!((got.width, got.height), (want.width, want.height), "frame {i}");
        for (a, b) in [(got.fx, want.fx), (got.fy, want.fy), (got.cx, want.cx), (got.cy, want.cy)] {
            assert!((a - b).abs() < 1e-12, "frame {i}: {got:?} vs {want:?}");
        }
        let f = seq.load_frame(i).unwrap();
        assert_eq!(f.rgb.dim().1, want.width, "frame {i} is loaded at its own size");
        assert_eq!(f.camera, got);
    }
    // The stored 2D observations, reprojected from points3D with the reader's cameras and poses
    // (COLMAP's coordinates are ours + 0.5).
    let sparse = m.dir.path().join("sparse/0");
    let pts: std::collections::HashMap<u64, Point3<f64>> =
        std::fs::read_to_string(sparse.join("points3D.txt"))
            .unwrap()
            .lines()
            .map(|l| {
                let f: Vec<f64> = l.split(' ').take(4).map(|v| v.parse().unwrap()).collect();
                (f[0] as u64, Point3::new(f[1], f[2], f[3]))
            })
            .collect();
    let text = std::fs::read_to_string(sparse.join("images.txt")).unwrap();
    let lines: Vec<&str> = text.lines().skip(1).collect();
    let (mut worst, mut n) = (0.0f64, 0);
    for (i, pair) in lines.chunks(2).enumerate() {
        let t_cw = seq.frames[i].pose.inverse();
        let k = seq.frame_camera(i);
        let f: Vec<&str> = pair[1].split(' ').collect();
        for o in f.chunks(3) {
            let (u, v, id): (f64, f64, u64) =
                (o[0].parse().unwrap(), o[1].parse().unwrap(), o[2].parse().unwrap());
            let uv = k.project(&(t_cw * pts[&id]).coords).unwrap();
            worst = worst.max(((uv.x + 0.5 - u).powi(2) + (uv.y + 0.5 - v).powi(2)).sqrt());
            n += 1;
        }
    }
    eprintln!("{n} observations reproject within {worst:e} px");
    assert!(n > 200 && worst < 1.5, "{n} observations, worst {worst} px");
    assert!(worst < 1e-6, "exact model: {worst} px");
    // The images agree with those cameras: frame 1 (80x60, its own intrinsics) warps onto frame 0
    // (96x72) with the rendered depth far better than without a warp.
    let mut f0 = seq.load_frame(0).unwrap();
    f0.depth = Some(m.depth0.clone());
    let f1 = seq.load_frame(1).unwrap();
    let c = densefeat::eval::photometric_warp_check(&f0, &f1).unwrap();
    // With frame 0's intrinsics for frame 1 (the one-camera assumption) the warp is much worse.
    let k0 = m.cameras[0];
    let one = densefeat::geometry::PinholeCamera::new(k0.fx, k0.fy, k0.cx, k0.cy, 80, 60).unwrap();
    let wrong = densefeat::eval::photometric_warp_check(&f0, &Frame { camera: one, ..f1 }).unwrap();
    eprintln!("warp 1 -> 0: own camera {c:?}, frame 0's camera {wrong:?}");
    assert!(c.gain() > 2.5 && c.warped_error < 0.6 * wrong.warped_error, "{c:?} vs {wrong:?}");
    let text = Summary::new(&seq).unwrap().to_string();
    eprintln!("{text}");
    assert!(text.contains("cameras      3 (each frame is used with its own)"), "{text}");
    assert!(text.contains("frames       4 (2 sizes: 80x60 x2, 96x72 x2)"), "{text}");
}

#[test]
fn colmap_one_camera_per_image_reconstructs_and_maps() {
    use std::process::Command;
    let m = per_image_model(8);
    let exe = env!("CARGO_BIN_EXE_densefeat");
    let o = m.dir.path().join("out");
    let ran = Command::new(exe)
        .args(["map", "--features", "rgb", "--bins", "32", "--voxel-size", "0.05", "--scale", "1"])
        .args(["--depth-range", "auto", "--consistency-views", "0"])
        .arg("--sequence")
        .arg(m.dir.path())
        .arg("--out")
        .arg(&o)
        .output()
        .unwrap();
    assert!(ran.status.success(), "{}", String::from_utf8_lossy(&ran.stderr));
    let ply = std::fs::read(o.join("mesh.ply")).unwrap();
    let head = String::from_utf8_lossy(&ply[..ply.len().min(400)]).to_string();
    let faces: usize = head
        .lines()
        .find_map(|l| l.strip_prefix("element face "))
        .map(|v| v.trim().parse().unwrap())
        .unwrap();
    assert!(faces > 100, "{head}");
    // The keyframe depth, against the rendering of frame 0: the per-frame cameras are right.
    let seq = open_with(m.dir.path(), &OpenOptions { scale: Some(1.0), ..OpenOptions::default() }).unwrap();
    let cfg = densefeat::mapping::keyframe::KeyframeConfig {
        bins: 64,
        ..densefeat::mapping::keyframe::KeyframeConfig::new(0, 0.5, 8.0)
    };
    let r = densefeat::mapping::keyframe::reconstruct(&seq, &cfg, |_, _, _| {}).unwrap();
    let gt = densefeat::mapping::keyframe::depth_at_level(&m.depth0, r.level);
    let metrics = densefeat::eval::depth_metrics(r.tv.as_ref().unwrap().depth.view(), gt.view()).unwrap();
    eprintln!("per-camera keyframe: {metrics:?}");
    assert!(metrics.delta_1_25 > 0.7, "{metrics:?}");
}
