//! A handheld-like camera path: smooth, bounded translation (two sinusoids per axis around a
//! centre, so any number of frames stays inside a known box) and a camera that looks at a slowly
//! wandering target point with a gentle roll, plus small per-frame jitter.
//!
//! Frame `i`'s pose depends only on the path and `i`, never on the sequence length.

use nalgebra::{Matrix3, Rotation3, Translation3, UnitQuaternion, Vector3};

use super::detmath::{cos, sin};
use crate::geometry::Pose;
use crate::util::rng::{hash_unit, SplitMix64};

/// Amplitudes (metres) of the slow and fast translation sinusoids along x, y (down), z.
const TRANSLATION_AMPLITUDE: [[f64; 2]; 3] = [[0.45, 0.05], [0.06, 0.02], [0.2, 0.04]];
/// Period ranges (frames) of the slow and fast sinusoids.
const SLOW_PERIOD: (f64, f64) = (170.0, 260.0);
const FAST_PERIOD: (f64, f64) = (35.0, 60.0);
/// Distance (metres) ahead of the camera centre of the look-at target.
const LOOK_DISTANCE: f64 = 3.5;
/// Pan (x) and tilt (y) amplitudes of the target, metres at [`LOOK_DISTANCE`].
const TARGET_AMPLITUDE: [f64; 2] = [0.7, 0.2];
/// Roll amplitude, radians.
const ROLL_AMPLITUDE: f64 = 0.035;
/// Per-frame uniform jitter half-widths: camera position (m), target (m), roll (rad).
const JITTER: [f64; 3] = [0.0015, 0.008, 0.002];

/// How a camera path moves (`densefeat synth --motion`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Motion {
    /// A hand-held walk: translation of up to half a metre, a gently panning view (the default).
    #[default]
    Handheld,
    /// Turning on the spot: a tenth of the hand-held translation, the view panning and tilting three
    /// times as far and four times as fast (rotation-dominant, like TUM fr1/rpy): weak parallax.
    Turn,
}

impl Motion {
    /// Factors of the translation amplitudes, the target's pan and tilt amplitudes, and the
    /// divisor of the target's periods (all exactly 1 for the hand-held path, so its poses keep
    /// their bits).
    fn factors(self) -> (f64, f64, f64) {
        match self {
            Motion::Handheld => (1.0, 1.0, 1.0),
            Motion::Turn => (0.1, 3.0, 4.0),
        }
    }
}

impl std::str::FromStr for Motion {
    type Err = crate::error::Error;
    fn from_str(s: &str) -> crate::error::Result<Self> {
        match s {
            "handheld" => Ok(Motion::Handheld),
            "turn" => Ok(Motion::Turn),
            _ => Err(crate::error::Error::invalid_argument(
                "--motion",
                format!("{s:?}: expected handheld or turn"),
            )),
        }
    }
}

impl std::fmt::Display for Motion {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Motion::Handheld => "handheld",
            Motion::Turn => "turn",
        })
    }
}

/// A seeded camera path.
#[derive(Clone, Debug, PartialEq)]
pub struct CameraPath {
    centre: Vector3<f64>,
    /// Per axis, per sinusoid: (period, phase).
    waves: [[(f64, f64); 2]; 3],
    /// Target pan, tilt and roll: (period, phase).
    view_waves: [(f64, f64); 3],
    /// Downward offset of the target, metres at [`LOOK_DISTANCE`] (a slight downward look).
    tilt: f64,
    key: u64,
    motion: Motion,
}

impl CameraPath {
    /// A path around `centre` with periods and phases drawn from `rng`.
    pub fn random(centre: Vector3<f64>, rng: &mut SplitMix64) -> Self {
        let tau = std::f64::consts::TAU;
        let mut wave = |p: (f64, f64)| (rng.range(p.0, p.1), rng.range(0.0, tau));
        let waves = [0; 3].map(|_| [wave(SLOW_PERIOD), wave(FAST_PERIOD)]);
        let view_waves = [wave(SLOW_PERIOD), wave(SLOW_PERIOD), wave(FAST_PERIOD)];
        Self {
            centre,
            waves,
            view_waves,
            tilt: rng.range(0.2, 0.5),
            key: rng.next_u64(),
            motion: Motion::Handheld,
        }
    }

