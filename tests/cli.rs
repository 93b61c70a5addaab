//! The `densefeat` binary: errors exit non-zero with `error:` naming the path; `inspect` prints the
//! summary; a Record3D export maps to a mesh without `--scale`; outputs that cannot be replaced are
//! refused up front (issue 34).

use crate::common;
use crate::common::record3d as record3d_fixture;

use std::process::Command;

#[test]
fn inspect_bad_folder_fails_naming_it() {
    let d = tempfile::tempdir().unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_densefeat")).arg("inspect").arg(d.path()).output().unwrap();
    assert!(!out.status.success());
    assert_eq!(out.status.code(), Some(1));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.starts_with("error: "), "{err}");
    assert!(err.contains(&d.path().display().to_string()), "{err}");
}

#[test]
fn inspect_hololens_prints_summary() {
    let Some(dir) = common::data_dir("hololens_000") else { return };
    let out = Command::new(env!("CARGO_BIN_EXE_densefeat")).arg("inspect").arg(&dir).output().unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert!(text.contains("DeepVideoMVS"), "{text}");
    assert!(text.contains("373 (540x360)"), "{text}");
    assert!(text.contains("consistency"), "{text}");
}

#[test]
fn inspect_rejects_bad_max_gap() {
    let d = tempfile::tempdir().unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_densefeat"))
        .args(["inspect", "--max-gap", "-1"])
        .arg(d.path())
        .output()
        .unwrap();
    assert!(!out.status.success());
}

#[test]
fn bench_tv_prints_iteration_and_solve_times() {
    let (mapping, raw) = (densefeat::dtam::MAPPING_DEFAULTS, densefeat::dtam::DtamParams::default());
    for (schedule, p) in [("mapping", mapping), ("raw", raw)] {
        let (iterations, steps) = (p.iterations, p.steps_per_search);
        let out = Command::new(env!("CARGO_BIN_EXE_densefeat"))
            .args(["bench", "tv", "--size", "40x30", "--bins", "8", "--threads", "2", "--runs", "5"])
            .args(["--schedule", schedule])
            .output()
            .unwrap();
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
        let text = String::from_utf8_lossy(&out.stdout);
        assert!(
            text.contains("one iteration") && text.contains("a-search") && text.contains("full solve"),
            "{text}"
        );
        let said =
            format!("{schedule} schedule ({iterations} iterations scheduled, {steps} primal-dual steps each");
        assert!(text.contains(&said), "{text}");
    }
    let out = Command::new(env!("CARGO_BIN_EXE_densefeat"))
        .args(["bench", "tv", "--size", "40x30", "--schedule", "fast"])
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("--schedule"));
    // `--tgv-beta` times TGV (SPEC.md §10.4) and refuses a β that is not positive.
    let bench = |beta: &str| {
        Command::new(env!("CARGO_BIN_EXE_densefeat"))
            .args(["bench", "tv", "--size", "40x30", "--bins", "8", "--runs", "5", "--tgv-beta", beta])
            .output()
            .unwrap()
    };
    let out = bench("4");
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(text.contains("dtam with TGV (β 4 at 640 px)") && text.contains("full solve"), "{text}");
    let out = bench("0");
    assert!(!out.status.success() && String::from_utf8_lossy(&out.stderr).contains("--tgv-beta"));
}

fn densefeat() -> Command {
    Command::new(env!("CARGO_BIN_EXE_densefeat"))
}

#[test]
fn record3d_inspect_and_map_make_a_mesh_without_scale() {
    let d = tempfile::tempdir().unwrap();
    let seq = d.path().join("r3d");
    let fixture = record3d_fixture::write(&seq, 160, 120, 10, 2);
    let out = densefeat().arg("inspect").arg(&seq).output().unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    eprintln!("{text}");
    for part in
        ["format       Record3D (EXR + JPG export)", "frames       10 (160x120)", "scale        metric"]
    {
        assert!(text.contains(part), "{part:?} missing: {text}");
    }
    assert!(!text.contains("WARNING"), "{text}");
    map_lies_in_front_of_frame_0(&seq, &d.path().join("map"), &fixture.frames[0].2);
}

