//! Every subcommand runs with only its required flags (every other flag at its default), as a new
//! user would first try it. The commands run in a scratch project folder whose `../shared` is the
//! real one, so defaults such as `fixtures/textures` or `../shared/data` resolve there and nothing
//! in the repository is overwritten.

use crate::common;

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

/// What a run must show.
#[derive(Clone, Copy, Debug)]
enum Expect {
    /// Exit 0 within the limit.
    Finishes,
    /// A long job with default settings (e.g. `train`'s 2000 steps): must not exit with an error
    /// within this many seconds (it is then stopped); exiting 0 earlier is fine too.
    RunsFor(u64),
}

/// Runs `args` in `cwd`; panics with the command's output when it breaks `expect`.
fn check(cwd: &Path, args: &[&str], expect: Expect) {
    let mut child = Command::new(env!("CARGO_BIN_EXE_densefeat"))
        .args(args)
        .current_dir(cwd)
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .expect("spawn densefeat");
    let limit = match expect {
        Expect::Finishes => Duration::from_secs(900),
        Expect::RunsFor(s) => Duration::from_secs(s),
    };
    let start = Instant::now();
    loop {
        if let Some(status) = child.try_wait().expect("wait") {
            let out = child.wait_with_output().expect("output");
            assert!(
                status.success(),
                "`densefeat {}` failed ({status}):\n{}",
                args.join(" "),
                String::from_utf8_lossy(&out.stderr)
            );
            return;
        }
        if start.elapsed() > limit {
            child.kill().expect("kill");
            let out = child.wait_with_output().expect("output");
            let err = String::from_utf8_lossy(&out.stderr);
            match expect {
                Expect::RunsFor(_) => {
                    assert!(
                        !err.contains("error:"),
                        "`densefeat {}` printed an error:\n{err}",
                        args.join(" ")
                    );
                    return;
                }
                Expect::Finishes => {
                    panic!("`densefeat {}` did not finish in {limit:?}:\n{err}", args.join(" "))
                }
            }
        }
        std::thread::sleep(Duration::from_millis(100));
    }
}

/// A scratch project folder next to a `shared` link to the real `../shared` (when there is one).
fn scratch_project() -> (tempfile::TempDir, PathBuf) {
    let root = tempfile::tempdir().unwrap();
    let proj = root.path().join("proj");
    std::fs::create_dir(&proj).unwrap();
    let shared = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared");
    if shared.is_dir() {
        std::os::unix::fs::symlink(shared.canonicalize().unwrap(), root.path().join("shared")).unwrap();
    }
    (root, proj)
}

#[test]
fn every_subcommand_runs_with_only_its_required_flags() {
    let (_root, proj) = scratch_project();
    let fixture = Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures/synthetic/room_s1");
    let fx = fixture.to_str().unwrap();
    let image = fixture.join("images/00000.png");
    let img = image.to_str().unwrap();
    use Expect::*;
    let mut runs: Vec<(Vec<&str>, Expect)> = vec![
        (vec!["inspect", fx], Finishes),
        (vec!["synth", "--out", "synth"], Finishes),
        (vec!["synth-sheet", "--out", "sheet.png"], Finishes),
        (vec!["features", "--out", "features", img], Finishes),
        (vec!["init-weights", "--out", "init.safetensors"], Finishes),
        (vec!["reconstruct", "--sequence", fx, "--keyframe", "10", "--out", "rec"], Finishes),
        (vec!["eval", "--sequence", fx, "--keyframes", "10:10:10", "--out", "eval"], Finishes),
        (vec!["map", "--sequence", fx, "--out", "map"], Finishes),
        (vec!["demo"], Finishes),
        (
            vec!["costcurve", "--sequence", fx, "--keyframe", "10", "--pixels", "10,10", "--out", "curve"],
            Finishes,
        ),
        (vec!["bench", "forward"], Finishes),
        (vec!["bench", "gemm"], Finishes),
        (vec!["bench", "costvolume"], Finishes),
        (vec!["bench", "tv"], Finishes),
        (vec!["bench", "train"], Finishes),
        // 2000 steps by default: it must start (issue 30: it used to stop at once on --threads 0).
        (vec!["train", "--out", "train"], RunsFor(20)),
        // The normal predictor's training (SPEC.md §13.11): 2000 steps by default, must start.
        (vec!["train-normals", "--out", "train_normals"], RunsFor(20)),
    ];
    // The texture atlas is cut from the training scenes in ../shared/data (its default).
    if common::data_dir("hololens_000").is_some() && common::data_dir("tartanair_hospital").is_some() {
        runs.push((vec!["texture-atlas"], Finishes));
    }
    for (args, expect) in &runs {
        check(&proj, args, *expect);
    }
    // The outputs landed in the scratch folder, not in the repository.
    for made in ["synth", "sheet.png", "features", "init.safetensors", "rec", "eval", "map", "curve"] {
        assert!(proj.join(made).exists(), "{made} was not written");
    }
    // The level defaults: `map` works at level 1 (SPEC.md §16.9), `reconstruct` at level 0.
    let json = |p: &str| -> serde_json::Value {
        serde_json::from_str(&std::fs::read_to_string(proj.join(p)).unwrap()).unwrap()
    };
    assert_eq!(json("map/map.json")["mapping"]["level"], densefeat::mapping::sequence_map::MAP_LEVEL);
    assert_eq!(densefeat::mapping::sequence_map::MAP_LEVEL, 1);
    assert_eq!(json("rec/metrics.json")["level"], 0, "{}", json("rec/metrics.json"));
}
