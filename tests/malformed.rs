//! Malformed inputs: each case builds a small folder in a tempdir and asserts the error variant and
//! that the message names the file (and line where there is one). None may panic.

use std::fs;
use std::path::{Path, PathBuf};

use densefeat::image::{save_depth_png_mm, save_rgb_png};
use densefeat::sequence::{open, open_with, CameraChoice, OpenOptions};
use densefeat::Error;
use ndarray::{Array2, Array3};
use tempfile::TempDir;

const W: usize = 8;
const H: usize = 6;

fn rgb(path: &Path, w: usize, h: usize) {
    fs::create_dir_all(path.parent().unwrap()).unwrap();
    save_rgb_png(path, &Array3::from_elem((h, w, 3), 100.0)).unwrap();
}

fn depth16(path: &Path) {
    fs::create_dir_all(path.parent().unwrap()).unwrap();
    save_depth_png_mm(path, &Array2::from_elem((H, W), 1.5)).unwrap();
}

fn write(dir: &Path, name: &str, text: &str) -> PathBuf {
    let p = dir.join(name);
    fs::create_dir_all(p.parent().unwrap()).unwrap();
    fs::write(&p, text).unwrap();
    p
}

const GT: &str = "# ground truth\n0.05 0 0 0 0 0 0 1\n0.15 0.1 0 0 0 0 0 1\n0.25 0.2 0 0 0 0 0 1\n";

/// A valid two-frame TUM folder; callers then break one file.
fn tum() -> TempDir {
    let d = tempfile::tempdir().unwrap();
    let p = d.path();
    for n in ["0.1", "0.2"] {
        rgb(&p.join(format!("rgb/{n}.png")), W, H);
        depth16(&p.join(format!("depth/{n}.png")));
    }
    write(p, "rgb.txt", "# color\n0.1 rgb/0.1.png\n0.2 rgb/0.2.png\n");
    write(p, "depth.txt", "0.1 depth/0.1.png\n0.2 depth/0.2.png\n");
    write(p, "groundtruth.txt", GT);
    write(p, "cam.txt", &format!("500 500 3.5 2.5\n{W} {H}\n"));
    d
}

fn opts() -> OpenOptions {
    OpenOptions { camera: Some(CameraChoice::Ros), ..Default::default() }
}

/// A valid two-frame DeepVideoMVS folder.
fn dvmvs() -> TempDir {
    let d = tempfile::tempdir().unwrap();
    let p = d.path();
    for n in ["00000", "00001"] {
        rgb(&p.join(format!("images/{n}.png")), W, H);
        depth16(&p.join(format!("depth/{n}.png")));
    }
    let id = "1 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1\n";
    write(p, "poses.txt", &format!("{id}{id}"));
    write(p, "K.txt", "500 0 3.5\n0 500 2.5\n0 0 1\n");
    d
}

/// A valid uncalibrated stereo folder with a scaled-PNG ground truth.
fn stereo() -> TempDir {
    let d = tempfile::tempdir().unwrap();
    let p = d.path();
    rgb(&p.join("imL.png"), W, H);
    rgb(&p.join("imR.png"), W, H);
    image::GrayImage::from_pixel(W as u32, H as u32, image::Luma([40]))
        .save(p.join("groundtruth.png"))
        .unwrap();
    write(p, "info.txt", "4\n59\n");
    d
}

/// Assert the message names `file` (by its file name) and, if given, `file:line`.
#[track_caller]
fn names(e: &Error, file: &str, line: Option<usize>) {
    let msg = e.to_string();
    eprintln!("{msg}");
    assert!(msg.contains(file), "message does not name {file}: {msg}");
    if let Some(l) = line {
        assert!(msg.contains(&format!("{file}:{l}")), "message does not name {file}:{l}: {msg}");
    }
}