    /// The same path moving as `motion` says (the random draws are those of [`CameraPath::random`]).
    pub fn with_motion(mut self, motion: Motion) -> Self {
        self.motion = motion;
        self
    }

    /// How the path moves.
    pub fn motion(&self) -> Motion {
        self.motion
    }

    /// Half-extent of the box around the path centre that every camera position stays in.
    pub fn half_extent() -> Vector3<f64> {
        let a = TRANSLATION_AMPLITUDE;
        Vector3::new(a[0][0] + a[0][1], a[1][0] + a[1][1], a[2][0] + a[2][1]).add_scalar(JITTER[0])
    }

    /// The path's centre.
    pub fn centre(&self) -> Vector3<f64> {
        self.centre
    }

    fn jitter(&self, i: usize, k: u64, half_width: f64) -> f64 {
        half_width * (2.0 * hash_unit(self.key, i as u64, k, 0) - 1.0)
    }

    /// Camera-to-world pose of frame `i`.
    pub fn pose(&self, i: usize) -> Pose {
        let (t, tau) = (i as f64, std::f64::consts::TAU);
        let wave = |(period, phase): (f64, f64)| sin(tau * t / period + phase);
        let (move_f, look_f, speed) = self.motion.factors();
        let look = |(period, phase): (f64, f64)| wave((period / speed, phase));
        let mut eye = self.centre;
        for k in 0..3 {
            let [slow, fast] = self.waves[k];
            eye[k] += TRANSLATION_AMPLITUDE[k][0] * move_f * wave(slow)
                + TRANSLATION_AMPLITUDE[k][1] * move_f * wave(fast);
            eye[k] += self.jitter(i, k as u64, JITTER[0]);
        }
        let target = Vector3::new(
            self.centre.x
                + TARGET_AMPLITUDE[0] * look_f * look(self.view_waves[0])
                + self.jitter(i, 3, JITTER[1]),
            eye.y
                + self.tilt
                + TARGET_AMPLITUDE[1] * look_f * look(self.view_waves[1])
                + self.jitter(i, 4, JITTER[1]),
            self.centre.z + LOOK_DISTANCE,
        );
        let roll = ROLL_AMPLITUDE * wave(self.view_waves[2]) + self.jitter(i, 5, JITTER[2]);
        look_at(&eye, &target, roll)
    }

    /// Camera-to-world pose at fractional frame time `t >= 0` (for motion blur): the sinusoids at
    /// `t`, the per-frame jitter linearly interpolated between frames `⌊t⌋` and `⌊t⌋ + 1`.
    pub fn pose_at(&self, t: f64) -> Pose {
        let t = t.max(0.0);
        let (i, f) = (t.floor() as usize, t - t.floor());
        let tau = std::f64::consts::TAU;
        let wave = |(period, phase): (f64, f64)| sin(tau * t / period + phase);
        let jitter = |k: u64, w: f64| (1.0 - f) * self.jitter(i, k, w) + f * self.jitter(i + 1, k, w);
        let (move_f, look_f, speed) = self.motion.factors();
        let look = |(period, phase): (f64, f64)| wave((period / speed, phase));
        let mut eye = self.centre;
        for k in 0..3 {
            let [slow, fast] = self.waves[k];
            eye[k] += TRANSLATION_AMPLITUDE[k][0] * move_f * wave(slow)
                + TRANSLATION_AMPLITUDE[k][1] * move_f * wave(fast);
            eye[k] += jitter(k as u64, JITTER[0]);
        }
        let target = Vector3::new(
            self.centre.x + TARGET_AMPLITUDE[0] * look_f * look(self.view_waves[0]) + jitter(3, JITTER[1]),
            eye.y
                + self.tilt
                + TARGET_AMPLITUDE[1] * look_f * look(self.view_waves[1])
                + jitter(4, JITTER[1]),
            self.centre.z + LOOK_DISTANCE,
        );
        let roll = ROLL_AMPLITUDE * wave(self.view_waves[2]) + jitter(5, JITTER[2]);
        look_at(&eye, &target, roll)
    }
}

