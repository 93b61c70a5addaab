//! A deterministic renderer of indoor-like scenes with exact depth, for training and testing
//! without a dataset.
//!
//! A seed fixes everything: a room (floor, ceiling, four walls) with textured boxes on the floor,
//! sometimes stacked, an optional wall cabinet and poster, and a board leaning against the far
//! wall (a slanted plane); per-surface procedural textures from rich to nearly textureless
//! ([`Texture`]); a handheld-like camera path ([`CameraPath`]); and a per-frame camera response
//! ([`Photometric`]).
//!
//! That is the [`Style::Classic`] look (the shipped fixture's). [`Style::Real`] aims at training
//! data that transfers to real rooms: photo textures cut from the training scenes' frames
//! (`fixtures/textures/`, embedded), painted nearly uniform walls and ceiling, furniture built from
//! boxes, slanted planes, a ceiling lamp, random intrinsics and a realistic sensor (white balance,
//! exposure jitter, vignetting, shot and read noise, motion blur, JPEG) — see SPEC.md §4b.
//!
//! Rendering casts rays analytically ([`surface`]): depth is the optical-axis depth of the nearest
//! hit through the pixel centre (integer coordinates, SPEC.md §2.1), colour is the mean of
//! `n × n` stratified sub-pixel samples around it. Geometry is `f64`.
//!
//! Determinism: the scene comes from an in-crate SplitMix64 ([`crate::util::rng`]), per-pixel noise from a
//! counter-based hash, trigonometry from [`detmath`] (IEEE basic operations only), and rows are
//! rendered in parallel with each pixel computed independently. A seed gives bit-identical frames
//! for any thread count, and the same files on any platform with the same `Cargo.lock`.
//!
//! Speed (`cargo bench -p densefeat-benches --bench synth`, 2×2 samples, 2 CPU cores): about 30 ms per 320×240 frame and
//! 117 ms per 640×480 frame, i.e. fast enough to render training data on the fly.
//!
//! ```
//! use densefeat::synth::{Scene, SceneConfig};
//! let cfg = SceneConfig { width: 64, height: 48, frames: 2, ..SceneConfig::default() };
//! let scene = Scene::generate(&cfg).unwrap();
//! let frame = scene.render(1).unwrap();
//! assert_eq!(frame.rgb.dim(), (48, 64, 3));
//! assert!(frame.depth.iter().all(|&z| z > 0.3 && z < 7.0));
//! ```

mod atlas;
pub mod detmath;
mod furnish;
mod layout;
pub mod noise;
mod photometric;
mod render;
mod scene;
mod sensor;
pub mod surface;
mod texture;
mod trajectory;
mod write;

pub use atlas::{tile_count as atlas_tile_count, ATLAS_CROPS};
pub use photometric::{Exposure, Photometric, PhotometricConfig};
pub use scene::{Lamp, Light, Scene, SynthFrame};
pub use sensor::{jpeg_round_trip, Sensor, FOCAL_RANGE_640, JPEG_QUALITY, MAX_SHUTTER, PRINCIPAL_JITTER};
pub use surface::{Cuboid, Hit, Quad, Shape, Surface};
pub use texture::{random_colour, Albedo, Texture, PALETTE_LEN};
pub use trajectory::{look_at, CameraPath, Motion};
pub use write::{write_scene, write_sequence};

use crate::error::{Error, Result};
use crate::geometry::PinholeCamera;

/// The scenes photo-texture crops may be cut from: the TRAINING scenes of the protocol (SPEC.md
/// §4b), never a validation or test scene.
pub const TRAINING_SCENES: [&str; 2] = ["hololens_000", "tartanair_hospital"];
/// Side of one square tile of the photo-texture atlas, pixels.
pub const ATLAS_TILE: usize = 128;
/// Tiles per row of the photo-texture atlas.
pub const ATLAS_COLUMNS: usize = 8;

/// Largest image side accepted, pixels.
pub const MAX_SIDE: usize = 8192;
/// Largest number of frames accepted.
pub const MAX_FRAMES: usize = 1_000_000;
/// Largest sub-pixel grid accepted (`samples_per_axis²` rays per pixel).
pub const MAX_SAMPLES_PER_AXIS: usize = 8;
/// Default focal length as a fraction of the image width (horizontal field of view ≈ 64°).
pub const DEFAULT_FOCAL_RATIO: f64 = 0.8;

/// The look of a generated scene.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Style {
    /// Procedural textures (noise, stripes, checker, collage), fixed intrinsics
    /// (`fx = fy = focal_ratio · W`, centred principal point) and the mild camera response of
    /// `photometric`. The shipped fixture `room_s1` is this style.
    #[default]
    Classic,
    /// Photo textures cut from the training scenes, painted walls and ceiling, furniture and
    /// slanted planes, random intrinsics and a realistic sensor ([`Sensor`]: white balance,
    /// exposure jitter, vignetting, shot and read noise, motion blur, JPEG). Ignores
    /// `focal_ratio` and `photometric` (both are drawn from the seed).
    Real,
}

