//! Deterministic inputs of the benchmarks (`densefeat bench`, `benches/`): the same bytes on every
//! machine, so timings compare.

use nalgebra::{Translation3, UnitQuaternion};
use ndarray::{Array2, Array3};

use crate::error::{Error, Result};
use crate::geometry::{InverseDepthBins, PinholeCamera, Pose};
use crate::util::rng::SplitMix64;

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

/// Inputs of the benchmark: random reference and live features in `[0, 1)` (three channels: random
/// integers `0..=255`, as decoded RGB images), a camera with
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
    // Three channels are RGB as decoded images hold it (integers 0..=255, the cost volume's packed
    // path, SPEC.md §9.4); other channel counts are learned-feature-like floats.
    let rgb = channels == 3;
    let mut feats = || {
        Array3::from_shape_simple_fn((height, width, channels), || {
            let u = rng.unit();
            if rgb {
                (u * 256.0).floor().min(255.0) as f32
            } else {
                u as f32
            }
        })
    };
    let (reference, live) = (feats(), feats());
    let t_nr = Pose::from_parts(
        Translation3::new(-0.05, 0.0, -0.02),
        UnitQuaternion::from_euler_angles(0.01, -0.015, 0.005),
    );
    Ok(BenchInputs { reference, live, camera: cam, bins, t_nr })
}

/// Inputs of the DTAM benchmark (see [`tv_inputs`]).
#[derive(Clone, Debug)]
pub struct TvInputs {
    /// Cost volume `[H, W, K]`.
    pub costs: Array3<f32>,
    /// The hypotheses.
    pub bins: InverseDepthBins,
    /// Reference grey image `[H, W]`, 0-255.
    pub grey: Array2<f32>,
    /// Initial inverse depth (the per-pixel argmin).
    pub init: Array2<f32>,
}

/// Width of the pseudo-noise in the synthetic cost curves, grey levels.
pub(crate) const NOISE: f64 = 8.0;
/// Depth of a cost curve's valley, grey levels (RGB mean L1 costs are of this order).
pub(crate) const VALLEY: f64 = 30.0;
/// Width of the valley in inverse depth, 1/m.
pub(crate) const VALLEY_WIDTH: f64 = 0.15;

/// A smooth synthetic cost volume with the statistics of an RGB volume: hypotheses over depths
/// `[0.4, 10]` m; the true inverse depth is a slanted plane plus a sine and two rectangles in front
/// (depth discontinuities); each curve is an inverted Gaussian valley of depth `VALLEY` grey levels
/// and width `VALLEY_WIDTH` at the truth plus uniform noise of `NOISE` levels; the left twentieth of the image has its
/// nearest quarter of hypotheses unseen (out of the live frames' view). The grey image has the
/// rectangles' edges plus texture noise. Deterministic (SplitMix64 seed 11).
///
/// # Errors
/// [`Error::InvalidArgument`] for an empty size or fewer than 2 bins.
pub fn tv_inputs(width: usize, height: usize, bins: usize) -> Result<TvInputs> {
    if width == 0 || height == 0 {
        return Err(Error::invalid_argument("--size", "empty"));
    }
    let bins = InverseDepthBins::from_depth_range(0.4, 10.0, bins)?;
    let (w, h) = (width as f64, height as f64);
    let in_box = |x: usize, y: usize| {
        let (u, v) = (x as f64 / w, y as f64 / h);
        (0.2..0.4).contains(&u) && (0.3..0.7).contains(&v)
            || (0.6..0.85).contains(&u) && (0.1..0.5).contains(&v)
    };
    let truth = |x: usize, y: usize| {
        let base = 0.3 + 1.2 * x as f64 / w + 0.2 * (std::f64::consts::PI * y as f64 / h).sin();
        if in_box(x, y) {
            base + 0.6
        } else {
            base
        }
    };
    let mut rng = SplitMix64::new(11);
    let k = bins.count;
    let costs = Array3::from_shape_fn((height, width, k), |(y, x, i)| {
        let noise = NOISE * rng.unit();
        if x * 20 < width && i * 4 >= 3 * k {
            return crate::costvolume::UNSEEN_COST;
        }
        let d = bins.rho(i) - truth(x, y);
        (VALLEY * (1.0 - (-d * d / (2.0 * VALLEY_WIDTH * VALLEY_WIDTH)).exp()) + noise) as f32
    });
    let grey = Array2::from_shape_fn((height, width), |(y, x)| {
        (if in_box(x, y) { 180.0 } else { 80.0 } + 20.0 * rng.unit()) as f32
    });
    let init = Array2::from_shape_fn((height, width), |(y, x)| {
        let curve = costs.slice(ndarray::s![y, x, ..]);
        let (kmin, _) =
            curve.iter().enumerate().fold((0, f32::INFINITY), |b, (i, &c)| if c < b.1 { (i, c) } else { b });
        bins.rho(kmin) as f32
    });
    Ok(TvInputs { costs, bins, grey, init })
}

