//! File output helpers: every file we write appears whole or not at all ([`write_atomic`]), and a
//! command's outputs appear together or not at all ([`Staging`], SPEC.md §14.2).

mod atomic;
mod npy;
pub mod staging;

pub use atomic::{write_atomic, write_atomic_with};
pub use npy::{npy_f32_header, write_npy_f32};
pub use staging::Staging;

use std::sync::atomic::{AtomicUsize, Ordering};

/// Test hook for the kill tests (SPEC.md §14.2): with `DENSEFEAT_TEST_HOOK=POINT` or `POINT:N`, the
/// process prints `densefeat-hook: POINT` on stderr at the `N`-th (default first) time it passes
/// `POINT` and sleeps 120 s there, so that a test can kill it at a known instant. Points:
/// `write` (a temporary file written, not yet renamed), `carry`, `exchange`, `remove-old` (the
/// steps of a folder commit) and `commit-file`. Unset (always, outside tests) it costs one
/// environment lookup.
pub fn hook(point: &str) {
    static PASSES: AtomicUsize = AtomicUsize::new(0);
    let Ok(spec) = std::env::var("DENSEFEAT_TEST_HOOK") else { return };
    let (name, nth) = match spec.split_once(':') {
        Some((n, k)) => (n.to_string(), k.parse::<usize>().unwrap_or(1)),
        None => (spec.clone(), 1),
    };
    if name != point {
        return;
    }
    if PASSES.fetch_add(1, Ordering::SeqCst) + 1 == nth {
        eprintln!("densefeat-hook: {point}");
        std::thread::sleep(std::time::Duration::from_secs(120));
    }
}
