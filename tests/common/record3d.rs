//! A Record3D "EXR + JPG" export written by hand from a rendered scene (SPEC.md §4a), for the
//! reader and CLI tests. It shares nothing with the reader: `metadata.json` is built with
//! serde_json, the OpenGL pose comes from the renderer's rotation matrix with its y and z columns
//! negated (the reader composes a quaternion instead), `K` is written column-major with the
//! principal point at `+0.5` pixel-centre coordinates, and depth is a half-float EXR at a fraction
//! of the colour size.
#![allow(dead_code)]

use std::path::Path;

use densefeat::geometry::{PinholeCamera, Pose};
use densefeat::image::{DepthMap, RgbImage};
use densefeat::synth::{PhotometricConfig, Scene, SceneConfig};
use exr::prelude::{
    f16, AnyChannel, AnyChannels, Encoding, FlatSamples, Layer, LayerAttributes, WritableImage,
};
use nalgebra::{Rotation3, UnitQuaternion};
use serde_json::json;

/// What was written: the renderer's camera, poses (`T_wc`, our axes) and full-size depth maps.
pub struct Record3dFixture {
    /// The renderer's camera (pixel centres at integers).
    pub camera: PinholeCamera,
    /// Per frame: colour, full-size depth, `T_wc`.
    pub frames: Vec<(RgbImage, DepthMap, Pose)>,
    /// Colour size over depth size (per side).
    pub depth_factor: usize,
}

/// The fixtures' scene: a classic room of seed 5, one sample per pixel, no photometric changes.
pub fn scene_config(width: usize, height: usize, frames: usize) -> SceneConfig {
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

/// Render `frames` frames of a classic synthetic room at `width x height`.
pub fn render(
    width: usize,
    height: usize,
    frames: usize,
) -> (PinholeCamera, Vec<(RgbImage, DepthMap, Pose)>) {
    let scene = Scene::generate(&scene_config(width, height, frames)).unwrap();
    let out = (0..frames)
        .map(|i| {
            let pose = scene.pose(i).unwrap();
            let (rgb, depth) = scene.render_pose(&pose, i).unwrap();
            (rgb, depth, pose)
        })
        .collect();
    (scene.camera(), out)
}

/// `[qx, qy, qz, qw, tx, ty, tz]` of `T_wc` in OpenGL camera axes: the rotation's y and z columns
/// negated (camera y up, looking along -z), as ARKit stores it.
pub fn opengl_pose(t_wc: &Pose) -> [f64; 7] {
    let mut r = t_wc.rotation.to_rotation_matrix().into_inner();
    for row in 0..3 {
        r[(row, 1)] = -r[(row, 1)];
        r[(row, 2)] = -r[(row, 2)];
    }
    let q = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(r));
    let t = t_wc.translation.vector;
    [q.i, q.j, q.k, q.w, t.x, t.y, t.z]
}

/// Write `depth` as a one-channel EXR named `channel`, half floats (`half`) or floats.
pub fn write_exr(path: &Path, depth: &DepthMap, channel: &str, half: bool) {
    let (h, w) = depth.dim();
    let samples = if half {
        FlatSamples::F16(depth.iter().map(|&z| f16::from_f32(z)).collect())
    } else {
        FlatSamples::F32(depth.iter().copied().collect())
    };
    let channels = AnyChannels::sort(vec![AnyChannel::new(channel, samples)].into());
    let layer = Layer::new((w, h), LayerAttributes::default(), Encoding::SMALL_LOSSLESS, channels);
    exr::prelude::Image::from_layer(layer).write().to_file(path).unwrap();
}

/// Save `[H, W, 3]` as a JPEG of quality 95.
pub fn write_jpeg(path: &Path, rgb: &RgbImage) {
    let (h, w, _) = rgb.dim();
    let bytes: Vec<u8> = rgb.iter().map(|v| v.round().clamp(0.0, 255.0) as u8).collect();
    let file = std::io::BufWriter::new(std::fs::File::create(path).unwrap());
    image::codecs::jpeg::JpegEncoder::new_with_quality(file, 95)
        .encode(&bytes, w as u32, h as u32, image::ExtendedColorType::Rgb8)
        .unwrap();
}

/// The depth map Record3D would store for a full-size one: every `factor`-th pixel, starting at
/// the first of each block, so that colour pixels `factor j ..= factor j + factor - 1` read depth
/// pixel `j` back after nearest upsampling with centres aligned when `factor` is 2.
pub fn subsample(depth: &DepthMap, factor: usize) -> DepthMap {
    let (h, w) = depth.dim();
    DepthMap::from_shape_fn((h / factor, w / factor), |(y, x)| depth[[factor * y, factor * x]])
}

/// The `metadata.json` of a rendering: column-major `K` with `cx + 0.5`, `cy + 0.5`.
pub fn metadata(
    camera: &PinholeCamera,
    frames: &[(RgbImage, DepthMap, Pose)],
    factor: usize,
) -> serde_json::Value {
    let k = camera;
    json!({
        "w": k.width,
        "h": k.height,
        "dw": k.width / factor,
        "dh": k.height / factor,
        "fps": 30,
        "K": [k.fx, 0.0, 0.0, 0.0, k.fy, 0.0, k.cx + 0.5, k.cy + 0.5, 1.0],
        "poses": frames.iter().map(|f| opengl_pose(&f.2).to_vec()).collect::<Vec<_>>(),
    })
}

/// Write a Record3D export of a `width x height` rendering with `frames` frames into `dir`
/// (`metadata.json`, `rgb/<i>.jpg`, `depth/<i>.exr` at `1 / factor` of the colour size).
pub fn write(dir: &Path, width: usize, height: usize, frames: usize, factor: usize) -> Record3dFixture {
    let (camera, frames) = render(width, height, frames);
    std::fs::create_dir_all(dir.join("rgb")).unwrap();
    std::fs::create_dir_all(dir.join("depth")).unwrap();
    for (i, (rgb, depth, _)) in frames.iter().enumerate() {
        write_jpeg(&dir.join(format!("rgb/{i}.jpg")), rgb);
        write_exr(&dir.join(format!("depth/{i}.exr")), &subsample(depth, factor), "R", true);
    }
    let meta = metadata(&camera, &frames, factor);
    std::fs::write(dir.join("metadata.json"), serde_json::to_string_pretty(&meta).unwrap()).unwrap();
    Record3dFixture { camera, frames, depth_factor: factor }
}

/// Rewrite `metadata.json` in `dir` through `f`.
pub fn edit_metadata(dir: &Path, f: impl FnOnce(&mut serde_json::Value)) {
    let p = dir.join("metadata.json");
    let mut v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&p).unwrap()).unwrap();
    f(&mut v);
    std::fs::write(&p, serde_json::to_string_pretty(&v).unwrap()).unwrap();
}
