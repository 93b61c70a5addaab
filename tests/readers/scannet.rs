//! ScanNet SensReader exports (SPEC.md §4a), written by hand from a rendered scene
//! (`tests/common/scannet.rs`): the colour camera, frames in numeric order, lost frames skipped,
//! depth from a depth camera of other intrinsics registered to the colour camera (and nearer the
//! truth than a plain upsampling), unequal extrinsics leaving the depth out, malformed calibration.

use densefeat::sequence::{open, upsample_nearest, Format};

use crate::common::scannet::{self as fx, ScanNetFixture};

fn fixture(frames: usize) -> (tempfile::TempDir, ScanNetFixture) {
    let d = tempfile::tempdir().unwrap();
    let f = fx::write(d.path(), 160, 120, frames);
    (d, f)
}

#[test]
fn scannet_reads_the_colour_camera_in_frame_order_and_skips_lost_frames() {
    let (d, f) = fixture(12);
    std::fs::write(
        d.path().join("pose/2.txt"),
        "-inf -inf -inf -inf\n-inf -inf -inf -inf\n-inf -inf -inf -inf\n-inf -inf -inf -inf\n",
    )
    .unwrap();
    let seq = open(d.path()).unwrap();
    assert_eq!(seq.format, Format::ScanNet);
    assert!(seq.metric);
    let k = seq.camera;
    assert_eq!((k.width, k.height), (160, 120));
    for (a, b) in [(k.fx, f.colour.fx), (k.fy, f.colour.fy), (k.cx, f.colour.cx), (k.cy, f.colour.cy)] {
        assert!((a - b).abs() <= 1e-12 * b.abs().max(1.0), "{a} vs {b}");
    }
    let names: Vec<&str> = seq.frames.iter().map(|i| i.name.as_str()).collect();
    assert_eq!(names, ["0", "1", "3", "4", "5", "6", "7", "8", "9", "10", "11"]);
    for info in &seq.frames {
        let want = &f.frames[info.name.parse::<usize>().unwrap()].2;
        assert!((info.pose.translation.vector - want.translation.vector).norm() <= 1e-12);
        assert!(info.pose.rotation.angle_to(&want.rotation) <= 1e-7);
    }
    assert!(
        seq.notes.iter().any(|n| n.contains("1 frame(s) skipped") && n.contains(": 2")),
        "{:?}",
        seq.notes
    );
}

/// Of the pixels where both maps hold depth, the fraction within 2 % of each other; and the
/// fraction of the truth's pixels that `got` covers.
fn agreement(got: &ndarray::Array2<f32>, truth: &ndarray::Array2<f32>) -> (f64, f64) {
    let (mut ok, mut both, mut n) = (0usize, 0usize, 0usize);
    for (&g, &t) in got.iter().zip(truth) {
        if t > 0.0 {
            n += 1;
            if g > 0.0 {
                both += 1;
                ok += usize::from((g - t).abs() <= 0.02 * t);
            }
        }
    }
    (ok as f64 / both as f64, both as f64 / n as f64)
}

#[test]
fn scannet_depth_is_registered_to_the_colour_camera_by_its_intrinsics() {
    let (d, f) = fixture(3);
    let seq = open(d.path()).unwrap();
    for i in 0..3 {
        let frame = seq.load_frame(i).unwrap();
        let got = frame.depth.unwrap();
        assert_eq!(got.dim(), (120, 160));
        let truth = &f.frames[i].1;
        // The depth camera sees a little less than the colour camera (longer focal lengths, moved
        // centre): the colour pixels outside it hold no depth.
        let (registered, coverage) = agreement(&got, truth);
        // What a reader that took the depth camera for a scaled copy of the colour camera would give.
        let raw =
            densefeat::image::load_depth_png(&d.path().join(format!("depth/{i}.png")), 1e-3, None).unwrap();
        let (naive, _) = agreement(&upsample_nearest(&raw, 160, 120), truth);
        eprintln!(
            "frame {i}: within 2 %: registered {registered:.3} (coverage {coverage:.3}), plain upsampling {naive:.3}"
        );
        assert!(registered >= 0.95 && coverage >= 0.85, "frame {i}: {registered}, coverage {coverage}");
        assert!(registered >= naive + 0.05, "frame {i}: registered {registered}, naive {naive}");
    }
}

#[test]
fn scannet_unequal_extrinsics_leave_the_depth_out_with_a_warning() {
    let (d, _) = fixture(2);
    std::fs::write(d.path().join("intrinsic/extrinsic_depth.txt"), "1 0 0 0.05\n0 1 0 0\n0 0 1 0\n0 0 0 1\n")
        .unwrap();
    let seq = open(d.path()).unwrap();
    assert!(seq.frames.iter().all(|f| f.depth.is_none()));
    assert!(
        seq.notes.iter().any(|n| n.starts_with("warning: ") && n.contains("not registered")),
        "{:?}",
        seq.notes
    );
}

#[test]
fn scannet_bad_calibration_or_a_missing_depth_map_names_the_file() {
    let (d, f) = fixture(2);
    std::fs::remove_file(d.path().join("intrinsic/intrinsic_depth.txt")).unwrap();
    let e = open(d.path()).expect_err("refused").to_string();
    assert!(e.contains("intrinsic_depth.txt") && e.contains("depth camera is unknown"), "{e}");
    fx::intrinsic(&d.path().join("intrinsic/intrinsic_depth.txt"), &f.depth);
    std::fs::remove_file(d.path().join("depth/1.png")).unwrap();
    let e = open(d.path()).expect_err("refused").to_string();
    assert!(e.contains("1.jpg") && e.contains("1.png") && e.contains("no depth map"), "{e}");
    std::fs::write(d.path().join("intrinsic/intrinsic_depth.txt"), "1 0 0\n0 1 0\n").unwrap();
    std::fs::write(d.path().join("intrinsic/intrinsic_color.txt"), "500 0 80 0\n0 500 60 0\n0 0 1 0\n")
        .unwrap();
    let e = open(d.path()).expect_err("refused").to_string();
    assert!(e.contains("intrinsic_color.txt") && e.contains("4 lines"), "{e}");
    std::fs::write(
        d.path().join("intrinsic/intrinsic_color.txt"),
        "500 0 80 0\n0 x 60 0\n0 0 1 0\n0 0 0 1\n",
    )
    .unwrap();
    let e = open(d.path()).expect_err("refused").to_string();
    assert!(e.contains("intrinsic_color.txt") && e.contains("\"x\""), "{e}");
}
