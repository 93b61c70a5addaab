//! The ground floor's utilities, used by every kernel above (issue 33): aligned, huge-page-advised
//! allocation of activation maps ([`alloc`], SPEC.md §8.9) and the deterministic integer RNG and hashes
//! ([`rng`], SPEC.md §4b).

pub mod alloc;
pub mod rng;
