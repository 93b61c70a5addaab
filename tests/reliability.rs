//! Issue 13: every finding of the hostile-input catalogue has a regression test here, plus the
//! all-or-nothing output contract (staging, stale temporaries, SIGKILL at several points) and the
//! memory guard (SPEC.md §14).
//!
//! `DENSEFEAT_RELIABILITY_BIN=/path/to/densefeat` runs the tests against another binary instead of
//! this build's (`CARGO_BIN_EXE_densefeat`), e.g. one built before the fixes, to check that every
//! `regression_13_*` test fails there for the reason of its finding:
//! `DENSEFEAT_RELIABILITY_BIN=/old/target/release/densefeat cargo test --release --test reliability
//! regression_13`. The other tests rely on hooks and flags of this build (`DENSEFEAT_TEST_HOOK`,
//! `--max-memory-mb` on every command) and are only meaningful without the override.
//! docs/reliability/regressions_old_vs_new.md records such a run.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

use densefeat::io::Staging;

/// The binary under test: `DENSEFEAT_RELIABILITY_BIN` when set (and not empty), else this build's.
fn bin() -> Command {
    match std::env::var_os("DENSEFEAT_RELIABILITY_BIN") {
        Some(p) if !p.is_empty() => Command::new(p),
        _ => Command::new(env!("CARGO_BIN_EXE_densefeat")),
    }
}

fn fixture() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("fixtures/synthetic/room_s1")
}

fn run(args: &[&str]) -> Output {
    bin().args(args).output().unwrap()
}

/// Address-space data cap for [`run_capped`] children: far above what a refusal needs, far below
/// what the findings allocate.
const CHILD_DATA_CAP: u64 = 4 << 30;

/// Like [`run`], for commands that could allocate in proportion to an absurd argument when pointed
/// at an older binary: the child's data segment (`RLIMIT_DATA`, which counts heap mappings) is
/// capped at [`CHILD_DATA_CAP`] and it is killed after `deadline`. Returns the output and whether
/// it was killed at the deadline.
fn run_capped(args: &[&str], deadline: Duration) -> (Output, bool) {
    use std::io::Read;
    let mut c = bin();
    c.args(args).stdin(Stdio::null()).stdout(Stdio::null()).stderr(Stdio::piped());
    #[cfg(target_os = "linux")]
    {
        use std::os::unix::process::CommandExt;
        // SAFETY: the closure only calls setrlimit, which is async-signal-safe, between fork and exec.
        unsafe {
            c.pre_exec(|| {
                let cap = libc::rlimit {
                    rlim_cur: CHILD_DATA_CAP as libc::rlim_t,
                    rlim_max: CHILD_DATA_CAP as libc::rlim_t,
                };
                if libc::setrlimit(libc::RLIMIT_DATA, &cap) != 0 {
                    return Err(std::io::Error::last_os_error());
                }
                Ok(())
            });
        }
    }
    let mut child = c.spawn().unwrap();
    let mut err = child.stderr.take().unwrap();
    let reader = std::thread::spawn(move || {
        let mut v = Vec::new();
        let _ = err.read_to_end(&mut v);
        v
    });
    let start = Instant::now();
    let mut killed = false;
    let status = loop {
        if let Some(st) = child.try_wait().unwrap() {
            break st;
        }
        if start.elapsed() > deadline {
            let _ = child.kill();
            killed = true;
            break child.wait().unwrap();
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    let stderr = reader.join().unwrap();
    (Output { status, stdout: Vec::new(), stderr }, killed)
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// Names in a folder (hidden ones too), sorted.
fn names(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir)
        .map(|rd| rd.flatten().map(|e| e.file_name().to_string_lossy().into_owned()).collect())
        .unwrap_or_default();
    v.sort();
    v
}

/// Copy of the fixture sequence (so tests can break it).
fn copy_fixture(to: &Path) {
    for sub in ["", "images", "depth"] {
        std::fs::create_dir_all(to.join(sub)).unwrap();
        for e in std::fs::read_dir(fixture().join(sub)).unwrap().flatten() {
            if e.file_type().unwrap().is_file() {
                std::fs::copy(e.path(), to.join(sub).join(e.file_name())).unwrap();
            }
        }
    }
}

const SMALL: [&str; 6] = ["--window", "2,2", "--iterations", "20", "--keyframe", "5"];

fn reconstruct(seq: &Path, out: &Path, extra: &[&str]) -> Command {
    let mut c = bin();
    c.args(["reconstruct", "--sequence", s(seq), "--out", s(out)]).args(SMALL).args(extra);
    c
}

#[test]
fn regression_13_costcurve_huge_bins_refused_before_allocating() {
    let dir = tempfile::tempdir().unwrap();
    let (out, seq) = (dir.path().join("cost.png"), fixture());
    let args = ["costcurve", "--sequence", s(&seq), "--keyframe", "5", "--pixels", "10,10"]
        .into_iter()
        .chain(["--bins", "100000", "--out", s(&out)])
        .collect::<Vec<_>>();
    let (o, killed) = run_capped(&args, Duration::from_secs(60));
    assert!(!killed, "still running after 60 s: no up-front refusal; {}", stderr(&o));
    assert_eq!(o.status.code(), Some(1), "{:?}: {}", o.status, stderr(&o));
    let e = stderr(&o);
    assert!(e.contains("--max-memory-mb") && e.contains("--bins"), "{e}");
    assert!(names(dir.path()).is_empty(), "{:?}", names(dir.path()));
}

#[test]
fn regression_13_reconstruct_failing_13th_output_writes_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("o");
    // The 13th output, metrics.json, cannot be written: a folder holds its name.
    std::fs::create_dir_all(out.join("metrics.json")).unwrap();
    let o = reconstruct(&fixture(), &out, &[]).output().unwrap();
    assert!(!o.status.success());
    assert!(stderr(&o).contains("metrics.json"), "{}", stderr(&o));
    assert_eq!(names(&out), ["metrics.json"]);
    assert_eq!(names(dir.path()), ["o"], "staging left behind");
}

#[test]
fn regression_13_costcurve_failing_csv_leaves_no_png() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::create_dir(dir.path().join("cost.csv")).unwrap();
    let out = dir.path().join("cost.png");
    let o = run(&["costcurve", "--sequence", s(&fixture()), "--keyframe", "5", "--pixels", "10,10"]
        .into_iter()
        .chain(["--features", "rgb", "--bins", "8", "--frames", "2", "--out", s(&out)])
        .collect::<Vec<_>>());
    assert!(!o.status.success());
    assert!(stderr(&o).contains("cost.csv"), "{}", stderr(&o));
    assert_eq!(names(dir.path()), ["cost.csv"]);
}

