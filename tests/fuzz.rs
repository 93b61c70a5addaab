//! Stable-Rust mutation fuzzer (issue 13, SPEC.md §14.4). Each target starts from a valid file,
//! applies seeded random mutations (bit flips, truncation, byte insertion, huge numbers, NaN/inf
//! text, duplicated or dropped lines) and feeds the result through the reader. Every case must
//! return (no panic), within a time limit, allocate at most [`CASE_CAP`] bytes at once, and an error
//! must name the file. `DENSEFEAT_FUZZ_CASES=N` sets the cases per target (default
//! [`DEFAULT_CASES`]); `DENSEFEAT_FUZZ_SEED` changes the seed. Inputs that once failed live in
//! `tests/fuzz/<target>/` and are replayed by `fuzz_regressions_replay`.

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

use densefeat::error::Result;

/// Cases per target in `cargo test`.
const DEFAULT_CASES: usize = 1500;
/// Largest live heap a case may reach on its thread, bytes.
const CASE_CAP: usize = 256 << 20;
/// Allocations above this fail outright (the process aborts with the case printed).
const HARD_CAP: usize = 2 << 30;
/// Longest a case may take.
const CASE_TIME: Duration = Duration::from_secs(2);

thread_local! {
    static LIVE: Cell<usize> = const { Cell::new(0) };
    static PEAK: Cell<usize> = const { Cell::new(0) };
}

struct Counting;

fn track(add: usize, sub: usize) {
    let _ = LIVE.try_with(|l| {
        let v = l.get().saturating_add(add).saturating_sub(sub);
        l.set(v);
        let _ = PEAK.try_with(|p| p.set(p.get().max(v)));
    });
}

static CASE: AtomicU64 = AtomicU64::new(0);

fn over_cap(size: usize) {
    use std::io::Write;
    let _ = writeln!(
        std::io::stderr(),
        "fuzz: allocation of {size} bytes over the hard cap in case {}",
        CASE.load(Ordering::SeqCst)
    );
}

// SAFETY: forwards to the system allocator; the bookkeeping is thread-local Cells without
// destructors and never allocates.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, l: Layout) -> *mut u8 {
        if l.size() > HARD_CAP {
            over_cap(l.size());
            return std::ptr::null_mut();
        }
        let p = unsafe { System.alloc(l) };
        if !p.is_null() {
            track(l.size(), 0);
        }
        p
    }
    unsafe fn dealloc(&self, p: *mut u8, l: Layout) {
        unsafe { System.dealloc(p, l) };
        track(0, l.size());
    }
    unsafe fn realloc(&self, p: *mut u8, l: Layout, new: usize) -> *mut u8 {
        if new > HARD_CAP {
            over_cap(new);
            return std::ptr::null_mut();
        }
        let q = unsafe { System.realloc(p, l, new) };
        if !q.is_null() {
            track(new, l.size());
        }
        q
    }
}

#[global_allocator]
static ALLOC: Counting = Counting;

/// SplitMix64.
struct Rng(u64);
impl Rng {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    fn below(&mut self, n: usize) -> usize {
        (self.next() % n.max(1) as u64) as usize
    }
}

const NASTY: [&str; 12] = [
    "nan",
    "NaN",
    "inf",
    "-inf",
    "1e308",
    "-1e308",
    "1e400",
    "18446744073709551616",
    "-0",
    "0",
    "4294967295",
    "99999999999999999999",
];

