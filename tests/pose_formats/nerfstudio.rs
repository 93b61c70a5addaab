//! nerfstudio / instant-ngp `transforms.json`.

use std::path::Path;

use densefeat::geometry::Camera;
use densefeat::sequence::depth_range::depth_range_of;
use densefeat::sequence::inspect::Summary;
use densefeat::sequence::nerfstudio_write::NerfstudioWriter;
use densefeat::sequence::{open, Format};
use serde_json::Value;

use crate::render::{
    assert_error, assert_same_geometry, assert_warp_matches_renderer, render, reprojection_difference,
    Rendered,
};

/// Depth PNGs store millimetres: a round trip is off by at most half a unit, plus f32 rounding.
const DEPTH_TOLERANCE_M: f32 = 0.5e-3 + 1e-6;

fn write(dir: &Path, r: &Rendered, per_frame: bool, depth: bool) {
    let mut w = NerfstudioWriter::create(dir, Camera::pinhole(r.camera), per_frame).unwrap();
    for (rgb, d, pose) in &r.frames {
        w.push(rgb, depth.then_some(d), pose).unwrap();
    }
    w.finish().unwrap();
}

#[test]
fn transforms_json_round_trip_with_depth_is_metric() {
    let r = render(96, 72, 4, None);
    let d = tempfile::tempdir().unwrap();
    write(d.path(), &r, false, true);
    let seq = open(d.path()).unwrap();
    assert_eq!(seq.format, Format::Nerfstudio);
    assert!(seq.metric);
    assert_same_geometry(&seq, &r);
    for (a, b) in [(0, 1), (0, 3), (3, 2)] {
        let e = reprojection_difference(&seq, &r, a, b);
        assert!(e < crate::render::REPROJECTION_TOLERANCE_PX, "{a} -> {b}: {e:e} px");
    }
    // The depth read back is the rendered depth within the PNG quantisation.
    for (i, (_, want, _)) in r.frames.iter().enumerate() {
        let got = seq.load_frame(i).unwrap().depth.unwrap();
        let worst = got.iter().zip(want).map(|(g, w)| (g - w).abs()).fold(0.0f32, f32::max);
        assert!(worst <= DEPTH_TOLERANCE_M, "frame {i}: depth off by {worst} m");
    }
    assert_warp_matches_renderer(&seq, &r, 0, 1, None);
    // --depth-range auto on ground-truth depth: the rule applied to the frame's valid depths.
    let z: Vec<f64> = seq.load_frame(2).unwrap().depth.unwrap().iter().map(|v| f64::from(*v)).collect();
    assert_eq!(seq.estimate_depth_range(2).unwrap(), depth_range_of(z));
    let text = Summary::new(&seq).unwrap().to_string();
    eprintln!("{text}");
    for part in [
        "format       nerfstudio / instant-ngp transforms.json",
        "scale        metric",
        "consistency  pose/depth",
    ] {
        assert!(text.contains(part), "inspect output lacks {part:?}");
    }
}

#[test]
fn transforms_json_per_frame_intrinsics_without_depth_warns_of_scale() {
    let r = render(96, 72, 3, None);
    let d = tempfile::tempdir().unwrap();
    write(d.path(), &r, true, false);
    let seq = open(d.path()).unwrap();
    assert!(!seq.metric);
    assert_same_geometry(&seq, &r);
    assert!(reprojection_difference(&seq, &r, 0, 2) < crate::render::REPROJECTION_TOLERANCE_PX);
    let text = Summary::new(&seq).unwrap().to_string();
    assert!(text.contains("transforms.json without depth maps: the pose scale is unknown"), "{text}");
}

fn edit_json(dir: &Path, f: impl FnOnce(&mut Value)) {
    let p = dir.join("transforms.json");
    let mut v: Value = serde_json::from_str(&std::fs::read_to_string(&p).unwrap()).unwrap();
    f(&mut v);
    std::fs::write(&p, serde_json::to_string_pretty(&v).unwrap()).unwrap();
}