#[test]
fn regression_13_features_failing_viz_leaves_no_npy() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("blocker"), b"a file, not a folder").unwrap();
    let img = fixture().join("images/00000.png");
    let (npy, viz) = (dir.path().join("f.npy"), dir.path().join("blocker/v.png"));
    let o = run(&["features", s(&img), "--out", s(&npy), "--viz", s(&viz)]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("blocker"), "{}", stderr(&o));
    assert_eq!(names(dir.path()), ["blocker"]);
}

#[test]
fn regression_13_train_bad_crop_names_the_flag_and_writes_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("run");
    for (crop, needle) in [("20000x20000", "--crop"), ("4000x4000", "--max-memory-mb"), ("0x5", "--crop")] {
        let args = ["train", "--out", s(&out), "--crop", crop, "--steps", "1", "--quiet"];
        let (o, killed) = run_capped(&args, Duration::from_secs(60));
        let (e, left) = (stderr(&o), names(dir.path()));
        // Every problem at once, so a failure shows the whole finding.
        let ok = !killed && o.status.code() == Some(1) && e.contains(needle) && left.is_empty();
        assert!(ok, "{crop}: {:?}, killed at deadline {killed}, left {left:?}, stderr: {e}", o.status);
    }
}

#[test]
fn train_bad_augmentation_ranking_term_or_deep_weight_names_the_flag_and_writes_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("run");
    for (flag, value) in [
        ("--augment-blur", "-1"),
        ("--augment-blur", "17"),
        ("--augment-gamma", "NaN"),
        ("--hinge-weight", "-1"),
        ("--hinge-margin", "inf"),
        ("--deep-weight", "0"),
        ("--deep-weight", "2"),
    ] {
        let bad = format!("{flag}={value}");
        let args = ["train", "--out", s(&out), &bad, "--steps", "1", "--quiet"];
        let (o, killed) = run_capped(&args, Duration::from_secs(60));
        let (e, left) = (stderr(&o), names(dir.path()));
        let ok = !killed && o.status.code() == Some(1) && e.contains(flag) && left.is_empty();
        assert!(
            ok,
            "{flag} {value}: {:?}, killed at deadline {killed}, left {left:?}, stderr: {e}",
            o.status
        );
    }
}

