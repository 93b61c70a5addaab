//! Record3D "EXR + JPG" exports (SPEC.md §4a), written by hand from a rendered scene
//! (`tests/common/record3d.rs`): camera, sizes and frame count; poses equal to the renderer's after
//! the OpenGL axis conversion; a warp check that the read depth and poses agree with the images
//! (and that the wrong axes or no motion do not); upsampled EXR depth; malformed inputs.

use densefeat::eval::photometric_warp_check;
use densefeat::geometry::Pose;
use densefeat::image::load_depth_exr;
use densefeat::sequence::{inspect::Summary, open, Format};
use nalgebra::{Isometry3, Quaternion, Translation3, UnitQuaternion};
use serde_json::Value;

use crate::common::record3d::{self as fx, Record3dFixture};

/// Camera and pose round trip: numbers are written in shortest round-trip form by serde_json; the
/// quaternion conversions cost a few ulp.
const POSE_TOLERANCE: f64 = 1e-12;

/// Relative error of rounding to half precision (10 stored mantissa bits, round to nearest).
const HALF_RELATIVE: f32 = 1.0 / 2048.0;

fn fixture(frames: usize) -> (tempfile::TempDir, Record3dFixture) {
    let d = tempfile::tempdir().unwrap();
    let f = fx::write(d.path(), 160, 120, frames, 2);
    (d, f)
}

#[track_caller]
fn assert_error<T>(result: densefeat::error::Result<T>, parts: &[&str]) {
    let e = match result {
        Ok(_) => panic!("expected an error containing {parts:?}"),
        Err(e) => e.to_string(),
    };
    for p in parts {
        assert!(e.contains(p), "error {e:?} lacks {p:?}");
    }
}

#[test]
fn record3d_reads_camera_sizes_and_poses_in_our_axes() {
    let (d, f) = fixture(6);
    let seq = open(d.path()).unwrap();
    assert_eq!(seq.format, Format::Record3d);
    assert!(seq.metric, "ARKit poses are metric: no --scale needed");
    assert_eq!(seq.len(), 6);
    let (k, want) = (seq.camera, f.camera);
    assert_eq!((k.width, k.height), (160, 120));
    for (x, y, name) in
        [(k.fx, want.fx, "fx"), (k.fy, want.fy, "fy"), (k.cx, want.cx, "cx"), (k.cy, want.cy, "cy")]
    {
        assert!((x - y).abs() <= POSE_TOLERANCE * y.abs().max(1.0), "{name}: read {x}, rendered {y}");
    }
    for (i, (info, (_, _, pose))) in seq.frames.iter().zip(&f.frames).enumerate() {
        let dt = (info.pose.translation.vector - pose.translation.vector).norm();
        let dr = info.pose.rotation.angle_to(&pose.rotation);
        assert!(
            dt <= POSE_TOLERANCE && dr <= POSE_TOLERANCE,
            "frame {i}: translation {dt:e} m, rotation {dr:e} rad"
        );
        assert_eq!(info.name, i.to_string());
        assert_eq!(info.timestamp, Some(i as f64 / 30.0));
    }
    // Depth: 80x60 half floats, upsampled so that colour pixels 2j and 2j + 1 read depth pixel j,
    // which holds the rendered depth at colour pixel 2j.
    for i in [0, 5] {
        let got = seq.load_frame(i).unwrap().depth.unwrap();
        assert_eq!(got.dim(), (120, 160));
        let want = &f.frames[i].1;
        for ((y, x), &z) in got.indexed_iter() {
            let src = want[[2 * (y / 2), 2 * (x / 2)]];
            assert!((z - src).abs() <= HALF_RELATIVE * src, "frame {i} ({x}, {y}): {z} vs {src}");
        }
    }
}

/// The GL pose read as if it were already in our axes: what a reader that forgot the conversion
/// would produce.
fn unconverted(q_t: &Value) -> Pose {
    let n: Vec<f64> = q_t.as_array().unwrap().iter().map(|v| v.as_f64().unwrap()).collect();
    let q = UnitQuaternion::from_quaternion(Quaternion::new(n[3], n[0], n[1], n[2]));
    Isometry3::from_parts(Translation3::new(n[4], n[5], n[6]), q)
}

