//! nerfstudio / instant-ngp `transforms.json` (SPEC.md §4a):
//!
//! ```text
//! transforms.json   intrinsics shared at the top level and/or per frame: fl_x, fl_y (or
//!                   camera_angle_x / camera_angle_y, radians), cx, cy, w, h, k1 k2 p1 p2 (k3);
//!                   frames[]: file_path, transform_matrix (4x4 camera-to-world, OpenGL camera axes:
//!                   x right, y up, z back), optional depth_file_path (16-bit PNG)
//! ```
//! Paths are relative to the folder of `transforms.json`; a `file_path` without an extension gets
//! `.png`, `.jpg` or `.jpeg`, the first that exists. Frames are read in `file_path` order.

use std::path::{Path, PathBuf};

use nalgebra::Matrix4;
use serde_json::{Map, Value};

use super::text::{check_depth_png16, find_colour_image, read_text, stem};
use super::{DepthSource, Format, FrameInfo, OpenOptions, Sequence, WARNING_NOTE};
use crate::error::{Error, Result};
use crate::geometry::{pose_from_matrix, Camera, PinholeCamera, RadTan};
use crate::image::read_dimensions;

/// The file this reader looks for.
pub const FILE: &str = "transforms.json";
/// Metres per stored depth unit unless `depth_unit_scale_factor` says otherwise (nerfstudio's
/// default: millimetre PNGs).
pub const DEFAULT_DEPTH_UNIT: f64 = 1e-3;
/// The warning of a `transforms.json` without depth maps.
pub const NO_SCALE_WARNING: &str = "transforms.json without depth maps: the pose scale is unknown \
     (COLMAP-derived poses have none). Pass --scale METRES_PER_UNIT to map/reconstruct/eval \
     (--scale 1 if the poses are metric, as ARKit exports are)";

/// The intrinsics keys; per-frame values override the top level's.
const INTRINSIC_KEYS: [&str; 13] =
    ["fl_x", "fl_y", "camera_angle_x", "camera_angle_y", "cx", "cy", "w", "h", "k1", "k2", "k3", "p1", "p2"];