/// `densefeat map` (RGB, a small schedule) on `seq` into `o`, then: a mesh of over 100 triangles
/// whose vertices lie where the rendered surfaces are, 1.7-5.0 m in front of frame 0 (`t_wc0`), from
/// two keyframes or more. Metric without `--scale`: a wrong scale or axis convention puts the mesh
/// elsewhere or behind the camera.
fn map_lies_in_front_of_frame_0(
    seq: &std::path::Path,
    o: &std::path::Path,
    t_wc0: &densefeat::geometry::Pose,
) {
    let run = densefeat()
        .args(["map", "--features", "rgb", "--bins", "16", "--level", "1", "--window", "3,3"])
        .args([
            "--iterations",
            "30",
            "--max-iterations",
            "30",
            "--kf-baseline",
            "0.05",
            "--voxel-size",
            "0.1",
        ])
        .arg("--sequence")
        .arg(seq)
        .arg("--out")
        .arg(o)
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&run.stdout);
    assert!(run.status.success(), "{stdout}\n{}", String::from_utf8_lossy(&run.stderr));
    eprintln!("{stdout}");
    let mesh = densefeat::fusion::ply::read_mesh_ply(&o.join("mesh.ply")).unwrap();
    assert!(mesh.triangles.len() > 100, "{} triangles", mesh.triangles.len());
    let t_cw = t_wc0.inverse();
    let mut z: Vec<f64> = mesh
        .vertices
        .iter()
        .map(|v| (t_cw * nalgebra::Point3::new(f64::from(v[0]), f64::from(v[1]), f64::from(v[2]))).z)
        .collect();
    z.sort_by(f64::total_cmp);
    let (lo, mid, hi) = (z[z.len() / 10], z[z.len() / 2], z[9 * z.len() / 10]);
    eprintln!("mesh depth in frame 0: 10% {lo:.2} m, median {mid:.2} m, 90% {hi:.2} m");
    assert!(lo > 1.0 && hi < 6.0 && (1.7..=5.0).contains(&mid), "{lo} {mid} {hi}");
    let doc: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(o.join("map.json")).unwrap()).unwrap();
    assert!(doc["keyframes"].as_array().unwrap().len() >= 2, "{doc}");
}

/// A ScanNet SensReader export (SPEC.md §4a): `inspect` names it, metric, without warnings; `map`
/// makes a mesh where the rendered surfaces are.
#[test]
fn scannet_inspect_and_map_make_a_mesh_without_scale() {
    let d = tempfile::tempdir().unwrap();
    let seq = d.path().join("scene0000_00");
    let fixture = crate::common::scannet::write(&seq, 160, 120, 10);
    let out = densefeat().arg("inspect").arg(&seq).output().unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    eprintln!("{text}");
    for part in [
        "format       ScanNet (SensReader export)",
        "frames       10 (160x120)",
        "scale        metric",
        "registered",
    ] {
        assert!(text.contains(part), "{part:?} missing: {text}");
    }
    assert!(!text.contains("WARNING"), "{text}");
    map_lies_in_front_of_frame_0(&seq, &d.path().join("map"), &fixture.frames[0].2);
}

/// Names in a folder (hidden ones too), sorted.
fn names(dir: &std::path::Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir)
        .map(|rd| rd.flatten().map(|e| e.file_name().to_string_lossy().into_owned()).collect())
        .unwrap_or_default();
    v.sort();
    v
}

#[cfg(unix)]
fn chmod(p: &std::path::Path, mode: u32) {
    use std::os::unix::fs::PermissionsExt;
    std::fs::set_permissions(p, std::fs::Permissions::from_mode(mode)).unwrap();
}

