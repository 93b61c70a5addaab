//! Opening a sequence folder: detect its format from the files present, then dispatch to a reader.
//!
//! | files present                                  | format                       |
//! |------------------------------------------------|------------------------------|
//! | `rgb.txt` or `associations.txt`                | [`Format::Tum`]              |
//! | `images/` and `poses.txt`                      | [`Format::DeepVideoMvs`]     |
//! | `transforms.json`                              | [`Format::Nerfstudio`]       |
//! | `metadata.json` and `rgb/` (or `rgbd/`)        | [`Format::Record3d`]         |
//! | `images/` and a COLMAP model in `sparse/0`, `sparse` or `.` | [`Format::Colmap`] |
//! | `color/`, `pose/` and `intrinsic/intrinsic_color.txt` | [`Format::ScanNet`]   |
//! | `frame-*.color.png`                            | [`Format::SevenScenes`]      |
//! | `imL.png` + `imR.png`, or `im0.png` + `im1.png` | [`Format::Stereo`]           |

use std::path::Path;

use super::{
    colmap, dvmvs, nerfstudio, record3d, scannet, sevenscenes, stereo, tum, CameraChoice, Format, Sequence,
};
use crate::error::{Error, Result};

/// Default largest rgb-depth timestamp difference for TUM association, seconds (TUM's own
/// `associate.py` uses 0.02 s).
pub const DEFAULT_MAX_TIME_GAP: f64 = 0.02;

/// Default largest time between the two ground-truth samples a TUM pose is interpolated from,
/// seconds. TUM's motion capture runs at 100 Hz, so 0.1 s spans ten samples: a longer hole means
/// the tracker lost the camera and interpolating across it would invent a pose.
pub const DEFAULT_MAX_POSE_GAP: f64 = 0.1;

/// Options for [`open_with`].
#[derive(Clone, Debug, PartialEq)]
pub struct OpenOptions {
    /// Camera to assume where the format stores none (TUM / ICL-NUIM). `None`: detect it from the
    /// folder name or the `# file:` header of `rgb.txt`, falling back to the ROS default with a
    /// warning note. Formats with their own calibration ignore it (with a note).
    pub camera: Option<CameraChoice>,
    /// Largest rgb-depth timestamp difference when associating TUM frames, seconds.
    pub max_time_gap: f64,
    /// Largest time between the two ground-truth samples a TUM pose is interpolated from, seconds.
    pub max_pose_gap: f64,
    /// Resample distorted raw images into the pinhole camera on load.
    pub undistort: bool,
    /// Metres per unit of the sequence's lengths (`--scale`): multiplies translations and depths
    /// ([`Sequence::rescale`]) and makes a non-metric sequence (COLMAP) metric.
    pub scale: Option<f64>,
}

impl Default for OpenOptions {
    fn default() -> Self {
        Self {
            camera: None,
            max_time_gap: DEFAULT_MAX_TIME_GAP,
            max_pose_gap: DEFAULT_MAX_POSE_GAP,
            undistort: true,
            scale: None,
        }
    }
}

/// Open the sequence in `path` with default options.
///
/// # Errors
/// As [`open_with`].
pub fn open(path: impl AsRef<Path>) -> Result<Sequence> {
    open_with(path, &OpenOptions::default())
}

/// The two views of a rectified stereo pair: `imL`/`imR` or `im0`/`im1`, each `.png`, `.jpg` or
/// `.jpeg`.
pub(crate) fn stereo_views(path: &Path) -> Option<(std::path::PathBuf, std::path::PathBuf)> {
    use super::text::find_colour_image;
    [("imL", "imR"), ("im0", "im1")]
        .iter()
        .find_map(|(l, r)| Some((find_colour_image(path, l)?, find_colour_image(path, r)?)))
}

/// Which format the folder holds, if any.
pub fn detect(path: &Path) -> Option<Format> {
    let has = |name: &str| path.join(name).is_file();
    if has("rgb.txt") || has("associations.txt") {
        Some(Format::Tum)
    } else if path.join("images").is_dir() && has("poses.txt") {
        Some(Format::DeepVideoMvs)
    } else if has(nerfstudio::FILE) {
        Some(Format::Nerfstudio)
    } else if record3d::looks_like(path) {
        Some(Format::Record3d)
    } else if scannet::looks_like(path) {
        Some(Format::ScanNet)
    } else if colmap::find_model(path).is_some() {
        Some(Format::Colmap)
    } else if sevenscenes::looks_like(path) {
        Some(Format::SevenScenes)
    } else if stereo_views(path).is_some() {
        Some(Format::Stereo)
    } else {
        None
    }
}

/// Open the sequence in `path`, detecting its format.
///
/// # Errors
/// [`Error::BadSequence`] if `path` is not a folder or matches no format (the message lists what
/// was looked for, and any subfolders that do hold sequences); otherwise the reader's errors, which
/// name the file and line.
pub fn open_with(path: impl AsRef<Path>, options: &OpenOptions) -> Result<Sequence> {
    let path = path.as_ref();
    for (name, v) in [("max time gap", options.max_time_gap), ("max pose gap", options.max_pose_gap)] {
        if !(v.is_finite() && v >= 0.0) {
            return Err(Error::invalid_argument(name, format!("{v} s: must be a finite number >= 0")));
        }
    }
    if !path.is_dir() {
        let what = if path.exists() { "is not a folder" } else { "does not exist" };
        return Err(Error::bad_sequence(path, format!("sequence folder {what}")));
    }
    let mut seq = match detect(path) {
        Some(Format::Tum) => tum::read(path, options),
        Some(Format::DeepVideoMvs) => dvmvs::read(path, options),
        Some(Format::Stereo) => stereo::read(path, options),
        Some(Format::Nerfstudio) => nerfstudio::read(path, options),
        Some(Format::Colmap) => colmap::read(path, options),
        Some(Format::SevenScenes) => sevenscenes::read(path, options),
        Some(Format::Record3d) => record3d::read(path, options),
        Some(Format::ScanNet) => scannet::read(path, options),
        _ => Err(no_format(path)),
    }?;
    if let Some(s) = options.scale {
        seq.rescale(s)?;
    }
    Ok(seq)
}

fn no_format(path: &Path) -> Error {
    let mut what = String::from(
        "not a sequence in any known format: looked for rgb.txt or associations.txt (TUM RGB-D / \
         ICL-NUIM), images/ with poses.txt and K.txt (DeepVideoMVS / 7-Scenes), transforms.json \
         (nerfstudio / instant-ngp), metadata.json with rgb/ (Record3D EXR + JPG export), color/ with pose/ and \
         intrinsic/intrinsic_color.txt (ScanNet SensReader export), images/ with cameras + images .bin/.txt in sparse/0, sparse or \
         the folder (COLMAP), frame-*.color.png (7-Scenes), imL.png + imR.png or im0.png + im1.png, \
         each also as .jpg/.jpeg (rectified stereo pair)",
    );
    let mut subs: Vec<String> = std::fs::read_dir(path)
        .map(|rd| {
            rd.filter_map(|e| e.ok().map(|e| e.path()))
                .filter(|p| p.is_dir() && detect(p).is_some())
                .filter_map(|p| p.file_name().map(|n| n.to_string_lossy().into_owned()))
                .collect()
        })
        .unwrap_or_default();
    if !subs.is_empty() {
        subs.sort();
        what.push_str(&format!("; these subfolders are sequences: {}", subs.join(", ")));
    }
    Error::bad_sequence(path, what)
}