#[test]
fn valid_fixtures_open() {
    assert_eq!(open_with(tum().path(), &opts()).unwrap().len(), 2);
    assert_eq!(open(dvmvs().path()).unwrap().len(), 2);
    let st = stereo();
    let s = open(st.path()).unwrap();
    assert_eq!(s.load_disparity(0).unwrap().unwrap()[[0, 0]], 10.0);
}

#[test]
fn tum_missing_referenced_rgb_file() {
    let d = tum();
    fs::remove_file(d.path().join("rgb/0.2.png")).unwrap();
    let e = open_with(d.path(), &opts()).unwrap_err();
    assert!(matches!(e, Error::Parse { line: 3, .. }), "{e:?}");
    names(&e, "rgb.txt", Some(3));
    assert!(e.to_string().contains("rgb/0.2.png"));
}

#[test]
fn tum_unparsable_timestamp() {
    let d = tum();
    write(d.path(), "rgb.txt", "# color\n0.1 rgb/0.1.png\nabc rgb/0.2.png\n");
    let e = open_with(d.path(), &opts()).unwrap_err();
    assert!(matches!(e, Error::Parse { line: 3, .. }), "{e:?}");
    names(&e, "rgb.txt", Some(3));
}

#[test]
fn tum_short_line() {
    let d = tum();
    write(d.path(), "depth.txt", "0.1 depth/0.1.png\n0.2\n");
    let e = open_with(d.path(), &opts()).unwrap_err();
    assert!(matches!(e, Error::Parse { line: 2, .. }), "{e:?}");
    names(&e, "depth.txt", Some(2));
}

#[test]
fn tum_ground_truth_nan_and_inf() {
    for bad in ["nan", "inf"] {
        let d = tum();
        write(d.path(), "groundtruth.txt", &format!("0.0 0 0 0 0 0 0 1\n1.0 {bad} 0 0 0 0 0 1\n"));
        let e = open_with(d.path(), &opts()).unwrap_err();
        assert!(matches!(e, Error::Parse { line: 2, .. }), "{e:?}");
        names(&e, "groundtruth.txt", Some(2));
    }
}

#[test]
fn tum_quaternion_norm_zero_or_two() {
    for q in ["0 0 0 0", "0 0 0 2"] {
        let d = tum();
        write(d.path(), "groundtruth.txt", &format!("# gt\n0.0 0 0 0 0 0 0 1\n1.0 0 0 0 {q}\n"));
        let e = open_with(d.path(), &opts()).unwrap_err();
        assert!(matches!(e, Error::Parse { line: 3, .. }), "{e:?}");
        names(&e, "groundtruth.txt", Some(3));
        assert!(e.to_string().contains("quaternion norm"));
    }
}

#[test]
fn tum_rgb_list_with_only_comments() {
    let d = tum();
    write(d.path(), "rgb.txt", "# color images\n# nothing here\n");
    let e = open_with(d.path(), &opts()).unwrap_err();
    assert!(matches!(e, Error::BadFile { .. }), "{e:?}");
    names(&e, "rgb.txt", None);
}

#[test]
fn tum_timestamps_cannot_be_associated() {
    let d = tum();
    write(d.path(), "depth.txt", "10.1 depth/0.1.png\n10.2 depth/0.2.png\n");
    let e = open_with(d.path(), &opts()).unwrap_err();
    assert!(matches!(e, Error::BadSequence { .. }), "{e:?}");
    names(&e, "rgb.txt", None);
    names(&e, "depth.txt", None);
    assert!(e.to_string().contains("10.100000"), "names the depth time range");
}

#[test]
fn tum_no_frame_inside_ground_truth_range() {
    let d = tum();
    write(d.path(), "groundtruth.txt", "5.0 0 0 0 0 0 0 1\n6.0 0 0 0 0 0 0 1\n");
    let e = open_with(d.path(), &opts()).unwrap_err();
    assert!(matches!(e, Error::BadSequence { .. }), "{e:?}");
    names(&e, "groundtruth.txt", None);
    names(&e, "rgb.txt", None);
}