/// Issue 34: `reconstruct --out DIR` into a folder made read-only (0555, parent writable) used to
/// exit 0 and leave the old contents beside it under `.DIR.densefeat-stage-PID`. Now it is refused
/// before any work, naming the folder, and nothing changes. The refusal reads the permission bits
/// (no write bit at all), so it holds when the tests run as root, whom mode 0555 does not stop.
#[cfg(unix)]
#[test]
fn regression_34_read_only_output_folder_is_refused_and_nothing_is_left() {
    let d = tempfile::tempdir().unwrap();
    let out = d.path().join("o");
    std::fs::create_dir_all(out.join("keyframes")).unwrap();
    std::fs::write(out.join("old.txt"), "old result").unwrap();
    let fixture = concat!(env!("CARGO_MANIFEST_DIR"), "/fixtures/synthetic/room_s1");
    let reconstruct = || {
        densefeat()
            .args(["reconstruct", "--sequence", fixture, "--keyframe", "5", "--window", "2,2"])
            .args(["--iterations", "20", "--bins", "16", "--out"])
            .arg(&out)
            .output()
            .unwrap()
    };
    for (folder, shown) in
        [(out.clone(), out.display().to_string()), (out.join("keyframes"), "keyframes".into())]
    {
        chmod(&folder, 0o555);
        let o = reconstruct();
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(1), "{:?}: {err}", o.status);
        assert!(err.contains(&shown) && err.contains("not writable") && err.contains("0555"), "{err}");
        assert_eq!(names(d.path()), ["o"], "nothing beside the folder");
        assert_eq!(names(&out), ["keyframes", "old.txt"], "the folder is unchanged");
        chmod(&folder, 0o755);
    }
    // Writable again: the run replaces the folder, keeps what it does not write, leaves nothing else.
    let o = reconstruct();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(names(d.path()), ["o"]);
    assert_eq!(std::fs::read_to_string(out.join("old.txt")).unwrap(), "old result");
    assert!(out.join("depth_tv.npy").is_file(), "{:?}", names(&out));
}

/// CRC-32 (IEEE) of `bytes`, for a hand-made PNG chunk.
fn crc32(bytes: &[u8]) -> u32 {
    let mut c = 0xffff_ffffu32;
    for &b in bytes {
        c ^= u32::from(b);
        for _ in 0..8 {
            c = if c & 1 != 0 { 0xedb8_8320 ^ (c >> 1) } else { c >> 1 };
        }
    }
    !c
}

/// Issue 34: a decompression-bomb PNG (the header says 60000x60000) given to `features` is refused
/// by the memory guard before decoding; the message names `--max-memory-mb` and the file.
#[test]
fn regression_34_png_bomb_refusal_names_the_file_and_the_memory_flag() {
    let d = tempfile::tempdir().unwrap();
    let png = d.path().join("bomb.png");
    let mut bytes = b"\x89PNG\r\n\x1a\n".to_vec();
    let chunk = |bytes: &mut Vec<u8>, kind: &[u8], data: &[u8]| {
        bytes.extend_from_slice(&(data.len() as u32).to_be_bytes());
        let body = [kind, data].concat();
        bytes.extend_from_slice(&body);
        bytes.extend_from_slice(&crc32(&body).to_be_bytes());
    };
    let mut ihdr = Vec::new();
    ihdr.extend_from_slice(&60000u32.to_be_bytes());
    ihdr.extend_from_slice(&60000u32.to_be_bytes());
    ihdr.extend_from_slice(&[8, 2, 0, 0, 0]); // 8-bit RGB, deflate, adaptive filter, no interlace
    chunk(&mut bytes, b"IHDR", &ihdr);
    // An empty zlib stream: the decoder needs an IDAT to finish reading the header.
    chunk(&mut bytes, b"IDAT", &[0x78, 0x9c, 0x03, 0x00, 0x00, 0x00, 0x00, 0x01]);
    chunk(&mut bytes, b"IEND", &[]);
    std::fs::write(&png, bytes).unwrap();
    let out = d.path().join("f.npy");
    let o = densefeat().arg("features").arg(&png).arg("--out").arg(&out).output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{:?}: {err}", o.status);
    assert!(err.contains("--max-memory-mb") && err.contains(&png.display().to_string()), "{err}");
    assert!(err.contains("60000x60000"), "{err}");
    assert_eq!(names(d.path()), ["bomb.png"], "nothing written");
}
