//! Diagnostic (SPEC.md §11.8): render a classic synthetic scene with a chosen camera response, to
//! see which photometric effect limits RGB matching.
//!
//! `cargo run -p densefeat-benches --release --example synth_photometric -- SEED OUT GAIN BIAS VIGNETTING NOISE`
//! (the default response is `0.12 5 0.35 1`; `0 0 0 0` is `PhotometricConfig::none()`).

use densefeat::error::{Error, Result};
use densefeat::synth::{write_scene, PhotometricConfig, Scene, SceneConfig};

fn main() -> Result<()> {
    let a: Vec<String> = std::env::args().collect();
    let usage = || Error::invalid_argument("arguments", "SEED OUT GAIN BIAS VIGNETTING NOISE");
    if a.len() != 7 {
        return Err(usage());
    }
    let f = |i: usize| a[i].parse::<f64>().map_err(|_| usage());
    let photometric = PhotometricConfig {
        gain_amplitude: f(3)?,
        bias_amplitude: f(4)?,
        vignetting: f(5)?,
        noise_sigma: f(6)?,
    };
    let seed = a[1].parse().map_err(|_| usage())?;
    let cfg = SceneConfig { seed, photometric, ..SceneConfig::default() };
    let scene = Scene::generate(&cfg)?;
    write_scene(&scene, std::path::Path::new(&a[2]), |_, _| {})
}
