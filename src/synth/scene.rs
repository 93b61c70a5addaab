//! A renderable scene: camera, per-frame poses, textured surfaces, light and camera response.

use nalgebra::Vector3;

use super::layout;
use super::photometric::{Photometric, PhotometricConfig};
use super::rng::SplitMix64;
use super::surface::Surface;
use super::trajectory::CameraPath;
use super::SceneConfig;
use crate::error::{Error, Result};
use crate::geometry::{PinholeCamera, Pose};
use crate::image::{DepthMap, RgbImage};

/// A directional light plus ambient term. Shading is "half-Lambert" (soft, never black) and
/// view-independent: `shade = ambient + diffuse · (1 - n·direction) / 2` with `n` the unit surface
/// normal facing the viewer.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Light {
    /// Unit direction the light travels in (world frame).
    pub direction: Vector3<f64>,
    /// Ambient term.
    pub ambient: f64,
    /// Diffuse term.
    pub diffuse: f64,
}

impl Default for Light {
    /// Uniform lighting (`shade = 1` everywhere).
    fn default() -> Self {
        Self { direction: Vector3::new(0.0, 1.0, 0.0), ambient: 1.0, diffuse: 0.0 }
    }
}

impl Light {
    /// The shading factor of a surface with unit normal `n` (facing the viewer).
    #[inline]
    pub fn shade(&self, n: &Vector3<f64>) -> f64 {
        self.ambient + self.diffuse * 0.5 * (1.0 - n.dot(&self.direction))
    }
}

/// One rendered frame.
#[derive(Clone, Debug)]
pub struct SynthFrame {
    /// Colour, `[H, W, 3]`, 8-bit values as `f32`.
    pub rgb: RgbImage,
    /// Exact depth along the optical axis at each pixel centre, metres; 0 where a ray hits nothing.
    pub depth: DepthMap,
    /// Camera-to-world pose.
    pub pose: Pose,
}

/// A scene ready to render.
#[derive(Clone, Debug)]
pub struct Scene {
    pub(super) camera: PinholeCamera,
    pub(super) poses: Vec<Pose>,
    pub(super) surfaces: Vec<Surface>,
    pub(super) light: Light,
    pub(super) photometric: Photometric,
    pub(super) samples_per_axis: usize,
    pub(super) summary: Vec<String>,
}

impl Scene {
    /// Generate the scene a config describes.
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] from [`SceneConfig::validate`].
    pub fn generate(cfg: &SceneConfig) -> Result<Self> {
        let camera = cfg.camera()?;
        let mut rng = SplitMix64::new(cfg.seed);
        let (mut layout_rng, mut path_rng, mut photo_rng) = (rng.fork(), rng.fork(), rng.fork());
        let path = CameraPath::random(Vector3::zeros(), &mut path_rng);
        let room = layout::generate(&mut layout_rng, &path);
        Ok(Self {
            camera,
            poses: (0..cfg.frames).map(|i| path.pose(i)).collect(),
            surfaces: room.surfaces,
            light: room.light,
            photometric: Photometric::new(cfg.photometric, &mut photo_rng),
            samples_per_axis: cfg.samples_per_axis,
            summary: room.summary,
        })
    }

    /// A hand-built scene: uniform light, no photometric variation, 2×2 anti-aliasing.
    pub fn new(camera: PinholeCamera, poses: Vec<Pose>, surfaces: Vec<Surface>) -> Self {
        let summary = vec![format!("{} hand-built surfaces", surfaces.len())];
        Self {
            camera,
            poses,
            surfaces,
            light: Light::default(),
            photometric: Photometric::new(PhotometricConfig::none(), &mut SplitMix64::new(0)),
            samples_per_axis: 2,
            summary,
        }
    }

    /// Replace the light.
    pub fn with_light(mut self, light: Light) -> Self {
        self.light = light;
        self
    }

    /// Replace the camera (the same world seen through other intrinsics, e.g. a pyramid level's).
    pub fn with_camera(mut self, camera: PinholeCamera) -> Self {
        self.camera = camera;
        self
    }

    /// Replace the camera response.
    pub fn with_photometric(mut self, photometric: Photometric) -> Self {
        self.photometric = photometric;
        self
    }

    /// The camera.
    pub fn camera(&self) -> PinholeCamera {
        self.camera
    }

    /// Number of frames.
    pub fn frames(&self) -> usize {
        self.poses.len()
    }

    /// The surfaces, room first.
    pub fn surfaces(&self) -> &[Surface] {
        &self.surfaces
    }

    /// The light.
    pub fn light(&self) -> &Light {
        &self.light
    }

    /// The camera response.
    pub fn photometric(&self) -> &Photometric {
        &self.photometric
    }

    /// One line per scene element, for logs and READMEs.
    pub fn summary(&self) -> &[String] {
        &self.summary
    }

    /// Camera-to-world pose of frame `i`.
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] if `i` is out of range.
    pub fn pose(&self, i: usize) -> Result<Pose> {
        self.poses.get(i).copied().ok_or_else(|| {
            Error::invalid_argument(
                "frame index",
                format!("{i} is out of range: the scene has {} frames", self.poses.len()),
            )
        })
    }

    /// Render frame `i`.
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] if `i` is out of range.
    pub fn render(&self, i: usize) -> Result<SynthFrame> {
        let pose = self.pose(i)?;
        let (rgb, depth) = self.render_pose(&pose, i);
        Ok(SynthFrame { rgb, depth, pose })
    }
}