pub(crate) fn read(root: &Path, opt: &OpenOptions) -> Result<Sequence> {
    let path = root.join(FILE);
    let text = read_text(&path)?;
    let json: Value = serde_json::from_str(&text)
        .map_err(|e| Error::parse(&path, e.line(), format!("not valid JSON: {e}")))?;
    let top = json.as_object().ok_or_else(|| Error::bad_file(&path, "top level is not a JSON object"))?;
    let bad = |what: String| Error::bad_file(&path, what);
    if let Some(m) = top.get("camera_model").and_then(Value::as_str) {
        if m != "OPENCV" && m != "PINHOLE" {
            return Err(bad(format!("camera_model {m:?} is not read; supported: OPENCV, PINHOLE")));
        }
    }
    let frames_json =
        top.get("frames").and_then(Value::as_array).ok_or_else(|| bad("no \"frames\" array".into()))?;
    if frames_json.is_empty() {
        return Err(bad("\"frames\" is empty".into()));
    }
    let depth_unit = match top.get("depth_unit_scale_factor") {
        None => DEFAULT_DEPTH_UNIT,
        Some(v) => v
            .as_f64()
            .filter(|v| v.is_finite() && *v > 0.0)
            .ok_or_else(|| bad(format!("depth_unit_scale_factor is {v}, expected a number > 0")))?,
    };
    let mut notes = Vec::new();
    if let Some(c) = &opt.camera {
        notes.push(format!("camera option ({c}) ignored: transforms.json gives the camera"));
    }
    let mut frames = Vec::with_capacity(frames_json.len());
    // Distinct cameras in order of first use; a frame's keys may give it its own (SPEC.md §4a).
    let mut cameras: Vec<Camera> = Vec::new();
    for (i, f) in frames_json.iter().enumerate() {
        let at = |what: String| bad(format!("frames[{i}]: {what}"));
        let f = f.as_object().ok_or_else(|| at("not a JSON object".into()))?;
        let rel =
            f.get("file_path").and_then(Value::as_str).ok_or_else(|| at("no \"file_path\" string".into()))?;
        let rgb = colour_file(root, rel).ok_or_else(|| {
            at(format!(
                "file_path {rel:?}: {} does not exist (also tried .png, .jpg, .jpeg)",
                root.join(rel).display()
            ))
        })?;
        let m = matrix(f.get("transform_matrix")).map_err(|e| at(format!("transform_matrix: {e}")))?;
        // OpenGL camera axes (y up, z back) to ours (y down, z forward): flip the y and z columns.
        let gl_to_cv = Matrix4::from_diagonal(&nalgebra::Vector4::new(1.0, -1.0, -1.0, 1.0));
        let pose = pose_from_matrix(&(m * gl_to_cv)).map_err(|e| at(format!("transform_matrix: {e}")))?;
        let depth = match f.get("depth_file_path") {
            None => None,
            Some(v) => {
                let d = v.as_str().ok_or_else(|| at("depth_file_path is not a string".into()))?;
                let p = root.join(d);
                if !p.is_file() {
                    return Err(at(format!("depth_file_path {d:?}: {} does not exist", p.display())));
                }
                check_depth_png16(&p)?;
                Some(DepthSource::Png16 { path: p, metres_per_unit: depth_unit, invalid: None })
            }
        };
        let cam = frame_camera(top, f, &rgb).map_err(at)?;
        let (iw, ih) = read_dimensions(&rgb)?;
        if (iw, ih) != (cam.pinhole.width, cam.pinhole.height) {
            return Err(at(format!(
                "w x h = {}x{}, but {} is {iw}x{ih}",
                cam.pinhole.width,
                cam.pinhole.height,
                rgb.display()
            )));
        }
        let camera_index = match cameras.iter().position(|c| *c == cam) {
            Some(k) => k,
            None => {
                cameras.push(cam);
                cameras.len() - 1
            }
        };
        let depth = match depth {
            Some(DepthSource::Png16 { path: p, metres_per_unit, .. }) => {
                Some(fit_depth(p, metres_per_unit, &cam.pinhole).map_err(at)?)
            }
            other => other,
        };
        frames.push(FrameInfo {
            name: stem(&rgb),
            timestamp: None,
            pose,
            rgb,
            depth,
            sparse_depth_range: None,
            camera: camera_index,
        });
    }
    frames.sort_by(|a, b| a.rgb.cmp(&b.rgb));
    let with_depth = frames.iter().filter(|f| f.depth.is_some()).count();
    let metric = with_depth == frames.len();
    if with_depth > 0 && !metric {
        return Err(bad(format!(
            "{with_depth} of {} frames have depth_file_path; all or none must",
            frames.len()
        )));
    }
    if metric {
        notes.push(format!("depth PNG units: {depth_unit} m (depth_unit_scale_factor)"));
    } else {
        notes.push(format!("{WARNING_NOTE}{NO_SCALE_WARNING}"));
    }
    if cameras.is_empty() {
        return Err(bad("\"frames\" is empty".into()));
    }
    if cameras.len() > 1 {
        notes.push(format!(
            "{} cameras (per-frame intrinsics): each frame is used with its own camera",
            cameras.len()
        ));
    }
    let mut seq = Sequence::from_cameras(
        Format::Nerfstudio,
        root.to_path_buf(),
        cameras,
        frames,
        None,
        notes,
        opt.undistort,
    )?;
    seq.metric = metric;
    Ok(seq)
}

/// `root/rel`, or with `.png` / `.jpg` / `.jpeg` appended when `rel` has no extension.
fn colour_file(root: &Path, rel: &str) -> Option<PathBuf> {
    let p = root.join(rel);
    if p.is_file() {
        return Some(p);
    }
    if p.extension().is_some() {
        return None;
    }
    let (dir, name) = (p.parent()?, p.file_name()?.to_string_lossy().into_owned());
    find_colour_image(dir, &name)
}

