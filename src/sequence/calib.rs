//! Camera choices for readers whose files carry no intrinsics (TUM RGB-D, ICL-NUIM): the published
//! calibrations, and a tiny camera file format.
//!
//! # Camera file format
//! ```text
//! # comments and blank lines are ignored
//! fx fy cx cy [k1 k2 p1 p2 [k3]]     first data line: 4, 8 or 9 numbers (radial-tangential distortion)
//! width height                       optional second data line: image size in pixels
//! ```
//! Without the size line the size is read from the first colour image's header. Values may be
//! separated by spaces or commas.

use std::path::{Path, PathBuf};
use std::str::FromStr;

use crate::error::{Error, Result};
use crate::geometry::{Camera, PinholeCamera, RadTan};
use crate::sequence::text::data_lines;

/// Which camera to assume for a sequence format that does not store one.
#[derive(Clone, Debug, PartialEq)]
pub enum CameraChoice {
    /// TUM freiburg1 (Kinect v1 RGB, with distortion).
    Fr1,
    /// TUM freiburg2 (with distortion).
    Fr2,
    /// TUM freiburg3 (already undistorted).
    Fr3,
    /// ICL-NUIM synthetic camera (`fy = -480`).
    Icl,
    /// The ROS default 525 / 525 / 319.5 / 239.5.
    Ros,
    /// A camera file (format in the [module docs](self)).
    File(PathBuf),
}

impl FromStr for CameraChoice {
    type Err = Error;

    /// `fr1`, `fr2`, `fr3`, `icl`, `ros` (any case), else a file path.
    fn from_str(s: &str) -> Result<Self> {
        Ok(match s.to_ascii_lowercase().as_str() {
            "fr1" | "freiburg1" => CameraChoice::Fr1,
            "fr2" | "freiburg2" => CameraChoice::Fr2,
            "fr3" | "freiburg3" => CameraChoice::Fr3,
            "icl" | "icl-nuim" => CameraChoice::Icl,
            "ros" => CameraChoice::Ros,
            "" => return Err(Error::invalid_argument("camera", "empty camera choice")),
            _ => CameraChoice::File(PathBuf::from(s)),
        })
    }
}

impl std::fmt::Display for CameraChoice {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            CameraChoice::Fr1 => f.write_str("TUM freiburg1 calibration"),
            CameraChoice::Fr2 => f.write_str("TUM freiburg2 calibration"),
            CameraChoice::Fr3 => f.write_str("TUM freiburg3 calibration"),
            CameraChoice::Icl => f.write_str("ICL-NUIM camera"),
            CameraChoice::Ros => f.write_str("ROS default camera"),
            CameraChoice::File(p) => write!(f, "camera file {}", p.display()),
        }
    }
}

/// Intrinsics and distortion of a preset: `(fx, fy, cx, cy, distortion)`.
type Preset = (f64, f64, f64, f64, Option<[f64; 5]>);

fn preset(choice: &CameraChoice) -> Option<Preset> {
    Some(match choice {
        CameraChoice::Fr1 => (517.3, 516.5, 318.6, 255.3, Some([0.2624, -0.9531, -0.0054, 0.0026, 1.1633])),
        CameraChoice::Fr2 => (520.9, 521.0, 325.1, 249.7, Some([0.2312, -0.7849, -0.0033, -0.0001, 0.9172])),
        CameraChoice::Fr3 => (535.4, 539.2, 320.1, 247.6, None),
        CameraChoice::Icl => (481.20, -480.00, 319.5, 239.5, None),
        CameraChoice::Ros => (525.0, 525.0, 319.5, 239.5, None),
        CameraChoice::File(_) => return None,
    })
}

fn radtan(d: [f64; 5]) -> RadTan {
    RadTan { k1: d[0], k2: d[1], p1: d[2], p2: d[3], k3: d[4] }
}

/// The camera for `choice` with images of `size` (`width, height`); a camera file's own size line,
/// when present, wins over `size`.
///
/// # Errors
/// Camera-file errors name the file and line; [`Error::InvalidArgument`] for bad intrinsics.
pub fn resolve_camera(choice: &CameraChoice, size: (usize, usize)) -> Result<Camera> {
    if let CameraChoice::File(path) = choice {
        return read_camera_file(path, size);
    }
    let (fx, fy, cx, cy, d) = preset(choice).ok_or_else(|| Error::invalid_argument("camera", "no preset"))?;
    let pinhole = PinholeCamera::new(fx, fy, cx, cy, size.0, size.1)?;
    Ok(Camera { pinhole, distortion: d.map(radtan) })
}

/// Read a camera file (format in the [module docs](self)); `size` is used when it has no size line.
///
/// # Errors
/// [`Error::Io`] if unreadable, [`Error::Parse`] naming the line for a malformed one.
pub fn read_camera_file(path: &Path, size: (usize, usize)) -> Result<Camera> {
    let lines = data_lines(path)?;
    let first = lines.first().ok_or_else(|| Error::bad_file(path, "camera file has no data line"))?;
    let n = first.fields.len();
    if ![4, 8, 9].contains(&n) {
        return Err(Error::parse(
            path,
            first.number,
            format!("expected `fx fy cx cy [k1 k2 p1 p2 [k3]]` (4, 8 or 9 numbers), found {n}"),
        ));
    }
    let values: Vec<f64> = (0..n).map(|i| first.float(path, i, "camera parameter")).collect::<Result<_>>()?;
    let size = match lines.get(1) {
        None => size,
        Some(l) => {
            let parse = |i: usize| -> Result<usize> {
                let s = l.fields.get(i).map(String::as_str).unwrap_or("");
                s.parse::<usize>().ok().filter(|&v| v > 0).ok_or_else(|| {
                    Error::parse(
                        path,
                        l.number,
                        format!("image size field {} is {s:?}, not a positive integer", i + 1),
                    )
                })
            };
            if l.fields.len() != 2 {
                return Err(Error::parse(path, l.number, "expected `width height` on the second line"));
            }
            (parse(0)?, parse(1)?)
        }
    };
    let pinhole = PinholeCamera::new(values[0], values[1], values[2], values[3], size.0, size.1)
        .map_err(|e| Error::parse(path, first.number, e.to_string()))?;
    let distortion =
        (n > 4).then(|| radtan([values[4], values[5], values[6], values[7], *values.get(8).unwrap_or(&0.0)]));
    Ok(Camera { pinhole, distortion })
}

/// Guess the TUM camera from text naming the recording (`freiburg1` ... `freiburg3`, or `icl`).
pub(crate) fn guess_from_text(text: &str) -> Option<CameraChoice> {
    let t = text.to_ascii_lowercase();
    if t.contains("freiburg1") {
        Some(CameraChoice::Fr1)
    } else if t.contains("freiburg2") {
        Some(CameraChoice::Fr2)
    } else if t.contains("freiburg3") {
        Some(CameraChoice::Fr3)
    } else if t.contains("icl") || t.contains("living_room") || t.contains("livingroom") {
        Some(CameraChoice::Icl)
    } else {
        None
    }
}