/// Inputs of the refinement benchmark (see [`refine_inputs`]).
#[derive(Clone, Debug)]
pub struct RefineInputs {
    /// The camera of every frame.
    pub camera: PinholeCamera,
    /// Keyframe grey image `[H, W]`.
    pub key: Array2<f64>,
    /// The estimate to refine `[H, W]`: the truth 0.7 bin nearer, NaN on the top twentieth of the rows.
    pub rho0: Array2<f64>,
    /// Live grey images `[H, W]`.
    pub greys: Vec<Array2<f64>>,
    /// Their `T_nr`.
    pub poses: Vec<Pose>,
    /// The bin step `Δρ` of 128 hypotheses over `[0.4, 10]` m, 1/m.
    pub step: f64,
}

/// A slanted textured plane 2 m away seen by a keyframe and `frames` live cameras up to 30 cm to
/// its sides (turned by up to about 1°), `f = 0.9 W`: the estimate sits 0.7 bin off the truth
/// (missing on the top twentieth of the rows), as DTAM's output at level 1 upsampled to the input resolution.
/// Deterministic (SplitMix64 seed 17).
///
/// # Errors
/// [`Error::InvalidArgument`] for an empty size or no frame.
pub fn refine_inputs(width: usize, height: usize, frames: usize) -> Result<RefineInputs> {
    if width == 0 || height == 0 {
        return Err(Error::invalid_argument("--size", "empty"));
    }
    if frames == 0 {
        return Err(Error::invalid_argument("--frames", "0: must be at least 1"));
    }
    let (w, h) = (width as f64, height as f64);
    let camera = PinholeCamera::new(0.9 * w, 0.9 * w, (w - 1.0) / 2.0, (h - 1.0) / 2.0, width, height)?;
    let n = nalgebra::Vector3::new(0.35, -0.2, 1.0).normalize();
    let c = 2.0;
    let mut rng = SplitMix64::new(17);
    let speckle: Vec<f64> = (0..64 * 64).map(|_| 30.0 * rng.unit()).collect();
    let render = |t_rn: &Pose| {
        Array2::from_shape_fn((height, width), |(y, x)| {
            let o = t_rn.translation.vector;
            let d = t_rn.rotation * camera.ray(x as f64, y as f64);
            let p = o + d * ((c - n.dot(&o)) / n.dot(&d));
            let cell = ((p.x * 40.0).rem_euclid(64.0) as usize) * 64 + (p.y * 40.0).rem_euclid(64.0) as usize;
            128.0
                + 40.0 * (7.0 * p.x).sin() * (5.0 * p.y).cos()
                + 25.0 * (23.0 * p.x + 17.0 * p.y).sin()
                + speckle[cell]
        })
    };
    let bins = InverseDepthBins::from_depth_range(0.4, 10.0, 128)?;
    let step = bins.step();
    let rho0 = Array2::from_shape_fn((height, width), |(y, x)| {
        if y * 20 < height {
            f64::NAN
        } else {
            n.dot(&camera.ray(x as f64, y as f64)) / c + 0.7 * step
        }
    });
    let mut greys = Vec::with_capacity(frames);
    let mut poses = Vec::with_capacity(frames);
    for i in 0..frames {
        let a = std::f64::consts::TAU * i as f64 / frames as f64;
        let t = [0.3 * a.cos(), 0.1 * a.sin(), 0.05 * (2.0 * a).sin()];
        let t_rn = Pose::from_parts(
            Translation3::new(t[0], t[1], t[2]),
            UnitQuaternion::from_euler_angles(0.03 * t[1], -0.06 * t[0], 0.005),
        );
        greys.push(render(&t_rn));
        poses.push(t_rn.inverse());
    }
    Ok(RefineInputs { camera, key: render(&Pose::identity()), rho0, greys, poses, step })
}