#[test]
fn record3d_warp_check_beats_no_motion_and_unconverted_axes() {
    let (d, _) = fixture(6);
    let seq = open(d.path()).unwrap();
    let meta: Value =
        serde_json::from_str(&std::fs::read_to_string(d.path().join("metadata.json")).unwrap()).unwrap();
    let (a, b) = (0, 4);
    let (fa, fb) = (seq.load_frame(a).unwrap(), seq.load_frame(b).unwrap());
    let right = photometric_warp_check(&fa, &fb).unwrap();
    let gl = |i: usize| unconverted(&meta["poses"][i]);
    let (mut wa, mut wb) = (fa.clone(), fb.clone());
    (wa.pose, wb.pose) = (gl(a), gl(b));
    let wrong = photometric_warp_check(&wa, &wb).unwrap();
    eprintln!(
        "record3d warp {b} -> {a}: {:.2} grey levels (in view {:.2}), no motion {:.2}, unconverted axes {:.2} (in view {:.2})",
        right.warped_error, right.in_view, right.identity_error, wrong.warped_error, wrong.in_view
    );
    assert!(right.in_view > 0.5, "{right:?}");
    assert!(right.warped_error < 0.4 * right.identity_error, "{right:?}");
    assert!(right.warped_error < 0.4 * wrong.warped_error, "right {right:?}, wrong {wrong:?}");
}

#[test]
fn record3d_skips_frames_without_colour_and_inspect_notes_it() {
    let (d, _) = fixture(5);
    std::fs::remove_file(d.path().join("rgb/2.jpg")).unwrap();
    let seq = open(d.path()).unwrap();
    let names: Vec<&str> = seq.frames.iter().map(|f| f.name.as_str()).collect();
    assert_eq!(names, ["0", "1", "3", "4"]);
    let text = Summary::new(&seq).unwrap().to_string();
    eprintln!("{text}");
    for part in [
        "format       Record3D (EXR + JPG export)",
        "frames       4 (160x120)",
        "colour       JPEG x4",
        "scale        metric",
        "1 of the 5 frames in metadata.json have no colour image",
        "skipped: 2",
        "depth: EXR 80x60 in metres, upsampled to 160x120",
        "consistency  pose/depth warp check",
    ] {
        assert!(text.contains(part), "inspect output lacks {part:?}");
    }
    assert!(!text.contains("WARNING"), "{text}");
}

#[test]
fn record3d_rgbd_folder_reads_as_rgb_and_depth() {
    let (d, f) = fixture(3);
    let rgbd = d.path().join("rgbd");
    std::fs::create_dir(&rgbd).unwrap();
    for i in 0..3 {
        std::fs::rename(d.path().join(format!("rgb/{i}.jpg")), rgbd.join(format!("{i}.jpg"))).unwrap();
        std::fs::rename(d.path().join(format!("depth/{i}.exr")), rgbd.join(format!("{i}.exr"))).unwrap();
    }
    std::fs::remove_dir(d.path().join("rgb")).unwrap();
    std::fs::remove_dir(d.path().join("depth")).unwrap();
    let seq = open(d.path()).unwrap();
    assert_eq!((seq.format, seq.len()), (Format::Record3d, 3));
    assert!(seq.frames[2].depth.as_ref().unwrap().path().ends_with("rgbd/2.exr"));
    assert!(seq.frames[1].pose.rotation.angle_to(&f.frames[1].2.rotation) <= POSE_TOLERANCE);
}

#[test]
fn exr_depth_reads_any_single_channel_half_or_float() {
    let d = tempfile::tempdir().unwrap();
    let depth = ndarray::Array2::from_shape_fn((6, 8), |(y, x)| 0.5 + 0.25 * (x + 8 * y) as f32);
    let mut odd = depth.clone();
    (odd[[0, 0]], odd[[0, 1]], odd[[0, 2]]) = (f32::NAN, -1.0, f32::INFINITY);
    for (name, half) in [("R", true), ("Y", false), ("Z", true), ("depth", false), ("whatever", false)] {
        let p = d.path().join(format!("{name}.exr"));
        fx::write_exr(&p, &odd, name, half);
        let got = load_depth_exr(&p, 8, 6).unwrap();
        assert_eq!(&got.as_slice().unwrap()[..3], &[0.0, 0.0, 0.0], "{name}: NaN, < 0 and inf are no depth");
        for (g, w) in got.iter().zip(&depth).skip(3) {
            assert!((g - w).abs() <= HALF_RELATIVE * w, "{name}: {g} vs {w}");
        }
    }
    // Larger than the colour image it belongs to: refused from the header, naming the file.
    let p = d.path().join("R.exr");
    assert_error(load_depth_exr(&p, 4, 6), &["R.exr", "EXR layer is 8x6", "at most 4x6"]);
    // Several channels: the first of R, Y, Z, depth; none of them is an error naming the channels.
    use exr::prelude::{
        AnyChannel, AnyChannels, Encoding, FlatSamples, Layer, LayerAttributes, WritableImage,
    };
    let two = |a: &str, b: &str| {
        let ch = |n: &str, v: f32| AnyChannel::new(n, FlatSamples::F32(vec![v; 48]));
        let layer = Layer::new(
            (8, 6),
            LayerAttributes::default(),
            Encoding::UNCOMPRESSED,
            AnyChannels::sort(vec![ch(a, 1.5), ch(b, 2.5)].into()),
        );
        let p = d.path().join(format!("{a}{b}.exr"));
        exr::prelude::Image::from_layer(layer).write().to_file(&p).unwrap();
        p
    };
    assert_eq!(load_depth_exr(&two("G", "Z"), 8, 6).unwrap()[[3, 3]], 2.5);
    assert_eq!(load_depth_exr(&two("R", "Z"), 8, 6).unwrap()[[3, 3]], 1.5);
    assert_error(load_depth_exr(&two("A", "B"), 8, 6), &["AB.exr", "channels [A, B]", "R/Y/Z/depth"]);
    std::fs::write(d.path().join("bad.exr"), b"not an exr file").unwrap();
    assert_error(load_depth_exr(&d.path().join("bad.exr"), 8, 6), &["bad.exr", "cannot read EXR header"]);
}