impl std::str::FromStr for Style {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        match s {
            "classic" => Ok(Style::Classic),
            "real" => Ok(Style::Real),
            _ => Err(Error::invalid_argument("--style", format!("{s:?}: expected classic or real"))),
        }
    }
}

impl std::fmt::Display for Style {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Style::Classic => "classic",
            Style::Real => "real",
        })
    }
}

/// Salt of the generator that draws the realistic style's intrinsics from the seed.
const INTRINSICS_SALT: u64 = 0x1A75_1C5E_ED00_0001;

/// What to render.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SceneConfig {
    /// Fixes the room, objects, textures, camera path and photometric drift.
    pub seed: u64,
    /// Image width, pixels.
    pub width: usize,
    /// Image height, pixels.
    pub height: usize,
    /// Number of frames.
    pub frames: usize,
    /// `fx = fy = focal_ratio · width`; the principal point is the image centre `((W-1)/2, (H-1)/2)`.
    pub focal_ratio: f64,
    /// Anti-aliasing: `samples_per_axis²` stratified colour samples per pixel.
    pub samples_per_axis: usize,
    /// Camera response.
    pub photometric: PhotometricConfig,
    /// Scene style.
    pub style: Style,
    /// How the camera moves.
    pub motion: Motion,
}

impl Default for SceneConfig {
    fn default() -> Self {
        Self {
            seed: 1,
            width: 320,
            height: 240,
            frames: 40,
            focal_ratio: DEFAULT_FOCAL_RATIO,
            samples_per_axis: 2,
            photometric: PhotometricConfig::default(),
            style: Style::Classic,
            motion: Motion::Handheld,
        }
    }
}

impl SceneConfig {
    /// Check every field.
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] naming the first field out of range.
    pub fn validate(&self) -> Result<()> {
        for (name, v) in [("width", self.width), ("height", self.height)] {
            if v == 0 || v > MAX_SIDE {
                return Err(Error::invalid_argument(name, format!("{v} pixels: must be in 1..={MAX_SIDE}")));
            }
        }
        if self.frames == 0 || self.frames > MAX_FRAMES {
            return Err(Error::invalid_argument(
                "frames",
                format!("{}: must be in 1..={MAX_FRAMES}", self.frames),
            ));
        }
        if !(self.focal_ratio.is_finite() && self.focal_ratio > 0.0) {
            return Err(Error::invalid_argument(
                "focal ratio",
                format!("{}: must be finite and positive", self.focal_ratio),
            ));
        }
        if self.samples_per_axis == 0 || self.samples_per_axis > MAX_SAMPLES_PER_AXIS {
            return Err(Error::invalid_argument(
                "samples per axis",
                format!("{}: must be in 1..={MAX_SAMPLES_PER_AXIS}", self.samples_per_axis),
            ));
        }
        let p = &self.photometric;
        let finite_non_negative = [
            ("gain amplitude", p.gain_amplitude),
            ("bias amplitude", p.bias_amplitude),
            ("vignetting", p.vignetting),
            ("noise sigma", p.noise_sigma),
        ];
        for (name, v) in finite_non_negative {
            if !(v.is_finite() && v >= 0.0) {
                return Err(Error::invalid_argument(name, format!("{v}: must be finite and >= 0")));
            }
        }
        if p.gain_amplitude >= 1.0 || p.vignetting > 1.0 {
            return Err(Error::invalid_argument(
                "photometric",
                format!(
                    "gain amplitude {} must be < 1 and vignetting {} <= 1",
                    p.gain_amplitude, p.vignetting
                ),
            ));
        }
        Ok(())
    }

    /// The pinhole camera these settings describe.
    ///
    /// # Errors
    /// As [`SceneConfig::validate`].
    pub fn camera(&self) -> Result<PinholeCamera> {
        self.validate()?;
        if self.style == Style::Real {
            let mut rng =
                crate::util::rng::SplitMix64::new(crate::util::rng::mix64(self.seed ^ INTRINSICS_SALT));
            let (fx, fy, cx, cy) = sensor::random_intrinsics(&mut rng, self.width, self.height);
            return PinholeCamera::new(fx, fy, cx, cy, self.width, self.height);
        }
        let f = self.focal_ratio * self.width as f64;
        PinholeCamera::new(
            f,
            f,
            (self.width as f64 - 1.0) / 2.0,
            (self.height as f64 - 1.0) / 2.0,
            self.width,
            self.height,
        )
    }
}

/// The scene of the demo fixture `fixtures/synthetic/room_s1`: `densefeat synth --seed 1 --frames 40 --size 320x240` writes it byte for
/// byte (tests/synth.rs, `fixture_regenerates_byte_identical`).
pub fn demo_fixture_config() -> SceneConfig {
    SceneConfig {
        seed: 1,
        width: 320,
        height: 240,
        frames: 40,
        style: Style::Classic,
        ..SceneConfig::default()
    }
}
