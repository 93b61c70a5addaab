//! The `densefeat` binary: errors exit non-zero with `error:` naming the path; `inspect` prints the
//! summary; a Record3D export maps to a mesh without `--scale` (issue 34).

mod common;
#[path = "common/record3d.rs"]
mod record3d_fixture;

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
    let o = d.path().join("map");
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
        .arg(&seq)
        .arg("--out")
        .arg(&o)
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&run.stdout);
    assert!(run.status.success(), "{stdout}\n{}", String::from_utf8_lossy(&run.stderr));
    eprintln!("{stdout}");
    let mesh = densefeat::fusion::ply::read_mesh_ply(&o.join("mesh.ply")).unwrap();
    assert!(mesh.triangles.len() > 100, "{} triangles", mesh.triangles.len());
    // Metric without --scale: the mesh lies where the rendered surfaces are, 1.7-5.0 m in front of
    // frame 0 (a wrong scale or axis convention puts it elsewhere or behind the camera).
    let t_cw = fixture.frames[0].2.inverse();
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
