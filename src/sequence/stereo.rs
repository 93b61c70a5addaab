//! A rectified stereo pair read as a two-frame sequence (Middlebury 2001/2003/2014, ETH3D two-view).
//!
//! Frame 0 is the left view at the identity pose; frame 1 the right view at `T_wc` = translation
//! `(+b, 0, 0)`, so a point at depth `z` seen at `x_l` in the left view appears at
//! `x_r = x_l - f b / z` (disparity `d = f b / z`).
//!
//! ```text
//! imL.png imR.png | im0.png im1.png     the views (each may also be .jpg / .jpeg)
//! disp0GT.pfm | disp0.pfm               left ground-truth disparity, PFM (ETH3D / Middlebury 2014)
//! groundtruth.png | disp0.png           left ground truth, scaled PNG: d = value / scale, with the
//!                                       scale on line 1 of info.txt (Middlebury 2001/2003)
//! disp1.pfm | disp6.png                 right ground truth (same encodings)
//! calib.txt                             cam0=[f 0 cx; 0 f cy; 0 0 1], doffs=, baseline= (mm), ...
//! ```
//! `baseline` is in millimetres in both Middlebury 2014 and ETH3D `calib.txt` files (ETH3D reuses
//! Middlebury's format; e.g. ETH3D `storage_room_2_2l` has `baseline=59.9696` where its COLMAP
//! `images.txt` camera centres are 0.05997 m apart). Without `calib.txt` the pair is uncalibrated:
//! a nominal camera with `f` = image width, centred principal point, baseline 1, so depths are in
//! baseline units and only disparity-space evaluation is meaningful.

use std::path::{Path, PathBuf};

use nalgebra::{Isometry3, Translation3, UnitQuaternion};

use super::text::{data_lines, read_text};
use super::{
    DepthSource, DisparityEncoding, Format, FrameInfo, OpenOptions, Sequence, StereoInfo, WARNING_NOTE,
};
use crate::error::{Error, Result};
use crate::geometry::{Camera, PinholeCamera, Pose};
use crate::image::read_dimensions;

/// Millimetres per metre (`calib.txt` baselines are in mm).
const MM_PER_M: f64 = 1000.0;

/// Parsed `calib.txt`.
struct Calib {
    f: f64,
    cx: f64,
    cy: f64,
    doffs: f64,
    baseline_m: f64,
}

fn first_existing(root: &Path, names: &[&str]) -> Option<PathBuf> {
    names.iter().map(|n| root.join(n)).find(|p| p.is_file())
}

fn is_pfm(p: &Path) -> bool {
    p.extension().is_some_and(|e| e.eq_ignore_ascii_case("pfm"))
}

pub(crate) fn read(root: &Path, opt: &OpenOptions) -> Result<Sequence> {
    let mut notes = Vec::new();
    if let Some(c) = &opt.camera {
        notes.push(format!("camera option ({c}) ignored: a stereo pair's camera comes from calib.txt"));
    }
    let Some((left, right)) = super::detect::stereo_views(root) else {
        return Err(Error::bad_sequence(root, "no imL/imR or im0/im1 image pair (.png, .jpg, .jpeg)"));
    };
    let (w, h) = read_dimensions(&left)?;
    let calib_path = root.join("calib.txt");
    let calib = if calib_path.is_file() { Some(read_calib(&calib_path)?) } else { None };
    let (camera, baseline, doffs, calibrated) = match &calib {
        Some(c) => (PinholeCamera::new(c.f, c.f, c.cx, c.cy, w, h)?, c.baseline_m, c.doffs, true),
        None => {
            notes.push(format!(
                "{WARNING_NOTE}uncalibrated stereo (no calib.txt): nominal f = {w} px (image width), baseline 1; \
                 depths are in baseline units, only disparity-space evaluation is meaningful"
            ));
            (
                PinholeCamera::new(w as f64, w as f64, (w as f64 - 1.0) / 2.0, (h as f64 - 1.0) / 2.0, w, h)?,
                1.0,
                0.0,
                false,
            )
        }
    };
    if doffs != 0.0 {
        notes.push(format!(
            "the right camera's principal point is {doffs} px right of the left one (doffs); both frames share \
             the left camera, so pose-based warps between the views are off by doffs px: use disparity"
        ));
    }
    let left_gt = first_existing(root, &["disp0GT.pfm", "disp0.pfm", "groundtruth.png", "disp0.png"]);
    let right_gt = first_existing(root, &["disp1GT.pfm", "disp1.pfm", "disp6.png"]);
    let mut scale = None;
    let mut source = |path: Option<PathBuf>| -> Result<Option<DepthSource>> {
        let Some(path) = path else { return Ok(None) };
        let encoding = if is_pfm(&path) {
            DisparityEncoding::Pfm
        } else {
            if scale.is_none() {
                scale = Some(read_scale(root, &path)?);
            }
            DisparityEncoding::ScaledPng { scale: scale.unwrap_or(1.0) }
        };
        Ok(Some(DepthSource::Disparity { path, encoding, focal_baseline: camera.fx * baseline, doffs }))
    };
    let (left_depth, right_depth) = (source(left_gt)?, source(right_gt)?);
    if left_depth.is_none() {
        notes.push(format!("{WARNING_NOTE}no ground-truth disparity for the left view"));
    }
    let right_pose: Pose =
        Isometry3::from_parts(Translation3::new(baseline, 0.0, 0.0), UnitQuaternion::identity());
    let frames = vec![
        FrameInfo {
            name: "left".into(),
            timestamp: None,
            pose: Pose::identity(),
            rgb: left,
            depth: left_depth,
            sparse_depth_range: None,
            camera: 0,
        },
        FrameInfo {
            name: "right".into(),
            timestamp: None,
            pose: right_pose,
            rgb: right,
            depth: right_depth,
            sparse_depth_range: None,
            camera: 0,
        },
    ];
    let stereo = StereoInfo { baseline, calibrated, doffs };
    Sequence::from_parts(
        Format::Stereo,
        root.to_path_buf(),
        Camera::pinhole(camera),
        frames,
        Some(stereo),
        notes,
        opt.undistort,
    )
}