fn matrix(v: Option<&Value>) -> std::result::Result<Matrix4<f64>, String> {
    let rows = v.and_then(Value::as_array).ok_or("missing or not an array")?;
    let mut vals = Vec::with_capacity(16);
    for r in rows {
        for x in r.as_array().ok_or("rows must be arrays")? {
            vals.push(x.as_f64().ok_or_else(|| format!("entry {x} is not a number"))?);
        }
    }
    if rows.len() != 4 || vals.len() != 16 {
        return Err(format!(
            "expected 4 rows of 4 numbers, found {} rows, {} numbers",
            rows.len(),
            vals.len()
        ));
    }
    Ok(Matrix4::from_row_slice(&vals))
}

/// The camera of one frame: its own keys over the top level's.
fn frame_camera(
    top: &Map<String, Value>,
    f: &Map<String, Value>,
    rgb: &Path,
) -> std::result::Result<Camera, String> {
    let mut get = std::collections::HashMap::new();
    for k in INTRINSIC_KEYS {
        if let Some(v) = f.get(k).or_else(|| top.get(k)) {
            let x = v
                .as_f64()
                .filter(|x| x.is_finite())
                .ok_or_else(|| format!("{k} is {v}, not a finite number"))?;
            get.insert(k, x);
        }
    }
    if let Some(k4) = f.get("k4").or_else(|| top.get("k4")).and_then(Value::as_f64).filter(|v| *v != 0.0) {
        return Err(format!("k4 = {k4}: fisheye distortion is not read"));
    }
    let (w, h) = match (get.get("w"), get.get("h")) {
        (Some(&w), Some(&h)) => (w as usize, h as usize),
        _ => read_dimensions(rgb).map_err(|e| e.to_string())?,
    };
    let fx = match (get.get("fl_x"), get.get("camera_angle_x")) {
        (Some(&f), _) => f,
        (None, Some(&a)) => 0.5 * w as f64 / (0.5 * a).tan(),
        _ => return Err("no focal length: needs fl_x or camera_angle_x".into()),
    };
    let fy = match (get.get("fl_y"), get.get("camera_angle_y")) {
        (Some(&f), _) => f,
        (None, Some(&a)) => 0.5 * h as f64 / (0.5 * a).tan(),
        _ => fx,
    };
    // nerfstudio and instant-ngp put pixel centres at +0.5 (default cx = w / 2); ours at integers.
    let cx = get.get("cx").copied().unwrap_or(w as f64 / 2.0) - 0.5;
    let cy = get.get("cy").copied().unwrap_or(h as f64 / 2.0) - 0.5;
    let pinhole = PinholeCamera::new(fx, fy, cx, cy, w, h).map_err(|e| e.to_string())?;
    let c = |k: &str| get.get(k).copied().unwrap_or(0.0);
    let d = RadTan { k1: c("k1"), k2: c("k2"), p1: c("p1"), p2: c("p2"), k3: c("k3") };
    Ok(Camera { pinhole, distortion: (!d.is_identity()).then_some(d) })
}

/// Largest relative difference between the depth and colour aspect ratios for upsampling.
pub const ASPECT_TOLERANCE: f64 = 0.01;

/// The depth source for a depth PNG: as is at the camera's size, upsampled when smaller with the
/// same aspect ratio (within [`ASPECT_TOLERANCE`]), else an error.
fn fit_depth(
    path: PathBuf,
    metres_per_unit: f64,
    k: &PinholeCamera,
) -> std::result::Result<DepthSource, String> {
    let (w, h) = read_dimensions(&path).map_err(|e| e.to_string())?;
    if (w, h) == (k.width, k.height) {
        return Ok(DepthSource::Png16 { path, metres_per_unit, invalid: None });
    }
    let aspect = |a: usize, b: usize| a as f64 / b as f64;
    let same_aspect = (aspect(w, h) / aspect(k.width, k.height) - 1.0).abs() <= ASPECT_TOLERANCE;
    if w < k.width && h < k.height && same_aspect {
        return Ok(DepthSource::Png16Upsampled { path, metres_per_unit, width: k.width, height: k.height });
    }
    Err(format!(
        "depth {} is {w}x{h}: it must be the colour size {}x{} or smaller with the same aspect ratio",
        path.display(),
        k.width,
        k.height
    ))
}