#[test]
fn record3d_malformed_inputs_name_the_file() {
    let fresh = || {
        let d = tempfile::tempdir().unwrap();
        fx::write(d.path(), 32, 24, 2, 2);
        d
    };
    type Edit = Box<dyn Fn(&mut Value)>;
    let cases: Vec<(Edit, Vec<&str>)> = vec![
        (Box::new(|v| drop(v.as_object_mut().unwrap().remove("K"))), vec!["metadata.json", "no \"K\" key"]),
        (Box::new(|v| drop(v.as_object_mut().unwrap().remove("h"))), vec!["metadata.json", "no \"h\" key"]),
        (
            Box::new(|v| drop(v.as_object_mut().unwrap().remove("poses"))),
            vec!["metadata.json", "no \"poses\" array"],
        ),
        (
            Box::new(|v| drop(v["K"].as_array_mut().unwrap().pop())),
            vec!["metadata.json", "K has 8 numbers, expected 9"],
        ),
        (
            Box::new(|v| {
                let k: Vec<f64> = v["K"].as_array().unwrap().iter().map(|x| x.as_f64().unwrap()).collect();
                v["K"] = serde_json::json!([k[0], 0.0, k[6], 0.0, k[4], k[7], 0.0, 0.0, 1.0]);
            }),
            vec!["metadata.json", "expected column-major", "looks row-major"],
        ),
        (
            Box::new(|v| v["poses"][1][4] = Value::Null),
            vec!["metadata.json", "poses[1]", "null is not a finite number"],
        ),
        (Box::new(|v| v["poses"][0][3] = 2.0.into()), vec!["metadata.json", "poses[0]", "quaternion norm"]),
        (
            Box::new(|v| drop(v["poses"][0].as_array_mut().unwrap().pop())),
            vec!["poses[0]", "has 6 numbers, expected 7"],
        ),
        (Box::new(|v| v["w"] = (-3).into()), vec!["metadata.json", "w is -3, expected a positive integer"]),
        (Box::new(|v| v["dw"] = 20.into()), vec!["metadata.json", "dw x dh = 20x12", "same aspect ratio"]),
        (Box::new(|v| v["fps"] = "fast".into()), vec!["metadata.json", "fps is \"fast\""]),
    ];
    for (f, parts) in cases {
        let d = fresh();
        fx::edit_metadata(d.path(), f);
        assert_error(open(d.path()), &parts);
    }
    // NaN is not JSON: the parser's error names the file and line.
    let d = fresh();
    let p = d.path().join("metadata.json");
    let text = std::fs::read_to_string(&p).unwrap();
    let text = text.replacen("\"poses\": [\n    [\n      ", "\"poses\": [\n    [\n      NaN, ", 1);
    assert!(text.contains("NaN"), "{text}");
    std::fs::write(&p, text).unwrap();
    assert_error(open(d.path()), &["metadata.json:", "not valid JSON"]);
    // An EXR whose size is not dw x dh names the EXR.
    let d = fresh();
    fx::write_exr(&d.path().join("depth/1.exr"), &ndarray::Array2::from_elem((10, 10), 1.0), "R", true);
    assert_error(open(d.path()), &["1.exr", "depth map is 10x10", "dw x dh = 16x12"]);
    // A missing depth map for a frame with colour names both files.
    let d = fresh();
    std::fs::remove_file(d.path().join("depth/0.exr")).unwrap();
    assert_error(open(d.path()), &["0.jpg", "no depth map", "0.exr"]);
    // No frame has a colour image.
    let d = fresh();
    for i in 0..2 {
        std::fs::remove_file(d.path().join(format!("rgb/{i}.jpg"))).unwrap();
    }
    assert_error(open(d.path()), &["none of the 2 frames in metadata.json has a colour image"]);
}
