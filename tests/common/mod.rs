//! Helpers shared by the integration tests.
#![allow(dead_code)]

use std::path::PathBuf;

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
