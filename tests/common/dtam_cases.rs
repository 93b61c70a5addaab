//! Inputs and fingerprints shared by the DTAM tests (tests/dtam.rs, dtam_normals.rs, dtam_tgv.rs).

use densefeat::dtam::{DtamReport, DtamResult};
use densefeat::geometry::{InverseDepthBins, PinholeCamera, Pose};
use densefeat::synth::{Quad, Scene, Shape, Surface, SynthFrame, Texture};
use nalgebra::{Translation3, UnitQuaternion, Vector3};
use ndarray::{Array2, Array3};

/// A deterministic pseudo-random stream from a seed (tests only).
pub fn stream(seed: u64) -> impl FnMut() -> f64 {
    let mut s = seed ^ 0x9E37_79B9_7F4A_7C15;
    move || {
        s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        (s >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// Random DTAM inputs `[h, w, k]` from `seed`: costs in [0, 50), bins over [0.1, 2] 1/m, grey levels
/// in [0, 255), initial inverse depth in [0.1, 2].
pub fn random_solve_inputs(
    (h, w, k): (usize, usize, usize),
    seed: u64,
) -> (Array3<f32>, InverseDepthBins, Array2<f32>, Array2<f32>) {
    let mut r = stream(seed);
    let costs = Array3::from_shape_fn((h, w, k), |_| (r() * 50.0) as f32);
    let bins = InverseDepthBins::new(0.1, 2.0, k).unwrap();
    let grey = Array2::from_shape_fn((h, w), |_| (r() * 255.0) as f32);
    let init = Array2::from_shape_fn((h, w), |_| (0.1 + 1.9 * r()) as f32);
    (costs, bins, grey, init)
}

/// The bits of a solve's result and report (all but the wall time).
pub type Fingerprint = (Vec<u32>, Vec<u32>, Vec<u64>, Vec<u64>, usize, bool);

/// [`Fingerprint`] of a solve.
pub fn fingerprint((res, rep): (DtamResult, DtamReport)) -> Fingerprint {
    (
        res.inverse_depth.iter().map(|v| v.to_bits()).collect(),
        res.auxiliary.iter().map(|v| v.to_bits()).collect(),
        rep.energy.iter().map(|v| v.to_bits()).collect(),
        rep.gap.iter().map(|v| v.to_bits()).collect(),
        rep.iterations,
        rep.converged,
    )
}

/// `f` run on a pool of `n` threads.
pub fn with_threads<T: Send>(n: usize, f: impl FnOnce() -> T + Send) -> T {
    rayon::ThreadPoolBuilder::new().num_threads(n).build().unwrap().install(f)
}

/// The camera of the plane cases: 160x120, `f` = 128.
pub fn plane_camera() -> PinholeCamera {
    PinholeCamera::new(128.0, 128.0, 79.5, 59.5, 160, 120).unwrap()
}

/// A plane through `(0, 0, 2)` turned `degrees` about the vertical axis (normal `(−sin, 0, cos)`
/// up to sign), [`render_plane`]d.
pub fn plane_frames(degrees: f64) -> (Vec<Pose>, Vec<SynthFrame>) {
    let (s, c) = degrees.to_radians().sin_cos();
    let axis_u = Vector3::new(c, 0.0, s);
    render_plane(Quad::new(Vector3::new(0.0, -10.0, 2.0) - axis_u * 6.0, axis_u, Vector3::y(), [12.0, 20.0]))
}

/// `plane` with faint, low-contrast texture (winner-take-all is noisy there, as on real walls),
/// rendered by [`plane_camera`] from 5 poses on a horizontal line 0.1 m apart.
pub fn render_plane(plane: Quad) -> (Vec<Pose>, Vec<SynthFrame>) {
    let texture =
        Texture::Noise { a: [0.45, 0.45, 0.45], b: [0.55, 0.55, 0.55], scale: 0.05, octaves: 2, key: 3 };
    let poses: Vec<Pose> = (0..5)
        .map(|i| {
            Pose::from_parts(Translation3::new(0.1 * (i as f64 - 2.0), 0.0, 0.0), UnitQuaternion::identity())
        })
        .collect();
    let scene =
        Scene::new(plane_camera(), poses.clone(), vec![Surface { shape: Shape::Quad(plane), texture }]);
    let frames = (0..5).map(|i| scene.render(i).unwrap()).collect();
    (poses, frames)
}

/// The RGB volume of a plane case's middle camera (64 hypotheses over 0.1-1 1/m, 4 live frames)
/// and what a solve on it needs.
pub struct PlaneVolume {
    pub costs: Array3<f32>,
    pub bins: InverseDepthBins,
    pub grey: Array2<f32>,
    pub wta: Array2<f32>,
    /// The middle frame's rendered depth.
    pub depth: Array2<f32>,
    /// The mapping's normalised schedule at the λ asked for.
    pub params: densefeat::dtam::DtamParams,
}

/// [`PlaneVolume`] of [`plane_frames`]`(degrees)` at `lambda`.
pub fn plane_volume(degrees: f64, lambda: f64) -> PlaneVolume {
    use densefeat::costvolume::CostVolume;
    use densefeat::geometry::relative_pose;
    let (poses, frames) = plane_frames(degrees);
    let cam = plane_camera();
    let bins = InverseDepthBins::new(0.1, 1.0, 64).unwrap();
    let mut cv = CostVolume::new(frames[2].rgb.clone(), cam, bins).unwrap();
    for i in [0, 1, 3, 4] {
        cv.add_frame(frames[i].rgb.view(), &relative_pose(&poses[2], &poses[i])).unwrap();
    }
    let wta = cv.winner_take_all().inverse_depth;
    let costs = cv.costs();
    let params = densefeat::dtam::DtamParams { lambda, ..densefeat::dtam::MAPPING_DEFAULTS }.normalised(
        densefeat::costvolume::cost_scale(costs.view()),
        cam.width,
        bins.rho_max - bins.rho_min,
    );
    let grey = densefeat::image::to_gray(&frames[2].rgb);
    PlaneVolume { costs, bins, grey, wta, depth: frames[2].depth.clone(), params }
}

impl PlaneVolume {
    /// Huber-TV's problem on this volume, initialised by winner-take-all.
    pub fn problem(&self) -> densefeat::dtam::DtamProblem<'_> {
        densefeat::dtam::DtamProblem::new(
            self.costs.view(),
            &self.bins,
            self.grey.view(),
            self.wta.view(),
            &self.params,
        )
    }

    /// The interior `[10, 110)²` of an inverse-depth map, row-major.
    pub fn interior(m: &Array2<f32>) -> Vec<f64> {
        m.slice(ndarray::s![10..110, 10..110]).iter().map(|&v| v as f64).collect()
    }

    /// The interior of the rendered inverse depth.
    pub fn truth(&self) -> Vec<f64> {
        Self::interior(&self.depth.mapv(|z| 1.0 / z))
    }
}

/// Root mean square difference.
pub fn rms(a: &[f64], b: &[f64]) -> f64 {
    (a.iter().zip(b).map(|(x, y)| (x - y) * (x - y)).sum::<f64>() / a.len() as f64).sqrt()
}
