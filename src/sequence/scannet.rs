//! ScanNet as its SensReader exports a scan (`reader.py --export_color_images --export_depth_images
//! --export_poses --export_intrinsics`; SPEC.md §4a):
//!
//! ```text
//! color/<i>.jpg                   colour of frame i (1296x968 in ScanNet v2)
//! depth/<i>.png                   16-bit millimetres, 0 = none, in the depth camera (640x480)
//! pose/<i>.txt                    4x4 camera-to-world, four lines of four numbers, metres; frames
//!                                 the tracker lost hold -inf or nan
//! intrinsic/intrinsic_color.txt   4x4, the colour camera: fx, fy on the diagonal, cx, cy in column 3
//! intrinsic/intrinsic_depth.txt   4x4, the depth camera
//! intrinsic/extrinsic_color.txt   4x4 sensor-to-camera (optional; identity in ScanNet)
//! intrinsic/extrinsic_depth.txt   4x4 (optional; identity in ScanNet)
//! ```
//! The sequence's camera is the colour camera. The depth camera shares its centre and axes (both
//! extrinsics identity, or equal): depth is registered to the colour camera by the change of
//! intrinsics alone, nearest neighbour ([`DepthSource::Png16Reprojected`]). Unequal extrinsics
//! would need a depth warp with occlusion, which is not done: the frames then carry no depth and a
//! warning says so. Frames whose pose is not finite are skipped with a note (ScanNet marks frames
//! the tracker lost that way).

use std::path::{Path, PathBuf};

use nalgebra::Matrix4;

use super::text::{list_files_with, read_matrix4, COLOUR_EXTENSIONS};
use super::{DepthSource, Format, FrameInfo, OpenOptions, Sequence, WARNING_NOTE};
use crate::error::{Error, Result};
use crate::geometry::{pose_from_matrix, Camera, PinholeCamera, Pose};
use crate::image::read_dimensions;

/// The colour folder.
pub const COLOUR_DIR: &str = "color";
/// The depth folder.
pub const DEPTH_DIR: &str = "depth";
/// The pose folder.
pub const POSE_DIR: &str = "pose";
/// The calibration folder.
pub const INTRINSIC_DIR: &str = "intrinsic";
/// ScanNet's depth unit: millimetres.
pub const METRES_PER_UNIT: f64 = 1e-3;
/// Largest entry difference for two extrinsics to count as equal.
const EXTRINSIC_TOLERANCE: f64 = 1e-6;

/// Whether `root` looks like a SensReader export: `color/`, `pose/` and the colour intrinsics.
pub(crate) fn looks_like(root: &Path) -> bool {
    root.join(COLOUR_DIR).is_dir()
        && root.join(POSE_DIR).is_dir()
        && root.join(INTRINSIC_DIR).join("intrinsic_color.txt").is_file()
}