/// `--lambda-sweep` was already checked up front before issue 13 (docs/reliability/
/// regressions_old_vs_new.md); `--lambda-learned` was checked only after the RGB evaluation, with
/// a message naming no flag.
#[test]
fn regression_13_eval_bad_lambda_refused_before_work() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("e");
    for (bad, methods) in [("--lambda-sweep=-1", "rgb-tv"), ("--lambda-learned=-1", "rgb-tv,learned-tv")] {
        let t = Instant::now();
        let o = run(&["eval", "--sequence", s(&fixture()), "--keyframes", "5:1:6", "--methods", methods]
            .into_iter()
            .chain([bad, "--out", s(&out)])
            .collect::<Vec<_>>());
        let (took, e, left) = (t.elapsed(), stderr(&o), names(dir.path()));
        let flag = bad.split('=').next().unwrap();
        let ok = o.status.code() == Some(1)
            && e.contains(flag)
            && left.is_empty()
            && took < Duration::from_secs(10);
        assert!(ok, "{bad}: {:?} after {took:?}, left {left:?}, stderr: {e}", o.status);
    }
}

#[test]
fn regression_13_stale_temporaries_removed_by_next_run() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("o");
    std::fs::create_dir(&out).unwrap();
    // Leftovers of killed runs: pid 999999999 is above any pid_max.
    let dead = 999_999_999u32;
    std::fs::write(out.join(format!(".depth_wta.npy.tmp-{dead}")), b"x").unwrap();
    std::fs::write(out.join(format!(".keyframe.png.densefeat-tmp-{dead}")), b"x").unwrap();
    std::fs::create_dir(dir.path().join(format!(".o.densefeat-stage-{dead}"))).unwrap();
    std::fs::write(out.join("user.txt"), b"keep me").unwrap();
    let o = reconstruct(&fixture(), &out, &["--regularizer", "none"]).output().unwrap();
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(names(&out).iter().all(|n| !n.starts_with('.')), "{:?}", names(&out));
    assert_eq!(names(dir.path()), ["o"]);
    assert_eq!(std::fs::read(out.join("user.txt")).unwrap(), b"keep me");
}

#[test]
fn regression_13_negative_fx_refused_naming_k_txt() {
    let dir = tempfile::tempdir().unwrap();
    let seq = dir.path().join("seq");
    copy_fixture(&seq);
    let k = std::fs::read_to_string(seq.join("K.txt")).unwrap();
    std::fs::write(seq.join("K.txt"), format!("-{k}")).unwrap();
    let o = run(&["inspect", s(&seq)]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("K.txt") && stderr(&o).contains("fx"), "{}", stderr(&o));
}

#[test]
fn regression_13_tiny_frames_refused_up_front_naming_a_file() {
    let dir = tempfile::tempdir().unwrap();
    let seq = dir.path().join("tiny");
    let o = run(&["synth", "--frames", "3", "--size", "1x1", "--quiet", "--out", s(&seq)]);
    assert!(o.status.success(), "{}", stderr(&o));
    let out = dir.path().join("o");
    for cmd in [
        vec!["reconstruct", "--keyframe", "1"],
        vec!["eval", "--keyframes", "1:1:1"],
        vec!["costcurve", "--keyframe", "1", "--pixels", "0,0"],
    ] {
        let o = bin().args(&cmd).args(["--sequence", s(&seq), "--out", s(&out)]).output().unwrap();
        assert!(!o.status.success());
        let e = stderr(&o);
        assert!(e.contains("00000.png") && e.contains("1x1"), "{cmd:?}: {e}");
        assert!(!out.exists(), "{cmd:?}");
    }
}

#[cfg(unix)]
#[test]
fn regression_13_symlink_loop_in_images_is_named() {
    let dir = tempfile::tempdir().unwrap();
    let seq = dir.path().join("seq");
    copy_fixture(&seq);
    let looping = seq.join("images/00005.png");
    std::fs::remove_file(&looping).unwrap();
    std::os::unix::fs::symlink(&looping, &looping).unwrap();
    let o = run(&["inspect", s(&seq)]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("00005.png"), "{}", stderr(&o));
}