#[test]
fn tum_8bit_depth_png() {
    let d = tum();
    image::GrayImage::new(W as u32, H as u32).save(d.path().join("depth/0.2.png")).unwrap();
    let e = open_with(d.path(), &opts()).unwrap_err();
    assert!(matches!(e, Error::BadFile { .. }), "{e:?}");
    names(&e, "0.2.png", None);
    assert!(e.to_string().contains("16-bit"));
}

#[test]
fn tum_images_of_different_sizes() {
    let d = tum();
    rgb(&d.path().join("rgb/0.2.png"), W + 2, H);
    let e = open_with(d.path(), &opts()).unwrap_err();
    assert!(matches!(e, Error::BadFile { .. }), "{e:?}");
    names(&e, "0.2.png", None);
}

#[test]
fn tum_camera_file_malformed() {
    let d = tum();
    let cam = write(d.path(), "cam.txt", "500 500 3.5\n");
    let o = OpenOptions { camera: Some(CameraChoice::File(cam)), ..Default::default() };
    let e = open_with(d.path(), &o).unwrap_err();
    assert!(matches!(e, Error::Parse { line: 1, .. }), "{e:?}");
    names(&e, "cam.txt", Some(1));
}

#[test]
fn dvmvs_nan_in_poses() {
    let d = dvmvs();
    write(d.path(), "poses.txt", "1 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1\n1 0 0 NaN 0 1 0 0 0 0 1 0 0 0 0 1\n");
    let e = open(d.path()).unwrap_err();
    assert!(matches!(e, Error::Parse { line: 2, .. }), "{e:?}");
    names(&e, "poses.txt", Some(2));
}

#[test]
fn dvmvs_non_orthonormal_rotation() {
    let d = dvmvs();
    write(d.path(), "poses.txt", "1 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1\n2 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1\n");
    let e = open(d.path()).unwrap_err();
    assert!(matches!(e, Error::Parse { line: 2, .. }), "{e:?}");
    names(&e, "poses.txt", Some(2));
    assert!(e.to_string().contains("orthonormal"));
}

#[test]
fn dvmvs_short_pose_line() {
    let d = dvmvs();
    write(d.path(), "poses.txt", "1 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1\n1 0 0 0 0 1 0 0 0 0 1 0 0 0 0\n");
    let e = open(d.path()).unwrap_err();
    assert!(matches!(e, Error::Parse { line: 2, .. }), "{e:?}");
    names(&e, "poses.txt", Some(2));
}

#[test]
fn dvmvs_pose_count_mismatch() {
    let d = dvmvs();
    write(d.path(), "poses.txt", "1 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1\n");
    let e = open(d.path()).unwrap_err();
    assert!(matches!(e, Error::BadSequence { .. }), "{e:?}");
    names(&e, "poses.txt", None);
    names(&e, "images", None);
    assert!(e.to_string().contains("1 poses") && e.to_string().contains("2 images"));
}

#[test]
fn dvmvs_k_malformed() {
    let d = dvmvs();
    write(d.path(), "K.txt", "500 0 3.5\n0 500 x\n0 0 1\n");
    let e = open(d.path()).unwrap_err();
    assert!(matches!(e, Error::Parse { line: 2, .. }), "{e:?}");
    names(&e, "K.txt", Some(2));
    write(d.path(), "K.txt", "500 0 3.5\n0 500 2.5\n0 1 1\n");
    let e = open(d.path()).unwrap_err();
    assert!(matches!(e, Error::Parse { line: 3, .. }), "{e:?}");
    names(&e, "K.txt", Some(3));
}

#[test]
fn dvmvs_truncated_png() {
    let d = dvmvs();
    let img = d.path().join("images/00001.png");
    let bytes = fs::read(&img).unwrap();
    // Header intact, pixel data cut: opens (headers are fine), fails on load.
    fs::write(&img, &bytes[..bytes.len() - 20]).unwrap();
    let seq = open(d.path()).unwrap();
    let e = seq.load_frame(1).unwrap_err();
    assert!(matches!(e, Error::BadFile { .. }), "{e:?}");
    names(&e, "00001.png", None);
    // Cut inside the header: reported on open.
    fs::write(&img, &bytes[..12]).unwrap();
    let e = open(d.path()).unwrap_err();
    assert!(matches!(e, Error::BadFile { .. }), "{e:?}");
    names(&e, "00001.png", None);
}

