//! A ScanNet SensReader export written by hand from a rendered scene (SPEC.md §4a), for the reader
//! tests: `color/<i>.jpg` from the renderer's camera, `depth/<i>.png` (millimetres) rendered
//! independently through a depth camera of the same centre and axes but other intrinsics and half
//! the size, `pose/<i>.txt` (row-major `T_wc`) and `intrinsic/` as 4x4 matrices.
#![allow(dead_code)]

use std::path::Path;

use densefeat::geometry::{PinholeCamera, Pose};
use densefeat::image::{DepthMap, RgbImage};
use densefeat::synth::Scene;

use super::record3d::{scene_config, write_jpeg};

/// What was written.
pub struct ScanNetFixture {
    /// The colour camera.
    pub colour: PinholeCamera,
    /// The depth camera.
    pub depth: PinholeCamera,
    /// Per frame: colour, the colour camera's own rendered depth (the truth the reader should
    /// approach), `T_wc`.
    pub frames: Vec<(RgbImage, DepthMap, Pose)>,
}

/// A depth camera of half the colour size whose focal lengths and principal point are not the
/// colour camera's halves (as ScanNet's are not): 3 % longer focal lengths, the centre moved by
/// (1.5, 2.5) depth pixels.
pub fn depth_camera(c: &PinholeCamera) -> PinholeCamera {
    let (w, h) = (c.width / 2, c.height / 2);
    PinholeCamera::new(0.5 * c.fx * 1.03, 0.5 * c.fy * 1.03, 0.5 * c.cx + 1.5, 0.5 * c.cy + 2.5, w, h)
        .unwrap()
}

fn matrix(path: &Path, m: [[f64; 4]; 4]) {
    let text: String = m.iter().map(|r| format!("{:e} {:e} {:e} {:e}\n", r[0], r[1], r[2], r[3])).collect();
    std::fs::write(path, text).unwrap();
}

/// Write `k` as a 4x4 intrinsics file.
pub fn intrinsic(path: &Path, k: &PinholeCamera) {
    matrix(
        path,
        [[k.fx, 0.0, k.cx, 0.0], [0.0, k.fy, k.cy, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]],
    );
}

/// The identity, as ScanNet's extrinsics are.
pub fn identity(path: &Path) {
    matrix(path, [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]]);
}

/// Render `frames` frames at `width x height` and write them into `dir`.
pub fn write(dir: &Path, width: usize, height: usize, frames: usize) -> ScanNetFixture {
    let scene = Scene::generate(&scene_config(width, height, frames)).unwrap();
    let colour = scene.camera();
    let depth = depth_camera(&colour);
    let through_depth = Scene::generate(&scene_config(width, height, frames)).unwrap().with_camera(depth);
    for sub in ["color", "depth", "pose", "intrinsic"] {
        std::fs::create_dir_all(dir.join(sub)).unwrap();
    }
    intrinsic(&dir.join("intrinsic/intrinsic_color.txt"), &colour);
    intrinsic(&dir.join("intrinsic/intrinsic_depth.txt"), &depth);
    identity(&dir.join("intrinsic/extrinsic_color.txt"));
    identity(&dir.join("intrinsic/extrinsic_depth.txt"));
    let mut out = Vec::new();
    for i in 0..frames {
        let pose = scene.pose(i).unwrap();
        let (rgb, z) = scene.render_pose(&pose, i).unwrap();
        let (_, zd) = through_depth.render_pose(&pose, i).unwrap();
        write_jpeg(&dir.join(format!("color/{i}.jpg")), &rgb);
        let (h, w) = zd.dim();
        let mm: Vec<u16> =
            zd.iter().map(|&v| if v > 0.0 { (f64::from(v) * 1e3).round() as u16 } else { 0 }).collect();
        image::ImageBuffer::<image::Luma<u16>, Vec<u16>>::from_raw(w as u32, h as u32, mm)
            .unwrap()
            .save(dir.join(format!("depth/{i}.png")))
            .unwrap();
        let m = pose.to_homogeneous();
        let rows = [0, 1, 2, 3].map(|r| [m[(r, 0)], m[(r, 1)], m[(r, 2)], m[(r, 3)]]);
        matrix(&dir.join(format!("pose/{i}.txt")), rows);
        out.push((rgb, z, pose));
    }
    ScanNetFixture { colour, depth, frames: out }
}