#[test]
fn every_command_refuses_over_its_memory_limit() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("o");
    let (seq, img) = (fixture(), fixture().join("images/00000.png"));
    let cases: Vec<Vec<&str>> = vec![
        vec!["reconstruct", "--sequence", s(&seq), "--keyframe", "5", "--out", s(&out)],
        vec!["eval", "--sequence", s(&seq), "--keyframes", "5:1:5", "--out", s(&out)],
        vec!["costcurve", "--sequence", s(&seq), "--keyframe", "5", "--pixels", "1,1", "--out", s(&out)],
        vec!["features", s(&img), "--out", s(&out)],
        vec!["train", "--out", s(&out)],
        vec!["bench", "forward"],
        vec!["bench", "gemm"],
        vec!["bench", "costvolume"],
        vec!["bench", "tv"],
        vec!["bench", "train"],
    ];
    for c in cases {
        let o = bin().args(&c).args(["--max-memory-mb", "1"]).output().unwrap();
        assert_eq!(o.status.code(), Some(1), "{c:?}");
        assert!(stderr(&o).contains("over the limit of 1 MiB"), "{c:?}: {}", stderr(&o));
        assert!(!out.exists(), "{c:?}");
    }
}

#[test]
fn staging_dropped_uncommitted_leaves_folders_as_they_were() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("a/b/out");
    let file = dir.path().join("c/f.txt");
    {
        let mut st = Staging::new();
        std::fs::write(st.dir(&out).unwrap().join("x"), b"1").unwrap();
        std::fs::write(st.file(&file).unwrap(), b"2").unwrap();
    }
    assert!(names(dir.path()).is_empty(), "{:?}", names(dir.path()));
}

#[test]
fn staging_commit_replaces_outputs_and_keeps_other_files() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    std::fs::create_dir_all(out.join("sub")).unwrap();
    std::fs::write(out.join("old.txt"), b"old").unwrap();
    std::fs::write(out.join("sub/keep"), b"k").unwrap();
    std::fs::write(out.join("new.txt"), b"before").unwrap();
    let mut st = Staging::new();
    let d = st.dir(&out).unwrap();
    std::fs::write(d.join("new.txt"), b"after").unwrap();
    std::fs::create_dir(d.join("sub")).unwrap();
    std::fs::write(d.join("sub/added"), b"a").unwrap();
    st.commit().unwrap();
    assert_eq!(names(&out), ["new.txt", "old.txt", "sub"]);
    assert_eq!(names(&out.join("sub")), ["added", "keep"]);
    assert_eq!(std::fs::read(out.join("new.txt")).unwrap(), b"after");
    assert_eq!(names(dir.path()), ["out"]);
}

#[test]
fn memory_guard_names_the_flags() {
    assert!(densefeat::memory::check(1, "x", 1 << 20, "use fewer --bins").is_ok());
    let e = densefeat::memory::check(1, "x", (1 << 20) + 1, "use fewer --bins").unwrap_err().to_string();
    assert!(e.contains("--max-memory-mb") && e.contains("--bins"), "{e}");
    assert_eq!(densefeat::memory::product(&[u64::MAX, 2]), u64::MAX);
    assert_eq!(densefeat::memory::DEFAULT_MAX_MEMORY_MB, 2048);
}

/// File name -> bytes of a folder's files; `metrics.json` reduced to its bin count (it holds
/// timings, which differ between runs).
fn snapshot(dir: &Path) -> BTreeMap<String, Vec<u8>> {
    let mut m = BTreeMap::new();
    for n in names(dir) {
        let bytes = std::fs::read(dir.join(&n)).unwrap_or_default();
        let v = if n == "metrics.json" {
            let j: serde_json::Value = serde_json::from_slice(&bytes).expect("metrics.json is whole JSON");
            j["bins"].to_string().into_bytes()
        } else {
            bytes
        };
        m.insert(n, v);
    }
    m
}

