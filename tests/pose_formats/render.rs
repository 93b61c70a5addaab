//! Small rendered sequences and the checks every format shares.

use densefeat::eval::photometric_warp_check;
use densefeat::geometry::{relative_pose, PinholeCamera, Pose, Warp};
use densefeat::image::{DepthMap, RgbImage};
use densefeat::sequence::{Frame, Sequence};
use densefeat::synth::{PhotometricConfig, Scene, SceneConfig};

/// Pose and camera round-trip tolerance (numbers are written in shortest round-trip form; the
/// quaternion / matrix conversions cost a few ulp).
pub const POSE_TOLERANCE: f64 = 1e-12;
/// Largest reprojection difference between the reader's cameras and poses and the renderer's.
pub const REPROJECTION_TOLERANCE_PX: f64 = 1e-6;

/// A rendered sequence: the renderer's camera, and per frame colour, depth and `T_wc`.
pub struct Rendered {
    pub camera: PinholeCamera,
    pub frames: Vec<(RgbImage, DepthMap, Pose)>,
}

fn config(width: usize, height: usize, frames: usize) -> SceneConfig {
    SceneConfig {
        seed: 5,
        width,
        height,
        frames,
        samples_per_axis: 1,
        photometric: PhotometricConfig::none(),
        ..SceneConfig::default()
    }
}

/// Render `frames` frames at `width x height` (through `camera` if given).
pub fn render(width: usize, height: usize, frames: usize, camera: Option<PinholeCamera>) -> Rendered {
    let mut scene = Scene::generate(&config(width, height, frames)).unwrap();
    if let Some(c) = camera {
        scene = scene.with_camera(c);
    }
    let camera = scene.camera();
    let frames = (0..frames)
        .map(|i| {
            let pose = scene.pose(i).unwrap();
            let (rgb, depth) = scene.render_pose(&pose, i).unwrap();
            (rgb, depth, pose)
        })
        .collect();
    Rendered { camera, frames }
}

/// The renderer's camera and poses equal the reader's within [`POSE_TOLERANCE`].
pub fn assert_same_geometry(seq: &Sequence, r: &Rendered) {
    let (a, b) = (&seq.camera, &r.camera);
    assert_eq!((a.width, a.height), (b.width, b.height));
    for (x, y, name) in [(a.fx, b.fx, "fx"), (a.fy, b.fy, "fy"), (a.cx, b.cx, "cx"), (a.cy, b.cy, "cy")] {
        assert!((x - y).abs() <= POSE_TOLERANCE * y.abs().max(1.0), "{name}: read {x}, rendered {y}");
    }
    assert_eq!(seq.len(), r.frames.len());
    for (i, (f, (_, _, p))) in seq.frames.iter().zip(&r.frames).enumerate() {
        let dt = (f.pose.translation.vector - p.translation.vector).norm();
        let dr = f.pose.rotation.angle_to(&p.rotation);
        assert!(
            dt <= POSE_TOLERANCE && dr <= POSE_TOLERANCE,
            "frame {i}: translation off by {dt:e}, rotation {dr:e} rad"
        );
    }
}

/// Largest difference, pixels, between frame `a`'s rendered depth reprojected into frame `b` with
/// the reader's camera and poses and with the renderer's.
pub fn reprojection_difference(seq: &Sequence, r: &Rendered, a: usize, b: usize) -> f64 {
    let truth = Warp::new(&r.camera, &r.camera, &relative_pose(&r.frames[a].2, &r.frames[b].2));
    let read = Warp::new(&seq.camera, &seq.camera, &relative_pose(&seq.frames[a].pose, &seq.frames[b].pose));
    let depth = &r.frames[a].1;
    let mut worst = 0.0f64;
    let mut n = 0;
    for ((y, x), &z) in depth.indexed_iter() {
        if z <= 0.0 || x % 3 != 0 || y % 3 != 0 {
            continue;
        }
        let rho = 1.0 / f64::from(z);
        if let (Some(p), Some(q)) =
            (truth.apply(x as f64, y as f64, rho), read.apply(x as f64, y as f64, rho))
        {
            worst = worst.max((p.uv - q.uv).norm());
            n += 1;
        }
    }
    assert!(n > 100, "only {n} pixels reprojected");
    worst
}

/// Half a grey level: colour files store 8-bit values, the renderer's are real, so the warp
/// check's mean absolute grey error moves by at most this through the round trip.
pub const GREY_QUANTISATION: f64 = 0.5;

/// The photometric warp check of frames `a -> b` as loaded by the reader (with `depth` for frame
/// `a` where the format has none) matches the same check on the renderer's own frames and poses
/// within [`GREY_QUANTISATION`]: the reader's images, depths and poses are the renderer's.
pub fn assert_warp_matches_renderer(
    seq: &Sequence,
    r: &Rendered,
    a: usize,
    b: usize,
    depth: Option<&DepthMap>,
) {
    let mut fa = seq.load_frame(a).unwrap();
    if let Some(d) = depth {
        fa.depth = Some(d.clone());
    }
    let fb = seq.load_frame(b).unwrap();
    let read = photometric_warp_check(&fa, &fb).unwrap();
    let truth_frame = |i: usize| Frame {
        index: i,
        rgb: r.frames[i].0.clone(),
        depth: Some(r.frames[i].1.clone()),
        pose: r.frames[i].2,
        camera: r.camera,
    };
    let truth = photometric_warp_check(&truth_frame(a), &truth_frame(b)).unwrap();
    eprintln!(
        "warp {b} -> {a}: read {:.3} (identity {:.3}), renderer {:.3} (identity {:.3})",
        read.warped_error, read.identity_error, truth.warped_error, truth.identity_error
    );
    assert!(
        (read.warped_error - truth.warped_error).abs() <= GREY_QUANTISATION,
        "warped grey error {} read vs {} rendered",
        read.warped_error,
        truth.warped_error
    );
    assert!(read.warped_error < read.identity_error, "the warp must beat no warp");
}

/// The error's text, which must contain every one of `parts`.
#[track_caller]
pub fn assert_error(result: densefeat::error::Result<Sequence>, parts: &[&str]) {
    let e = match result {
        Ok(_) => panic!("expected an error containing {parts:?}"),
        Err(e) => e.to_string(),
    };
    for p in parts {
        assert!(e.contains(p), "error {e:?} lacks {p:?}");
    }
}