/// One to four mutations of `seed`.
fn mutate(seed: &[u8], rng: &mut Rng, text: bool) -> Vec<u8> {
    let mut b = seed.to_vec();
    for _ in 0..1 + rng.below(4) {
        let n = b.len();
        match rng.below(if text { 9 } else { 6 }) {
            0 if n > 0 => {
                let i = rng.below(n);
                b[i] ^= 1 << rng.below(8);
            }
            1 => b.truncate(rng.below(n + 1)),
            2 => {
                let at = rng.below(n + 1);
                let k = 1 + rng.below(8);
                let bytes: Vec<u8> = (0..k).map(|_| rng.next() as u8).collect();
                b.splice(at..at, bytes);
            }
            3 if n > 0 => {
                let i = rng.below(n);
                b[i] = [0, 0xff, 0x7f, 0x80][rng.below(4)];
            }
            4 if n >= 4 => {
                // A 32-bit field set to a huge value (lengths, sizes in binary headers).
                let i = rng.below(n - 3);
                let v: u32 = [u32::MAX, 0x7fff_ffff, 0x1000_0000, 0][rng.below(4)];
                b[i..i + 4].copy_from_slice(&v.to_be_bytes());
            }
            5 if n > 8 => {
                let (i, j) = (rng.below(n), rng.below(n));
                let (i, j) = (i.min(j), i.max(j));
                let chunk = b[i..j].to_vec();
                b.splice(j..j, chunk);
            }
            6 => {
                // Replace one number-like token with a nasty one.
                let s = String::from_utf8_lossy(&b).into_owned();
                let tokens: Vec<(usize, usize)> = token_spans(&s);
                if let Some(&(i, j)) = tokens.get(rng.below(tokens.len())) {
                    let mut t = s.clone();
                    t.replace_range(i..j, NASTY[rng.below(NASTY.len())]);
                    b = t.into_bytes();
                }
            }
            7 | 8 => {
                let s = String::from_utf8_lossy(&b).into_owned();
                let mut lines: Vec<&str> = s.lines().collect();
                if !lines.is_empty() {
                    let i = rng.below(lines.len());
                    if rng.below(2) == 0 {
                        lines.insert(i, lines[i]);
                    } else {
                        lines.remove(i);
                    }
                }
                b = (lines.join("\n") + "\n").into_bytes();
            }
            _ => {}
        }
    }
    b
}

fn token_spans(s: &str) -> Vec<(usize, usize)> {
    let mut out = Vec::new();
    let mut start = None;
    for (i, c) in s.char_indices() {
        let num = c.is_ascii_digit() || matches!(c, '.' | '-' | 'e' | '+');
        match (num, start) {
            (true, None) => start = Some(i),
            (false, Some(st)) => {
                out.push((st, i));
                start = None;
            }
            _ => {}
        }
    }
    if let Some(st) = start {
        out.push((st, s.len()));
    }
    out
}

/// A fuzz target: the file to mutate, its valid content, and the reader.
struct Target {
    name: &'static str,
    file: PathBuf,
    seed: Vec<u8>,
    text: bool,
    read: Box<dyn Fn() -> Result<()>>,
}

/// Run one input through a target: `Ok(rejected)` (whether the reader returned an error) or
/// `Err(why)` on a contract violation.
fn run_case(t: &Target, input: &[u8]) -> std::result::Result<bool, String> {
    std::fs::write(&t.file, input).map_err(|e| e.to_string())?;
    LIVE.with(|l| l.set(0));
    PEAK.with(|p| p.set(0));
    let start = Instant::now();
    let r = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| (t.read)()));
    let took = start.elapsed();
    let peak = PEAK.with(Cell::get);
    let r = r.map_err(|_| "panicked".to_string())?;
    if took > CASE_TIME {
        return Err(format!("took {took:?}"));
    }
    if peak > CASE_CAP {
        return Err(format!("allocated {peak} bytes at once"));
    }
    if let Err(e) = &r {
        let msg = e.to_string();
        let fname = t.file.file_name().unwrap().to_string_lossy();
        let root = t.file.parent().unwrap().to_string_lossy();
        if !(msg.contains(&*fname) || msg.contains(&*root)) {
            return Err(format!("error names no file: {msg}"));
        }
    }
    Ok(r.is_err())
}

fn cases() -> usize {
    std::env::var("DENSEFEAT_FUZZ_CASES").ok().and_then(|v| v.parse().ok()).unwrap_or(DEFAULT_CASES)
}

