//! Nothing: this package only holds densefeat's criterion benches (`cargo bench -p
//! densefeat-benches --bench NAME`), kept out of the root package so that `cargo test` does not build
//! criterion.
