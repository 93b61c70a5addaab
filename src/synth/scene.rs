//! A renderable scene: camera, per-frame poses, textured surfaces, light and camera response.

use nalgebra::Vector3;

use super::photometric::{Photometric, PhotometricConfig};
use super::sensor::{random_photometric, Sensor};
use super::surface::Surface;
use super::trajectory::CameraPath;
use super::{furnish, layout, SceneConfig, Style};
use crate::error::{Error, Result};
use crate::geometry::{PinholeCamera, Pose};
use crate::image::{DepthMap, RgbImage};
use crate::util::rng::SplitMix64;

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

/// A point light with soft fall-off (the realistic style's ceiling lamp): a surface point `p` with
/// unit normal `n` (facing the viewer) gets `power · max(0, n·(q - p)/|q - p|) / (1 + |q - p|²/radius²)`
/// added to its shading, `q` the lamp position. View-independent, like [`Light`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Lamp {
    /// Position, world frame.
    pub position: Vector3<f64>,
    /// Strength.
    pub power: f64,
    /// Fall-off distance, metres.
    pub radius: f64,
}

impl Lamp {
    /// The lamp's shading contribution at `p` with unit normal `n`.
    #[inline]
    pub fn shade(&self, p: &Vector3<f64>, n: &Vector3<f64>) -> f64 {
        let d = self.position - p;
        let d2 = d.norm_squared();
        let cos = n.dot(&d) / d2.sqrt();
        self.power * cos.max(0.0) / (1.0 + d2 / (self.radius * self.radius))
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
    /// Realistic style only: the ceiling lamp, the camera path (for motion blur) and the sensor.
    pub(super) lamp: Option<Lamp>,
    pub(super) path: Option<CameraPath>,
    pub(super) sensor: Option<Sensor>,
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
        let path = CameraPath::random(Vector3::zeros(), &mut path_rng).with_motion(cfg.motion);
        let poses = (0..cfg.frames).map(|i| path.pose(i)).collect();
        if cfg.style == Style::Real {
            let mut sensor_rng = rng.fork();
            super::atlas::check()?;
            let (room, lamp) = furnish::generate(&mut layout_rng, &path);
            let photometric = random_photometric(&mut photo_rng);
            let mut summary = room.summary;
            summary.push(format!("camera motion {}", cfg.motion));
            summary.push(format!(
                "camera fx {:.1} fy {:.1} cx {:.1} cy {:.1}",
                camera.fx, camera.fy, camera.cx, camera.cy
            ));
            return Ok(Self {
                camera,
                poses,
                surfaces: room.surfaces,
                light: room.light,
                photometric: Photometric::new(photometric, &mut photo_rng),
                samples_per_axis: cfg.samples_per_axis,
                summary,
                lamp: Some(lamp),
                path: Some(path),
                sensor: Some(Sensor::random(&mut sensor_rng)),
            });
        }
        let room = layout::generate(&mut layout_rng, &path);
        let mut summary = room.summary;
        summary.push(format!("camera motion {}", cfg.motion));
        Ok(Self {
            camera,
            poses,
            surfaces: room.surfaces,
            light: room.light,
            photometric: Photometric::new(cfg.photometric, &mut photo_rng),
            samples_per_axis: cfg.samples_per_axis,
            summary,
            lamp: None,
            path: None,
            sensor: None,
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
            lamp: None,
            path: None,
            sensor: None,
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

    /// The realistic style's sensor (`None` for the classic style and hand-built scenes).
    pub fn sensor(&self) -> Option<&Sensor> {
        self.sensor.as_ref()
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
    /// [`Error::InvalidArgument`] if `i` is out of range (or, never in practice, if the JPEG codec
    /// of the realistic style fails).
    pub fn render(&self, i: usize) -> Result<SynthFrame> {
        let pose = self.pose(i)?;
        let (rgb, depth) = self.render_pose(&pose, i)?;
        Ok(SynthFrame { rgb, depth, pose })
    }
}