/// The camera-to-world pose at `eye` whose optical axis (z) points at `target`, with image x to the
/// right and y down relative to world "down" `(0, 1, 0)`, rolled by `roll` radians about z.
/// Uses only `+ - * / sqrt` and [`sin`]/[`cos`].
pub fn look_at(eye: &Vector3<f64>, target: &Vector3<f64>, roll: f64) -> Pose {
    let down = Vector3::new(0.0, 1.0, 0.0);
    let f = (target - eye).normalize();
    let r = down.cross(&f).normalize();
    let d = f.cross(&r);
    let (c, s) = (cos(roll), sin(roll));
    let (r, d) = (r * c + d * s, d * c - r * s);
    let rot = Rotation3::from_matrix_unchecked(Matrix3::from_columns(&[r, d, f]));
    Pose::from_parts(Translation3::from(*eye), UnitQuaternion::from_rotation_matrix(&rot))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn look_at_points_the_optical_axis_at_the_target() {
        let eye = Vector3::new(0.3, -0.2, 0.1);
        let target = Vector3::new(1.0, 0.4, 4.0);
        let pose = look_at(&eye, &target, 0.02);
        let in_cam = pose.inverse_transform_point(&target.into());
        assert!(in_cam.x.abs() < 1e-12 && in_cam.y.abs() < 1e-12 && in_cam.z > 0.0, "{in_cam:?}");
        // No roll, level target: camera x stays horizontal.
        let level = look_at(&eye, &Vector3::new(0.3, -0.2, 3.0), 0.0);
        assert!((level.rotation * Vector3::x() - Vector3::x()).norm() < 1e-12);
    }

    /// The rotation (radians) between two poses.
    fn turned(a: &Pose, b: &Pose) -> f64 {
        a.rotation.angle_to(&b.rotation)
    }

    #[test]
    fn turning_motion_is_rotation_dominant_and_handheld_keeps_its_bits() {
        let base = CameraPath::random(Vector3::zeros(), &mut SplitMix64::new(9));
        let turn = base.clone().with_motion(Motion::Turn);
        let handheld = base.clone().with_motion(Motion::Handheld);
        assert_eq!(turn.motion(), Motion::Turn);
        let (mut move_h, mut move_t, mut rot_h, mut rot_t) = (0.0, 0.0, 0.0, 0.0);
        for i in 0..40 {
            // The default motion is the path `random` draws, bit for bit (the fixture depends on it).
            assert_eq!(handheld.pose(i), base.pose(i));
            assert_eq!(handheld.pose_at(i as f64 + 0.25), base.pose_at(i as f64 + 0.25));
            let (h0, h1, t0, t1) = (base.pose(i), base.pose(i + 1), turn.pose(i), turn.pose(i + 1));
            move_h += (h1.translation.vector - h0.translation.vector).norm();
            move_t += (t1.translation.vector - t0.translation.vector).norm();
            rot_h += turned(&h0, &h1);
            rot_t += turned(&t0, &t1);
        }
        // A tenth of the translation, except the per-frame jitter which both keep...
        assert!(move_t < 0.5 * move_h, "turn moved {move_t} m, handheld {move_h} m");
        // ... and several times the rotation.
        assert!(rot_t > 2.5 * rot_h, "turn rotated {rot_t} rad, handheld {rot_h} rad");
        assert!(turn.pose(0) != base.pose(0));
        // Inside the same box (the room generators keep clear of it).
        let h = CameraPath::half_extent();
        for i in 0..2000 {
            let p = turn.pose(i).translation.vector;
            assert!(p.x.abs() <= h.x && p.y.abs() <= h.y && p.z.abs() <= h.z, "frame {i}: {p:?}");
        }
        assert_eq!("turn".parse::<Motion>().unwrap(), Motion::Turn);
        assert_eq!("handheld".parse::<Motion>().unwrap(), Motion::Handheld);
        let err = "spin".parse::<Motion>().unwrap_err().to_string();
        assert!(err.contains("--motion") && err.contains("spin"), "{err}");
    }

    #[test]
    fn positions_stay_inside_the_advertised_box() {
        let path = CameraPath::random(Vector3::zeros(), &mut SplitMix64::new(9));
        let h = CameraPath::half_extent();
        for i in 0..2000 {
            let p = path.pose(i).translation.vector;
            assert!(p.x.abs() <= h.x && p.y.abs() <= h.y && p.z.abs() <= h.z, "frame {i}: {p:?}");
        }
    }
}