/// Start a reconstruct with 24 bins into `out` (which holds a 16-bin result), kill it with SIGKILL
/// at `hook` (or after `delay`), and check the folder holds the complete old or the complete new
/// result; returns which.
fn kill_and_check(
    seq: &Path,
    out: &Path,
    hook: Option<&str>,
    delay: Duration,
    old: &BTreeMap<String, Vec<u8>>,
    new: &BTreeMap<String, Vec<u8>>,
) -> &'static str {
    let mut c = reconstruct(seq, out, &["--bins", "24"]);
    if let Some(h) = hook {
        c.env("DENSEFEAT_TEST_HOOK", h);
    }
    let mut child = c.stdout(Stdio::null()).stderr(Stdio::piped()).spawn().unwrap();
    if hook.is_some() {
        use std::io::BufRead;
        let err = child.stderr.take().unwrap();
        let mut lines = std::io::BufReader::new(err).lines();
        let seen = lines.any(|l| l.is_ok_and(|l| l.starts_with("densefeat-hook:")));
        assert!(seen, "hook {hook:?} never reached");
    } else {
        std::thread::sleep(delay);
    }
    let _ = child.kill(); // SIGKILL on unix
    let _ = child.wait();
    let now = snapshot(out);
    if &now == old {
        "old"
    } else if &now == new {
        "new"
    } else {
        panic!(
            "after a kill at {hook:?} / {delay:?} the folder is a mix: {:?}",
            now.keys().collect::<Vec<_>>()
        );
    }
}

#[cfg(unix)]
#[test]
fn reconstruct_killed_anywhere_leaves_old_or_new_outputs() {
    let dir = tempfile::tempdir().unwrap();
    let (out, fresh) = (dir.path().join("o"), dir.path().join("fresh"));
    let seq = fixture();
    assert!(reconstruct(&seq, &fresh, &["--bins", "24"]).output().unwrap().status.success());
    let new = snapshot(&fresh);
    let reset = || {
        let _ = std::fs::remove_dir_all(&out);
        assert!(reconstruct(&seq, &out, &["--bins", "16"]).output().unwrap().status.success());
        snapshot(&out)
    };
    let old = reset();
    assert_ne!(old, new);
    let mut seen = Vec::new();
    let hooks = ["write:1", "write:7", "write:13", "carry", "exchange", "remove-old"];
    for h in hooks {
        seen.push((h.to_string(), kill_and_check(&seq, &out, Some(h), Duration::ZERO, &old, &new)));
        // The next run cleans up: no temporary inside or beside the folder, then the new result.
        let o = reconstruct(&seq, &out, &["--bins", "24"]).output().unwrap();
        assert!(o.status.success(), "{}", stderr(&o));
        assert_eq!(snapshot(&out), new, "after {h}");
        assert!(names(dir.path()).iter().all(|n| !n.starts_with('.')), "{h}: {:?}", names(dir.path()));
        reset();
    }
    for ms in [30u64, 150, 400, 700] {
        let d = Duration::from_millis(ms);
        seen.push((format!("{ms} ms"), kill_and_check(&seq, &out, None, d, &old, &new)));
        assert!(reconstruct(&seq, &out, &["--bins", "16"]).output().unwrap().status.success());
        assert!(names(dir.path()).iter().all(|n| !n.starts_with('.')), "{ms} ms: {:?}", names(dir.path()));
        assert_eq!(snapshot(&out), old);
    }
    // Before the swap the old result stays; from the swap on, the new one.
    let by: BTreeMap<_, _> = seen.iter().cloned().collect();
    assert_eq!(by["write:13"], "old");
    assert_eq!(by["exchange"], "old");
    assert_eq!(by["remove-old"], "new");
    eprintln!("kill points: {seen:?}");
}

#[test]
fn an_output_folder_holding_the_working_directory_is_refused_before_work() {
    // Found running `train-normals --out .` (2026-12-03): the first checkpoint swapped the folder
    // out from under the process, and the next one failed on its vanished working directory.
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("run");
    std::fs::create_dir_all(out.join("inner")).unwrap();
    std::fs::write(out.join("keep.txt"), "old").unwrap();
    for (cwd, arg) in [(out.clone(), "."), (out.clone(), s(&out)), (out.join("inner"), s(&out))] {
        let o = bin()
            .current_dir(&cwd)
            .args(["synth", "--seed", "3", "--frames", "2", "--size", "32x24", "--quiet", "--out", arg])
            .output()
            .unwrap();
        assert!(!o.status.success(), "--out {arg} from {}", cwd.display());
        assert!(stderr(&o).contains("working directory"), "{}", stderr(&o));
        assert_eq!(names(&out), ["inner", "keep.txt"], "--out {arg}: the folder was touched");
        assert_eq!(names(dir.path()), ["run"], "staging left behind");
    }
    // From outside, the same folder is fine.
    let o = bin()
        .current_dir(dir.path())
        .args(["synth", "--seed", "3", "--frames", "2", "--size", "32x24", "--quiet", "--out", "run"])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", stderr(&o));
}
