//! Helpers shared by the integration tests.
#![allow(dead_code)]

pub mod dtam_cases;
pub mod record3d;
pub mod scannet;

use std::path::{Path, PathBuf};

/// `../shared/data/<name>` relative to the crate, or `None` (after printing `SKIPPED`) when it is
/// missing. With `DENSEFEAT_REQUIRE_DATA=1` a missing folder panics instead.
pub fn data_dir(name: &str) -> Option<PathBuf> {
    let p = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared/data").join(name);
    if p.is_dir() {
        return Some(p);
    }
    if std::env::var("DENSEFEAT_REQUIRE_DATA").is_ok_and(|v| v == "1") {
        panic!("{} not found and DENSEFEAT_REQUIRE_DATA=1", p.display());
    }
    eprintln!("SKIPPED: {} not found", p.display());
    None
}

/// A smooth grey-level `pattern(x, y)` of normalised image coordinates rendered `[H, W, 3]` on
/// camera `k`'s grid twice: through the ideal pinhole, and as the distorted camera `(k, d)` records
/// it (pixel `u` sees the ray whose distorted coordinates are `k⁻¹ u`). Returns `(pinhole, raw)`:
/// undistorting `raw` should give `pinhole`.
pub fn pinhole_and_distorted(
    k: &densefeat::geometry::PinholeCamera,
    d: &densefeat::geometry::RadTan,
    pattern: impl Fn(f64, f64) -> f64,
) -> (ndarray::Array3<f32>, ndarray::Array3<f32>) {
    let shape = (k.height, k.width, 3);
    let pinhole = ndarray::Array3::from_shape_fn(shape, |(v, u, _)| {
        let r = k.ray(u as f64, v as f64);
        pattern(r.x, r.y) as f32
    });
    let raw = ndarray::Array3::from_shape_fn(shape, |(v, u, _)| {
        let r = k.ray(u as f64, v as f64);
        let (x, y) = d.undistort(r.x, r.y).unwrap();
        pattern(x, y) as f32
    });
    (pinhole, raw)
}

/// Values in [-1, 1) from a seeded LCG (all randomness of the kernel tests comes from a seed).
pub fn lcg(seed: u64) -> impl FnMut() -> f32 {
    let mut s = seed ^ 0x9E37_79B9_7F4A_7C15;
    move || {
        s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        ((s >> 40) as f32 / (1u64 << 23) as f32) - 1.0
    }
}

/// The bit patterns of an array's values, for bit-for-bit comparisons.
pub fn bits<D: ndarray::Dimension>(a: &ndarray::Array<f32, D>) -> Vec<u32> {
    a.iter().map(|v| v.to_bits()).collect()
}

/// A rayon pool of `n` threads (the determinism tests run 1, 2, 3 and 8).
pub fn thread_pool(n: usize) -> rayon::ThreadPool {
    rayon::ThreadPoolBuilder::new().num_threads(n).build().unwrap()
}

/// Runs the `densefeat` binary with `args` (no program name): `Ok(())` when it exits 0, else
/// `Err` with what it printed on stderr.
pub fn run_densefeat(args: &[&str]) -> Result<(), String> {
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_densefeat")).args(args).output().unwrap();
    if out.status.success() {
        Ok(())
    } else {
        Err(String::from_utf8_lossy(&out.stderr).into_owned())
    }
}

/// Every file under `root`, by relative path.
pub fn files(root: &Path) -> std::collections::BTreeMap<String, Vec<u8>> {
    let mut out = std::collections::BTreeMap::new();
    let mut stack = vec![root.to_path_buf()];
    while let Some(dir) = stack.pop() {
        for entry in std::fs::read_dir(&dir).unwrap() {
            let path = entry.unwrap().path();
            if path.is_dir() {
                stack.push(path);
            } else {
                let rel = path.strip_prefix(root).unwrap().to_string_lossy().into_owned();
                out.insert(rel, std::fs::read(&path).unwrap());
            }
        }
    }
    out
}