#[test]
fn transforms_json_camera_angle_and_paths_without_extension() {
    let r = render(96, 72, 2, None);
    let d = tempfile::tempdir().unwrap();
    write(d.path(), &r, false, false);
    edit_json(d.path(), |v| {
        let o = v.as_object_mut().unwrap();
        for k in ["fl_x", "fl_y", "cx", "cy", "w", "h"] {
            o.remove(k);
        }
        o.insert("camera_angle_x".into(), (2.0 * (48.0 / r.camera.fx).atan()).into());
        for f in o["frames"].as_array_mut().unwrap() {
            let p = f["file_path"].as_str().unwrap().trim_end_matches(".png").to_string();
            f["file_path"] = p.into();
        }
    });
    let seq = open(d.path()).unwrap();
    let k = seq.camera;
    assert!((k.fx - r.camera.fx).abs() < 1e-9 && (k.fy - r.camera.fy).abs() < 1e-9, "{k:?}");
    // Without cx, cy the principal point is the image centre, w / 2 - 0.5 in our convention.
    assert_eq!((k.cx, k.cy), (47.5, 35.5));
    assert_eq!(seq.len(), 2);
}

#[test]
fn transforms_json_malformed_inputs_name_file_and_entry() {
    let r = render(48, 36, 2, None);
    let fresh = || {
        let d = tempfile::tempdir().unwrap();
        write(d.path(), &r, false, true);
        d
    };
    let d = fresh();
    std::fs::write(d.path().join("transforms.json"), "{\n  \"frames\": [\n    {\"file_path\": }\n  ]\n}\n")
        .unwrap();
    assert_error(open(d.path()), &["transforms.json:3:", "not valid JSON"]);
    type Edit = Box<dyn Fn(&mut Value)>;
    let cases: Vec<(Edit, Vec<&str>)> = vec![
        (
            Box::new(|v| drop(v["frames"][1].as_object_mut().unwrap().remove("transform_matrix"))),
            vec!["transforms.json", "frames[1]", "transform_matrix"],
        ),
        (
            Box::new(|v| drop(v["frames"][0]["transform_matrix"].as_array_mut().unwrap().pop())),
            vec!["frames[0]", "4 rows of 4 numbers"],
        ),
        (
            Box::new(|v| v["frames"][0]["transform_matrix"][0][0] = "a".into()),
            vec!["frames[0]", "is not a number"],
        ),
        (
            Box::new(|v| v["frames"][0]["transform_matrix"][0][0] = 3.0.into()),
            vec!["frames[0]", "not orthonormal"],
        ),
        (
            Box::new(|v| v["frames"][1]["file_path"] = "images/nope.png".into()),
            vec!["frames[1]", "nope.png", "does not exist"],
        ),
        (
            Box::new(|v| v["frames"][1]["depth_file_path"] = "depth/nope.png".into()),
            vec!["frames[1]", "depth/nope.png"],
        ),
        (
            Box::new(|v| drop(v["frames"][1].as_object_mut().unwrap().remove("depth_file_path"))),
            vec!["1 of 2 frames have depth_file_path"],
        ),
        (Box::new(|v| v["camera_model"] = "OPENCV_FISHEYE".into()), vec!["camera_model \"OPENCV_FISHEYE\""]),
        (Box::new(|v| v["fl_x"] = (-3.0).into()), vec!["frames[0]", "fx"]),
        (Box::new(|v| v["frames"] = Value::Array(vec![])), vec!["\"frames\" is empty"]),
    ];
    for (f, parts) in cases {
        let d = fresh();
        edit_json(d.path(), f);
        assert_error(open(d.path()), &parts);
    }
}

#[test]
fn transforms_json_frames_with_their_own_intrinsics_get_their_own_camera() {
    // A frame's `fl_x` overrides the top level's: that frame is read with a camera of its own
    // (SPEC.md §4a per-frame cameras); the others share the top-level camera.
    let r = render(48, 36, 3, None);
    let d = tempfile::tempdir().unwrap();
    write(d.path(), &r, false, true);
    edit_json(d.path(), |v| v["frames"][1]["fl_x"] = 99.0.into());
    let seq = open(d.path()).unwrap();
    assert_eq!(seq.raw_cameras.len(), 2);
    assert_eq!(seq.frame_camera(1).fx, 99.0);
    assert_eq!(seq.frame_camera(0), r.camera);
    assert_eq!(seq.frame_camera(2), r.camera);
    assert_eq!(seq.load_frame(1).unwrap().camera.fx, 99.0);
    assert!(seq.notes.iter().any(|n| n.contains("2 cameras (per-frame intrinsics)")), "{:?}", seq.notes);
}