fn fuzz(t: &Target) {
    let base: u64 = std::env::var("DENSEFEAT_FUZZ_SEED").ok().and_then(|v| v.parse().ok()).unwrap_or(13);
    let rejected = run_case(t, &t.seed).unwrap_or_else(|e| panic!("{}: the valid seed fails: {e}", t.name));
    assert!(!rejected, "{}: the valid seed is rejected: {:?}", t.name, (t.read)().err());
    let n = cases();
    let start = Instant::now();
    let mut errors = 0usize;
    for i in 0..n {
        CASE.store(i as u64, Ordering::SeqCst);
        let mut rng = Rng(base ^ (i as u64).wrapping_mul(0x2545_F491_4F6C_DD1D) ^ hash(t.name));
        let input = mutate(&t.seed, &mut rng, t.text);
        let rejected = run_case(t, &input).unwrap_or_else(|why| {
            let keep = std::env::temp_dir().join(format!("densefeat-fuzz-{}-{i}.bin", t.name));
            let _ = std::fs::write(&keep, &input);
            panic!("{} case {i} (seed {base}): {why}; input kept at {}", t.name, keep.display());
        });
        // Count errors to show the mutations reach the parsers' checks.
        if rejected {
            errors += 1;
            if errors == 1 && std::env::var_os("DENSEFEAT_FUZZ_KEEP").is_some() {
                keep_in_corpus(t, &input, &format!("seed{base}-case{i}-rejected.bin"));
            }
        }
    }
    eprintln!(
        "fuzz {}: {n} cases, {errors} rejected with an error, {:.1} s",
        t.name,
        start.elapsed().as_secs_f64()
    );
    std::fs::write(&t.file, &t.seed).unwrap();
}

/// `DENSEFEAT_FUZZ_KEEP=1`: the first input a target rejects goes into its committed corpus
/// (`tests/fuzz/<target>/`), so that `fuzz_regressions_replay` has one for every target.
fn keep_in_corpus(t: &Target, input: &[u8], file: &str) {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fuzz").join(t.name);
    std::fs::create_dir_all(&dir).unwrap();
    std::fs::write(dir.join(file), input).unwrap();
}

fn hash(s: &str) -> u64 {
    s.bytes().fold(0xcbf2_9ce4_8422_2325u64, |h, b| (h ^ u64::from(b)).wrapping_mul(0x100_0000_01b3))
}

#[path = "fuzz/setup.rs"]
mod setup;
#[path = "fuzz/setup_formats.rs"]
mod setup_formats;
use setup::targets;

macro_rules! fuzz_test {
    ($name:ident) => {
        #[test]
        fn $name() {
            let dir = tempfile::tempdir().unwrap();
            let mut t = targets(dir.path(), &|n| n == stringify!($name));
            assert_eq!(t.len(), 1, "target {} is not built exactly once", stringify!($name));
            fuzz(&t.remove(0));
        }
    };
}

fuzz_test!(png_colour);
fuzz_test!(png_depth);
fuzz_test!(jpeg);
fuzz_test!(dvmvs_poses);
fuzz_test!(dvmvs_k);
fuzz_test!(tum_groundtruth);
fuzz_test!(tum_rgb_list);
fuzz_test!(camera_file);
fuzz_test!(stereo_calib);
fuzz_test!(pfm);
fuzz_test!(safetensors);
// Issue 34: every sequence reader and the PLY reader.
fuzz_test!(colmap_cameras_txt);
fuzz_test!(colmap_images_txt);
fuzz_test!(colmap_points3d_txt);
fuzz_test!(colmap_cameras_bin);
fuzz_test!(colmap_images_bin);
fuzz_test!(colmap_points3d_bin);
fuzz_test!(transforms_json);
fuzz_test!(sevenscenes_pose);
fuzz_test!(record3d_metadata);
fuzz_test!(exr_depth);
fuzz_test!(scannet_intrinsic);
fuzz_test!(scannet_pose);
fuzz_test!(ply_mesh);

/// Every committed input (`tests/fuzz/<target>/*`: at least one per target, rejected mutations and
/// any input that once failed) goes through its target and must keep the contract.
#[test]
fn fuzz_regressions_replay() {
    let dir = tempfile::tempdir().unwrap();
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fuzz");
    let (mut n, mut empty) = (0, Vec::new());
    for t in targets(dir.path(), &|_| true) {
        let mut files: Vec<PathBuf> = std::fs::read_dir(root.join(t.name))
            .map(|rd| rd.flatten().map(|e| e.path()).collect())
            .unwrap_or_default();
        files.sort();
        if files.is_empty() {
            empty.push(t.name);
        }
        for f in &files {
            let input = std::fs::read(f).unwrap();
            run_case(&t, &input).unwrap_or_else(|why| panic!("{}: {why}", f.display()));
            n += 1;
        }
    }
    eprintln!("replayed {n} committed inputs");
    assert!(empty.is_empty(), "targets without a committed input in tests/fuzz/<target>/: {empty:?}");
}
