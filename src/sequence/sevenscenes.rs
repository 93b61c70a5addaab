//! 7-Scenes as Microsoft distributes it, one `seq-XX` folder (SPEC.md §4a):
//!
//! ```text
//! frame-000000.color.png   640x480 colour
//! frame-000000.depth.png   640x480 16-bit millimetres (65535 = invalid), from the depth camera
//! frame-000000.pose.txt    4x4 camera-to-world, four lines of four numbers, metres
//! ```
//! The release gives no colour calibration and no colour-depth extrinsics: "the RGB and depth camera
//! have not been calibrated". The colour camera is taken as `f = 525, (cx, cy) = (320, 240)`; the
//! depth maps (depth camera `f = 585`, `(320, 240)`) are **not** registered to it, so frames carry no
//! ground-truth depth and a warning says so. Registering with the intrinsics alone (a zero baseline)
//! would misplace depth by `f b / z` pixels, about 13 px at 1 m for the Kinect's 2.5 cm baseline.

use std::path::{Path, PathBuf};

use super::text::{list_files_with, read_matrix4};
use super::{Format, FrameInfo, OpenOptions, Sequence, WARNING_NOTE};
use crate::error::{Error, Result};
use crate::geometry::{pose_from_matrix, Camera, PinholeCamera, Pose};
use crate::image::read_dimensions;

/// Colour focal length assumed, pixels (the value commonly used with 7-Scenes).
pub const COLOUR_FOCAL: f64 = 525.0;
/// Principal point of both cameras as published, pixels.
pub const PRINCIPAL_POINT: (f64, f64) = (320.0, 240.0);
/// The depth camera's published focal length, pixels (KinectFusion's default).
pub const DEPTH_FOCAL: f64 = 585.0;
/// Suffix of the colour images.
pub const COLOUR_SUFFIX: &str = ".color.png";

/// Whether `root` holds `frame-*.color.png` files.
pub(crate) fn looks_like(root: &Path) -> bool {
    std::fs::read_dir(root).is_ok_and(|rd| {
        rd.filter_map(|e| e.ok()).any(|e| {
            let n = e.file_name().to_string_lossy().into_owned();
            n.starts_with("frame-") && n.ends_with(COLOUR_SUFFIX)
        })
    })
}

pub(crate) fn read(root: &Path, opt: &OpenOptions) -> Result<Sequence> {
    let mut notes = Vec::new();
    if let Some(c) = &opt.camera {
        notes.push(format!("camera option ({c}) ignored: 7-Scenes uses the published nominal camera"));
    }
    let colour: Vec<PathBuf> = list_files_with(root, &["png"])?
        .into_iter()
        .filter(|p| p.file_name().is_some_and(|n| n.to_string_lossy().ends_with(COLOUR_SUFFIX)))
        .collect();
    let mut frames = Vec::with_capacity(colour.len());
    let mut depth_files = 0;
    for rgb in colour {
        let file = rgb.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
        let name = file.trim_end_matches(COLOUR_SUFFIX).to_string();
        let pose_path = root.join(format!("{name}.pose.txt"));
        if !pose_path.is_file() {
            return Err(Error::bad_sequence(
                root,
                format!("{} has no pose file {}", rgb.display(), pose_path.display()),
            ));
        }
        depth_files += usize::from(root.join(format!("{name}.depth.png")).is_file());
        let pose = read_pose(&pose_path)?;
        frames.push(FrameInfo {
            name,
            timestamp: None,
            pose,
            rgb,
            depth: None,
            sparse_depth_range: None,
            camera: 0,
        });
    }
    if frames.is_empty() {
        return Err(Error::bad_sequence(root, "no frame-*.color.png files"));
    }
    let (w, h) = read_dimensions(&frames[0].rgb)?;
    let k = PinholeCamera::new(COLOUR_FOCAL, COLOUR_FOCAL, PRINCIPAL_POINT.0, PRINCIPAL_POINT.1, w, h)?;
    notes.push(format!(
        "camera: 7-Scenes nominal colour camera f {COLOUR_FOCAL}, principal point ({}, {})",
        PRINCIPAL_POINT.0, PRINCIPAL_POINT.1
    ));
    notes.push(format!(
        "{WARNING_NOTE}7-Scenes depth ({depth_files} depth PNGs, depth camera f {DEPTH_FOCAL}) is not registered to \
         the colour camera (no published extrinsics): frames carry no ground-truth depth; pass --depth-range"
    ));
    Sequence::from_parts(
        Format::SevenScenes,
        root.to_path_buf(),
        Camera::pinhole(k),
        frames,
        None,
        notes,
        opt.undistort,
    )
}

/// `frame-XXXXXX.pose.txt`: four lines of four numbers, row-major `T_wc`, every entry finite.
fn read_pose(path: &Path) -> Result<Pose> {
    let m = read_matrix4(path)?
        .ok_or_else(|| Error::bad_file(path, "the pose matrix has an entry that is not finite"))?;
    pose_from_matrix(&m).map_err(|e| Error::parse(path, 1, e))
}