/// The disparity scale of a scaled PNG: the first number on line 1 of `info.txt`.
fn read_scale(root: &Path, png: &Path) -> Result<f64> {
    let info = root.join("info.txt");
    if !info.is_file() {
        return Err(Error::bad_sequence(
            root,
            format!(
                "{} is a scaled disparity PNG, but {} (whose first line gives the scale) is missing",
                png.display(),
                info.display()
            ),
        ));
    }
    let lines = data_lines(&info)?;
    let first =
        lines.first().ok_or_else(|| Error::bad_file(&info, "empty: line 1 must give the disparity scale"))?;
    let s = first.float(&info, 0, "disparity scale")?;
    if s <= 0.0 {
        return Err(Error::parse(&info, first.number, format!("disparity scale {s} must be positive")));
    }
    Ok(s)
}

/// Middlebury 2014 / ETH3D `calib.txt`: `key=value` lines.
fn read_calib(path: &Path) -> Result<Calib> {
    let text = read_text(path)?;
    let (mut cam0, mut doffs, mut baseline) = (None, 0.0, None);
    for (i, raw) in text.lines().enumerate() {
        let line = i + 1;
        let Some((key, value)) = raw.split_once('=') else {
            if raw.trim().is_empty() {
                continue;
            }
            return Err(Error::parse(path, line, format!("expected `key=value`, found {:?}", raw.trim())));
        };
        let num = |v: &str| -> Result<f64> {
            v.trim().parse::<f64>().ok().filter(|x| x.is_finite()).ok_or_else(|| {
                Error::parse(path, line, format!("{} is {:?}, not a finite number", key.trim(), v.trim()))
            })
        };
        match key.trim() {
            "cam0" => {
                let v: Vec<f64> =
                    value.replace(['[', ']', ';'], " ").split_whitespace().map(num).collect::<Result<_>>()?;
                if v.len() != 9 {
                    return Err(Error::parse(
                        path,
                        line,
                        format!("cam0 must be a 3x3 matrix, found {} numbers", v.len()),
                    ));
                }
                cam0 = Some((v[0], v[2], v[5], line));
            }
            "doffs" => doffs = num(value)?,
            "baseline" => baseline = Some((num(value)?, line)),
            _ => {}
        }
    }
    let (f, cx, cy, cam_line) =
        cam0.ok_or_else(|| Error::bad_file(path, "no cam0=[f 0 cx; 0 f cy; 0 0 1] line"))?;
    let (b, b_line) = baseline.ok_or_else(|| Error::bad_file(path, "no baseline= line (millimetres)"))?;
    if f <= 0.0 {
        return Err(Error::parse(path, cam_line, format!("focal length {f} must be positive")));
    }
    if b <= 0.0 {
        return Err(Error::parse(path, b_line, format!("baseline {b} mm must be positive")));
    }
    Ok(Calib { f, cx, cy, doffs, baseline_m: b / MM_PER_M })
}