#[test]
fn transforms_json_reconstructs_as_the_deepvideomvs_layout_does() {
    // The same rendered frames through two readers: the keyframe reconstruction (RGB features, TV,
    // range from the ground truth by `--depth-range auto`'s rule) must agree, so the reader changes
    // nothing the mapper sees beyond rounding in the last bits of the poses.
    use densefeat::mapping::keyframe::{reconstruct, KeyframeConfig};
    use densefeat::sequence::DvmvsWriter;
    let r = render(96, 72, 7, None);
    let (a, b) = (tempfile::tempdir().unwrap(), tempfile::tempdir().unwrap());
    write(a.path(), &r, false, true);
    let mut w = DvmvsWriter::create(b.path(), r.camera).unwrap();
    for (rgb, d, pose) in &r.frames {
        w.push(rgb, d, pose).unwrap();
    }
    w.finish().unwrap();
    let (ns, dv) = (open(a.path()).unwrap(), open(b.path()).unwrap());
    assert_eq!(dv.format, Format::DeepVideoMvs);
    let range = ns.estimate_depth_range(3).unwrap().unwrap();
    assert_eq!(Some(range), dv.estimate_depth_range(3).unwrap());
    let mut cfg = KeyframeConfig::new(3, range.0, range.1);
    (cfg.past, cfg.future, cfg.bins) = (3, 3, 32);
    let run = |seq| {
        let res = reconstruct(seq, &cfg, |_, _, _| {}).unwrap();
        let m = res.metrics(res.tv.as_ref().unwrap()).unwrap();
        eprintln!(
            "{}: range {:.3}..{:.3} m, TV rms {:.4} m, abs rel {:.4}, δ<1.25 {:.4}",
            seq.format, range.0, range.1, m.rms, m.abs_rel, m.delta_1_25
        );
        m
    };
    let (m_ns, m_dv) = (run(&ns), run(&dv));
    for (x, y, name) in [
        (m_ns.rms, m_dv.rms, "rms"),
        (m_ns.abs_rel, m_dv.abs_rel, "abs rel"),
        (m_ns.delta_1_25, m_dv.delta_1_25, "δ<1.25"),
    ] {
        assert!((x - y).abs() <= 1e-3 * y.abs().max(1e-3), "{name}: transforms.json {x} vs DeepVideoMVS {y}");
    }
}

#[test]
fn transforms_json_smaller_depth_is_upsampled_with_centres_aligned() {
    // Phone exports store depth below the colour resolution. Half-size depth maps (depth pixel j
    // = rendered pixel 2j) upsample so that colour pixels 2j and 2j + 1 read depth pixel j: the
    // even pixels get the rendered depth back within the PNG quantisation.
    use densefeat::image::save_depth_png_mm;
    use ndarray::Array2;
    let r = render(96, 72, 2, None);
    let d = tempfile::tempdir().unwrap();
    write(d.path(), &r, false, true);
    for (i, (_, depth, _)) in r.frames.iter().enumerate() {
        let half = Array2::from_shape_fn((36, 48), |(y, x)| depth[[2 * y, 2 * x]]);
        save_depth_png_mm(&d.path().join(format!("depth/frame_{:05}.png", i + 1)), &half).unwrap();
    }
    let seq = open(d.path()).unwrap();
    assert!(seq.metric);
    let got = seq.load_frame(1).unwrap().depth.unwrap();
    assert_eq!(got.dim(), (72, 96));
    let want = &r.frames[1].1;
    for y in 0..72 {
        for x in 0..96 {
            let src = want[[2 * (y / 2), 2 * (x / 2)]];
            assert!((got[[y, x]] - src).abs() <= DEPTH_TOLERANCE_M, "({x}, {y}): {} vs {src}", got[[y, x]]);
        }
    }
    // A depth map of another aspect ratio is refused, naming the frame and the file.
    save_depth_png_mm(&d.path().join("depth/frame_00002.png"), &Array2::from_elem((30, 48), 1.0)).unwrap();
    assert_error(open(d.path()), &["frames[1]", "frame_00002.png is 48x30", "same aspect ratio"]);
}
