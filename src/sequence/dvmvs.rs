//! DeepVideoMVS / 7-Scenes reader (the layout [`super::DvmvsWriter`] writes):
//!
//! ```text
//! images/*.png   8-bit colour (PNG, or JPEG as *.jpg / *.jpeg), frames in file-name order
//! depth/*.png    optional; same stems as images/ (always PNG), 16-bit millimetres, 0 and 65535 = no depth
//! poses.txt      one line per frame: 16 numbers, row-major 4x4 camera-to-world, metres
//! K.txt          3x3 intrinsics of the (already undistorted) images, three lines
//! ```

use std::path::Path;

use nalgebra::Matrix4;

use super::text::{check_depth_png16, data_lines, list_colour_images, list_pngs, stem, Line};
use super::{DepthSource, Format, FrameInfo, OpenOptions, Sequence};
use crate::error::{Error, Result};
use crate::geometry::{pose_from_matrix, Camera, PinholeCamera, Pose};
use crate::image::read_dimensions;

/// Depth PNGs store millimetres.
const METRES_PER_MM: f64 = 1e-3;
/// 7-Scenes marks missing depth with 65535 as well as 0.
const INVALID_DEPTH: u16 = u16::MAX;
/// Largest `|K[1][0]|`, `|K[2][0]|`, `|K[2][1]|`, `|K[2][2] - 1|` accepted in `K.txt`.
const K_TOLERANCE: f64 = 1e-6;

pub(crate) fn read(root: &Path, opt: &OpenOptions) -> Result<Sequence> {
    let mut notes = Vec::new();
    if let Some(c) = &opt.camera {
        notes.push(format!("camera option ({c}) ignored: this format's K.txt gives the camera"));
    }
    let images_dir = root.join("images");
    let images = list_colour_images(&images_dir)?;
    if images.is_empty() {
        return Err(Error::bad_sequence(&images_dir, "no colour images (*.png, *.jpg, *.jpeg)"));
    }
    let poses_path = root.join("poses.txt");
    let poses = read_poses(&poses_path)?;
    if poses.len() != images.len() {
        return Err(Error::bad_sequence(
            root,
            format!(
                "{} has {} poses but {} has {} images; there must be one pose per image",
                poses_path.display(),
                poses.len(),
                images_dir.display(),
                images.len()
            ),
        ));
    }
    let depth_dir = root.join("depth");
    let has_depth = depth_dir.is_dir();
    if has_depth {
        let depths = list_pngs(&depth_dir)?;
        if depths.len() != images.len() {
            return Err(Error::bad_sequence(
                root,
                format!(
                    "{} has {} depth maps but {} has {} images",
                    depth_dir.display(),
                    depths.len(),
                    images_dir.display(),
                    images.len()
                ),
            ));
        }
    } else {
        notes.push(format!("{}no depth/ folder: frames have no ground-truth depth", super::WARNING_NOTE));
    }
    let mut frames = Vec::with_capacity(images.len());
    for (rgb, pose) in images.into_iter().zip(poses) {
        let depth = if has_depth {
            // The depth map has the colour image's stem and is always a 16-bit PNG.
            let path = depth_dir.join(format!("{}.png", stem(&rgb)));
            if !path.is_file() {
                return Err(Error::bad_sequence(
                    root,
                    format!("{} has no depth map {}", rgb.display(), path.display()),
                ));
            }
            check_depth_png16(&path)?;
            Some(DepthSource::Png16 { path, metres_per_unit: METRES_PER_MM, invalid: Some(INVALID_DEPTH) })
        } else {
            None
        };
        frames.push(FrameInfo {
            name: stem(&rgb),
            timestamp: None,
            pose,
            rgb,
            depth,
            sparse_depth_range: None,
            camera: 0,
        });
    }
    let (w, h) = read_dimensions(&frames[0].rgb)?;
    let camera = read_k(&root.join("K.txt"), w, h)?;
    Sequence::from_parts(
        Format::DeepVideoMvs,
        root.to_path_buf(),
        Camera::pinhole(camera),
        frames,
        None,
        notes,
        opt.undistort,
    )
}

/// `poses.txt`: 16 numbers per line.
fn read_poses(path: &Path) -> Result<Vec<Pose>> {
    let lines = data_lines(path)?;
    let mut out = Vec::with_capacity(lines.len());
    for l in &lines {
        if l.fields.len() != 16 {
            return Err(Error::parse(
                path,
                l.number,
                format!("expected 16 numbers (a row-major 4x4 pose), found {}", l.fields.len()),
            ));
        }
        let v: [f64; 16] = l.floats(path, 0, "pose matrix entry")?;
        let m = Matrix4::from_row_slice(&v);
        out.push(pose_from_matrix(&m).map_err(|e| Error::parse(path, l.number, e))?);
    }
    Ok(out)
}

/// `K.txt`: three lines of three numbers, `[fx 0 cx; 0 fy cy; 0 0 1]`.
fn read_k(path: &Path, width: usize, height: usize) -> Result<PinholeCamera> {
    let lines = data_lines(path)?;
    if lines.len() != 3 {
        return Err(Error::bad_file(
            path,
            format!("expected 3 lines of 3 numbers (a 3x3 K), found {} lines", lines.len()),
        ));
    }
    let row = |l: &Line| -> Result<[f64; 3]> {
        if l.fields.len() != 3 {
            return Err(Error::parse(
                path,
                l.number,
                format!("expected 3 numbers, found {}", l.fields.len()),
            ));
        }
        l.floats(path, 0, "K entry")
    };
    let (r0, r1, r2) = (row(&lines[0])?, row(&lines[1])?, row(&lines[2])?);
    if r1[0].abs() > K_TOLERANCE {
        return Err(Error::parse(path, lines[1].number, format!("K[1][0] is {}, expected 0", r1[0])));
    }
    if r2[0].abs() > K_TOLERANCE || r2[1].abs() > K_TOLERANCE || (r2[2] - 1.0).abs() > K_TOLERANCE {
        return Err(Error::parse(path, lines[2].number, format!("last row is {r2:?}, expected [0, 0, 1]")));
    }
    if r0[1].abs() > K_TOLERANCE {
        return Err(Error::parse(
            path,
            lines[0].number,
            format!("skew K[0][1] = {} is not supported", r0[1]),
        ));
    }
    PinholeCamera::new(r0[0], r1[1], r0[2], r1[2], width, height)
        .map_err(|e| Error::parse(path, lines[0].number, e.to_string()))
}