#[test]
fn dvmvs_depth_count_mismatch() {
    let d = dvmvs();
    fs::remove_file(d.path().join("depth/00001.png")).unwrap();
    let e = open(d.path()).unwrap_err();
    assert!(matches!(e, Error::BadSequence { .. }), "{e:?}");
    names(&e, "depth", None);
    names(&e, "images", None);
}

#[test]
fn folder_of_no_known_format() {
    let d = tempfile::tempdir().unwrap();
    write(d.path(), "notes.txt", "hello\n");
    let e = open(d.path()).unwrap_err();
    assert!(matches!(e, Error::BadSequence { .. }), "{e:?}");
    let msg = e.to_string();
    assert!(msg.contains(&d.path().display().to_string()));
    for looked_for in ["rgb.txt", "poses.txt", "imL.png"] {
        assert!(msg.contains(looked_for), "{msg}");
    }
    let missing = d.path().join("nope");
    let e = open(&missing).unwrap_err();
    assert!(matches!(e, Error::BadSequence { .. }) && e.to_string().contains("does not exist"), "{e:?}");
}

#[test]
fn stereo_scaled_png_without_info_txt() {
    let d = stereo();
    fs::remove_file(d.path().join("info.txt")).unwrap();
    let e = open(d.path()).unwrap_err();
    assert!(matches!(e, Error::BadSequence { .. }), "{e:?}");
    names(&e, "info.txt", None);
    names(&e, "groundtruth.png", None);
}

#[test]
fn stereo_unparsable_info_scale() {
    let d = stereo();
    write(d.path(), "info.txt", "four\n59\n");
    let e = open(d.path()).unwrap_err();
    assert!(matches!(e, Error::Parse { line: 1, .. }), "{e:?}");
    names(&e, "info.txt", Some(1));
}

#[test]
fn stereo_bad_pfm() {
    let d = stereo();
    fs::remove_file(d.path().join("groundtruth.png")).unwrap();
    fs::write(d.path().join("disp0GT.pfm"), b"Pf\n8 6\n-1.0\n\x00\x00\x00").unwrap();
    let seq = open(d.path()).unwrap();
    let e = seq.load_frame(0).unwrap_err();
    assert!(matches!(e, Error::BadFile { .. }), "{e:?}");
    names(&e, "disp0GT.pfm", None);
    assert!(e.to_string().contains("truncated"));
}

#[test]
fn stereo_calib_bad_baseline() {
    let d = stereo();
    write(d.path(), "calib.txt", "cam0=[500 0 3.5; 0 500 2.5; 0 0 1]\ndoffs=0\nbaseline=abc\nwidth=8\n");
    let e = open(d.path()).unwrap_err();
    assert!(matches!(e, Error::Parse { line: 3, .. }), "{e:?}");
    names(&e, "calib.txt", Some(3));
}

#[test]
fn stereo_calibrated_reads_metres() {
    let d = stereo();
    write(
        d.path(),
        "calib.txt",
        "cam0=[500 0 3.5; 0 500 2.5; 0 0 1]\ncam1=[500 0 5.5; 0 500 2.5; 0 0 1]\ndoffs=2\nbaseline=100\n",
    );
    let seq = open(d.path()).unwrap();
    let st = seq.stereo.as_ref().unwrap();
    assert!(st.calibrated && st.baseline == 0.1 && st.doffs == 2.0);
    // d = 40 / 4 = 10 px: z = f b / (d + doffs) = 500 * 0.1 / 12.
    let z = seq.load_frame(0).unwrap().depth.unwrap()[[0, 0]];
    assert!((z - 50.0 / 12.0).abs() < 1e-5, "{z}");
}
