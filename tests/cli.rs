//! The `densefeat` binary: errors exit non-zero with `error:` naming the path; `inspect` prints the
//! summary.

mod common;

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
