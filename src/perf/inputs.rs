//! Deterministic inputs of the benchmarks (`densefeat bench`, `benches/`): the same bytes on every
//! machine, so timings compare.

use nalgebra::{Translation3, UnitQuaternion};
use ndarray::Array3;

use crate::error::{Error, Result};
use crate::geometry::{InverseDepthBins, PinholeCamera, Pose};
use crate::synth::rng::SplitMix64;

/// A deterministic test pattern `[h, w, 3]` in 0..=255.
pub fn pattern(h: usize, w: usize) -> Array3<f32> {
    Array3::from_shape_fn((h, w, 3), |(y, x, c)| ((x * 7 + y * 13 + c * 61 + (x * y) % 17) % 256) as f32)
}

/// Inputs of [`bench_inputs`].
#[derive(Clone, Debug)]
pub struct BenchInputs {
    /// Reference features `[H, W, C]`.
    pub reference: Array3<f32>,
    /// Live features `[H, W, C]`.
    pub live: Array3<f32>,
    /// The camera of both frames.
    pub camera: PinholeCamera,
    /// The hypotheses.
    pub bins: InverseDepthBins,
    /// `T_nr`.
    pub t_nr: Pose,
}

/// Inputs of the benchmark: random reference and live features in `[0, 1)`, a camera with
/// `f = 0.8 W` and the principal point at the centre, hypotheses over `[0.25, 4]` 1/m, and a live
/// camera 5 cm to the right, 2 cm forward, rotated by about 1° (a typical neighbouring keyframe).
///
/// # Errors
/// [`Error::InvalidArgument`] for an empty size, fewer than 2 bins or no channel.
pub fn bench_inputs(width: usize, height: usize, channels: usize, bins: usize) -> Result<BenchInputs> {
    if channels == 0 {
        return Err(Error::invalid_argument("--channels", "0: must be at least 1"));
    }
    let f = 0.8 * width as f64;
    let cam =
        PinholeCamera::new(f, f, (width as f64 - 1.0) / 2.0, (height as f64 - 1.0) / 2.0, width, height)?;
    let bins = InverseDepthBins::new(0.25, 4.0, bins)?;
    let mut rng = SplitMix64::new(7);
    let mut feats = || Array3::from_shape_simple_fn((height, width, channels), || rng.unit() as f32);
    let (reference, live) = (feats(), feats());
    let t_nr = Pose::from_parts(
        Translation3::new(-0.05, 0.0, -0.02),
        UnitQuaternion::from_euler_angles(0.01, -0.015, 0.005),
    );
    Ok(BenchInputs { reference, live, camera: cam, bins, t_nr })
}