pub(crate) fn read(root: &Path, opt: &OpenOptions) -> Result<Sequence> {
    let mut notes = Vec::new();
    if let Some(c) = &opt.camera {
        notes.push(format!(
            "camera option ({c}) ignored: {INTRINSIC_DIR}/intrinsic_color.txt gives the camera"
        ));
    }
    let calib = root.join(INTRINSIC_DIR);
    let colour = numbered(&root.join(COLOUR_DIR), &COLOUR_EXTENSIONS)?;
    if colour.is_empty() {
        return Err(Error::bad_sequence(root, format!("{COLOUR_DIR}/ holds no colour images")));
    }
    let (w, h) = read_dimensions(&colour[0].1)?;
    let k = intrinsics(&calib.join("intrinsic_color.txt"), w, h)?;
    let depth_dir = root.join(DEPTH_DIR);
    let depth_camera = match depth_dir.is_dir() {
        false => None,
        true => {
            let path = calib.join("intrinsic_depth.txt");
            if !path.is_file() {
                return Err(Error::bad_sequence(
                    root,
                    format!(
                        "{DEPTH_DIR}/ is present but {} is missing: the depth camera is unknown",
                        path.display()
                    ),
                ));
            }
            let first = numbered(&depth_dir, &["png"])?;
            match first.first() {
                None => None,
                Some((_, p)) => {
                    let (dw, dh) = read_dimensions(p)?;
                    Some(intrinsics(&path, dw, dh)?)
                }
            }
        }
    };
    // The depth camera when its depth maps register to the colour camera by intrinsics alone.
    let registered = match depth_camera {
        Some(d) => extrinsics_equal(&calib)?.then_some(d),
        None => None,
    };
    if depth_camera.is_some() && registered.is_none() {
        notes.push(format!(
            "{WARNING_NOTE}extrinsic_color.txt and extrinsic_depth.txt differ: the depth is not registered to the \
             colour camera by its intrinsics alone; frames carry no ground-truth depth, pass --depth-range"
        ));
    }
    let mut frames = Vec::with_capacity(colour.len());
    let mut lost = Vec::new();
    for (index, rgb) in colour {
        let name = index.to_string();
        let pose_path = root.join(POSE_DIR).join(format!("{name}.txt"));
        if !pose_path.is_file() {
            return Err(Error::bad_sequence(
                root,
                format!("{} has no pose file {}", rgb.display(), pose_path.display()),
            ));
        }
        let Some(pose) = read_pose(&pose_path)? else {
            lost.push(name);
            continue;
        };
        let depth = match registered {
            Some(d) => {
                let path = depth_dir.join(format!("{name}.png"));
                if !path.is_file() {
                    return Err(Error::bad_sequence(
                        root,
                        format!(
                            "{} has no depth map {} (every frame needs one when depth/ exists)",
                            rgb.display(),
                            path.display()
                        ),
                    ));
                }
                Some(DepthSource::Png16Reprojected {
                    path,
                    metres_per_unit: METRES_PER_UNIT,
                    depth_camera: d,
                    colour_camera: k,
                })
            }
            None => None,
        };
        frames.push(FrameInfo {
            name,
            timestamp: None,
            pose,
            rgb,
            depth,
            sparse_depth_range: None,
            camera: 0,
        });
    }
    if !lost.is_empty() {
        notes.push(format!(
            "{WARNING_NOTE}{} frame(s) skipped: their pose is not finite (the tracker lost them): {}",
            lost.len(),
            preview(&lost)
        ));
    }
    if frames.is_empty() {
        return Err(Error::bad_sequence(root, "no frame has a finite pose"));
    }
    if let Some(d) = registered {
        notes.push(format!(
            "depth: {}x{} depth camera (fx {:.2}, fy {:.2}, cx {:.2}, cy {:.2}) registered to the colour camera by its \
             intrinsics (nearest neighbour)",
            d.width, d.height, d.fx, d.fy, d.cx, d.cy
        ));
    }
    Sequence::from_parts(
        Format::ScanNet,
        root.to_path_buf(),
        Camera::pinhole(k),
        frames,
        None,
        notes,
        opt.undistort,
    )
}

/// The files of `dir` named `<i>.<ext>` with `i` a decimal frame number, in frame order.
fn numbered(dir: &Path, extensions: &[&str]) -> Result<Vec<(u64, PathBuf)>> {
    let mut out: Vec<(u64, PathBuf)> = list_files_with(dir, extensions)?
        .into_iter()
        .filter_map(|p| Some((p.file_stem()?.to_str()?.parse().ok()?, p)))
        .collect();
    out.sort();
    Ok(out)
}

/// Up to five names, then how many more.
fn preview(names: &[String]) -> String {
    let shown = names.iter().take(5).cloned().collect::<Vec<_>>().join(", ");
    match names.len() {
        n if n > 5 => format!("{shown} and {} more", n - 5),
        _ => shown,
    }
}

/// `pose/<i>.txt`: row-major `T_wc`; `None` when not finite.
fn read_pose(path: &Path) -> Result<Option<Pose>> {
    match read_matrix4(path)? {
        None => Ok(None),
        Some(m) => pose_from_matrix(&m).map(Some).map_err(|e| Error::parse(path, 1, e)),
    }
}

/// `intrinsic_*.txt`: `fx = m00`, `fy = m11`, `cx = m02`, `cy = m12` for a `w x h` image.
fn intrinsics(path: &Path, w: usize, h: usize) -> Result<PinholeCamera> {
    let m = read_matrix4(path)?.ok_or_else(|| Error::bad_file(path, "the intrinsics are not finite"))?;
    PinholeCamera::new(m[(0, 0)], m[(1, 1)], m[(0, 2)], m[(1, 2)], w, h)
        .map_err(|e| Error::bad_file(path, format!("not a camera for a {w}x{h} image: {e}")))
}

/// Whether the two extrinsics (each identity when its file is absent) are equal.
fn extrinsics_equal(calib: &Path) -> Result<bool> {
    let read = |name: &str| -> Result<Matrix4<f64>> {
        let path = calib.join(name);
        if !path.is_file() {
            return Ok(Matrix4::identity());
        }
        read_matrix4(&path)?.ok_or_else(|| Error::bad_file(&path, "the extrinsics are not finite"))
    };
    let (c, d) = (read("extrinsic_color.txt")?, read("extrinsic_depth.txt")?);
    Ok((c - d).abs().max() <= EXTRINSIC_TOLERANCE)
}
