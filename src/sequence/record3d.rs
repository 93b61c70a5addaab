//! Record3D's "EXR + JPG" export (SPEC.md §4a):
//!
//! ```text
//! metadata.json   w, h: colour size; K: 9 numbers, column-major [fx 0 0 0 fy 0 cx cy 1] for w x h;
//!                 dw, dh: depth size (optional); fps (optional);
//!                 poses: per frame [qx, qy, qz, qw, tx, ty, tz], camera-to-world, ARKit / OpenGL
//!                 camera axes (x right, y up, looking along -z), metres
//! rgb/<i>.jpg     colour of frame i (rgbd/<i>.jpg also read)
//! depth/<i>.exr   depth of frame i, one half or float channel, metres (rgbd/<i>.exr also read)
//! ```
//! Poses are converted to our axes with [`pose_from_opengl`]. The principal point is taken with
//! pixel centres at `+0.5`, as nerfstudio's Record3D import does: `cx = K[6] - 0.5`. Depth smaller
//! than the colour images (LiDAR: 256x192 for 1920x1440) is upsampled on load by nearest neighbour
//! with pixel centres aligned ([`super::upsample_nearest`]). Frames of `poses` without a colour image
//! are skipped with a note. ARKit poses are metric, so the sequence is metric with or without depth.

use std::path::{Path, PathBuf};

use serde_json::{Map, Value};

use super::nerfstudio::ASPECT_TOLERANCE;
use super::text::{find_colour_image, list_files_with, read_text, COLOUR_EXTENSIONS};
use super::{DepthSource, Format, FrameInfo, OpenOptions, Sequence};
use crate::error::{Error, Result};
use crate::geometry::{pose_from_opengl, pose_from_tum, Camera, PinholeCamera, Pose};
use crate::image::{read_dimensions, read_exr_dimensions};

/// The file this reader looks for.
pub const FILE: &str = "metadata.json";
/// Folders searched for the colour images, in order.
pub const COLOUR_DIRS: [&str; 2] = ["rgb", "rgbd"];
/// Folders searched for the depth maps, in order.
pub const DEPTH_DIRS: [&str; 2] = ["depth", "rgbd"];
/// Largest `|entry|` accepted where column-major `K` has a structural zero, pixels.
const K_ZERO_TOLERANCE: f64 = 1e-6;

/// Whether `root` looks like a Record3D export: `metadata.json` and a colour folder.
pub(crate) fn looks_like(root: &Path) -> bool {
    root.join(FILE).is_file() && first_dir(root, &COLOUR_DIRS).is_some()
}

fn first_dir(root: &Path, names: &[&str]) -> Option<PathBuf> {
    names.iter().map(|n| root.join(n)).find(|p| p.is_dir())
}

pub(crate) fn read(root: &Path, opt: &OpenOptions) -> Result<Sequence> {
    let path = root.join(FILE);
    let text = read_text(&path)?;
    let json: Value = serde_json::from_str(&text)
        .map_err(|e| Error::parse(&path, e.line(), format!("not valid JSON: {e}")))?;
    let bad = |what: String| Error::bad_file(&path, what);
    let top = json.as_object().ok_or_else(|| bad("top level is not a JSON object".into()))?;
    let (w, h) = (size(top, "w").map_err(bad)?, size(top, "h").map_err(bad)?);
    let camera = intrinsics(top, w, h).map_err(bad)?;
    let depth_size = match (top.contains_key("dw"), top.contains_key("dh")) {
        (false, false) => None,
        _ => Some((size(top, "dw").map_err(bad)?, size(top, "dh").map_err(bad)?)),
    };
    if let Some((dw, dh)) = depth_size {
        fits(dw, dh, &camera).map_err(|e| bad(format!("depth size dw x dh = {dw}x{dh}: {e}")))?;
    }
    let fps = match top.get("fps") {
        None => None,
        Some(v) => Some(
            v.as_f64()
                .filter(|f| f.is_finite() && *f > 0.0)
                .ok_or_else(|| bad(format!("fps is {v}, expected a number > 0")))?,
        ),
    };
    let poses = top.get("poses").and_then(Value::as_array).ok_or_else(|| bad("no \"poses\" array".into()))?;
    if poses.is_empty() {
        return Err(bad("\"poses\" is empty".into()));
    }
    let rgb_dir = first_dir(root, &COLOUR_DIRS).ok_or_else(|| {
        Error::bad_sequence(root, format!("no colour folder: looked for {}", COLOUR_DIRS.join("/, ") + "/"))
    })?;
    let depth_dir = first_dir(root, &DEPTH_DIRS);
    let mut notes = Vec::new();
    if let Some(c) = &opt.camera {
        notes.push(format!("camera option ({c}) ignored: {FILE} gives the camera"));
    }
    let (mut frames, mut skipped) = (Vec::with_capacity(poses.len()), Vec::new());
    for (i, p) in poses.iter().enumerate() {
        let pose = pose(p).map_err(|e| bad(format!("poses[{i}]: {e}")))?;
        let Some(rgb) = find_colour_image(&rgb_dir, &i.to_string()) else {
            skipped.push(i);
            continue;
        };
        let (iw, ih) = read_dimensions(&rgb)?;
        if (iw, ih) != (w, h) {
            return Err(bad(format!("w x h = {w}x{h}, but {} is {iw}x{ih}", rgb.display())));
        }
        let depth = match &depth_dir {
            None => None,
            Some(dir) => Some(depth_source(root, dir, i, &rgb, depth_size, &camera)?),
        };
        frames.push(FrameInfo {
            name: i.to_string(),
            timestamp: fps.map(|f| i as f64 / f),
            pose,
            rgb,
            depth,
            sparse_depth_range: None,
            camera: 0,
        });
    }
    if frames.is_empty() {
        return Err(Error::bad_sequence(
            root,
            format!(
                "none of the {} frames in {FILE} has a colour image ({}/<index>.jpg)",
                poses.len(),
                rgb_dir.display()
            ),
        ));
    }
    notes.extend(summary_notes(&rgb_dir, poses.len(), &frames, &skipped, depth_dir.is_some(), &camera)?);
    Sequence::from_parts(
        Format::Record3d,
        root.to_path_buf(),
        Camera::pinhole(camera),
        frames,
        None,
        notes,
        opt.undistort,
    )
}

/// A positive integer entry of the metadata.
fn size(top: &Map<String, Value>, key: &str) -> std::result::Result<usize, String> {
    let v = top.get(key).ok_or_else(|| format!("no \"{key}\" key"))?;
    v.as_u64()
        .filter(|&n| n > 0)
        .and_then(|n| usize::try_from(n).ok())
        .ok_or_else(|| format!("{key} is {v}, expected a positive integer"))
}

/// The camera from column-major `K` (`[fx 0 0 0 fy 0 cx cy 1]`) for the `w x h` colour images.
fn intrinsics(top: &Map<String, Value>, w: usize, h: usize) -> std::result::Result<PinholeCamera, String> {
    let k = top.get("K").ok_or("no \"K\" key")?;
    let k: Vec<f64> = k
        .as_array()
        .ok_or_else(|| format!("K is {k}, expected an array of 9 numbers"))?
        .iter()
        .map(|x| {
            x.as_f64().filter(|v| v.is_finite()).ok_or_else(|| format!("K entry {x} is not a finite number"))
        })
        .collect::<std::result::Result<_, _>>()?;
    if k.len() != 9 {
        return Err(format!("K has {} numbers, expected 9 (a 3x3 matrix, column-major)", k.len()));
    }
    let structural = [1, 2, 3, 5].iter().all(|&i| k[i].abs() <= K_ZERO_TOLERANCE)
        && (k[8] - 1.0).abs() <= K_ZERO_TOLERANCE;
    if !structural {
        let row_major = k[2] != 0.0 && k[5] != 0.0 && k[6] == 0.0 && k[7] == 0.0;
        return Err(format!(
            "K is {k:?}: expected column-major [fx, 0, 0, 0, fy, 0, cx, cy, 1]{}",
            if row_major { " (this one looks row-major)" } else { "" }
        ));
    }
    // ARKit puts the principal point in coordinates whose origin is the image corner (pixel centres
    // at +0.5, as in nerfstudio's import of Record3D); ours has pixel centres at integers (§2.1).
    PinholeCamera::new(k[0], k[4], k[6] - 0.5, k[7] - 0.5, w, h).map_err(|e| format!("K: {e}"))
}

/// `[qx, qy, qz, qw, tx, ty, tz]`, camera-to-world in OpenGL camera axes, as our `T_wc`.
fn pose(v: &Value) -> std::result::Result<Pose, String> {
    let a = v.as_array().ok_or_else(|| format!("{v} is not an array [qx, qy, qz, qw, tx, ty, tz]"))?;
    if a.len() != 7 {
        return Err(format!("has {} numbers, expected 7 [qx, qy, qz, qw, tx, ty, tz]", a.len()));
    }
    let mut n = [0.0; 7];
    for (o, x) in n.iter_mut().zip(a) {
        *o = x
            .as_f64()
            .filter(|v| v.is_finite())
            .ok_or_else(|| format!("entry {x} is not a finite number"))?;
    }
    let gl = pose_from_tum([n[4], n[5], n[6]], [n[0], n[1], n[2], n[3]])?;
    Ok(pose_from_opengl(&gl))
}

/// Whether a `dw x dh` depth map can be read for `k`: the colour size, or smaller with its aspect
/// ratio (within [`ASPECT_TOLERANCE`]).
fn fits(dw: usize, dh: usize, k: &PinholeCamera) -> std::result::Result<(), String> {
    let aspect = |a: usize, b: usize| a as f64 / b as f64;
    let same_aspect = (aspect(dw, dh) / aspect(k.width, k.height) - 1.0).abs() <= ASPECT_TOLERANCE;
    if (dw, dh) == (k.width, k.height) || (dw <= k.width && dh <= k.height && same_aspect) {
        return Ok(());
    }
    Err(format!("must be the colour size {}x{} or smaller with the same aspect ratio", k.width, k.height))
}

/// Frame `i`'s depth map, its header checked against `dw x dh` (or the colour size's aspect).
fn depth_source(
    root: &Path,
    dir: &Path,
    i: usize,
    rgb: &Path,
    depth_size: Option<(usize, usize)>,
    k: &PinholeCamera,
) -> Result<DepthSource> {
    let path = dir.join(format!("{i}.exr"));
    if !path.is_file() {
        return Err(Error::bad_sequence(
            root,
            format!(
                "{} has no depth map {} (every frame needs one when there is a depth folder)",
                rgb.display(),
                path.display()
            ),
        ));
    }
    let (w, h) = read_exr_dimensions(&path)?;
    match depth_size {
        Some(want) if want != (w, h) => {
            return Err(Error::bad_file(
                &path,
                format!("depth map is {w}x{h}, but {FILE} says dw x dh = {}x{}", want.0, want.1),
            ))
        }
        Some(_) => {}
        None => fits(w, h, k).map_err(|e| Error::bad_file(&path, format!("depth map is {w}x{h}: {e}")))?,
    }
    Ok(DepthSource::Exr { path, metres_per_unit: 1.0, width: k.width, height: k.height })
}

/// What `inspect` should say: skipped frames, unused images, the depth and its upsampling.
fn summary_notes(
    rgb_dir: &Path,
    listed: usize,
    frames: &[FrameInfo],
    skipped: &[usize],
    has_depth: bool,
    k: &PinholeCamera,
) -> Result<Vec<String>> {
    let mut notes = Vec::new();
    if !skipped.is_empty() {
        let shown: Vec<String> = skipped.iter().take(10).map(usize::to_string).collect();
        let more =
            if skipped.len() > 10 { format!(" and {} more", skipped.len() - 10) } else { String::new() };
        notes.push(format!(
            "{} of the {listed} frames in {FILE} have no colour image in {} and were skipped: {}{more}",
            skipped.len(),
            rgb_dir.display(),
            shown.join(", ")
        ));
    }
    let images = list_files_with(rgb_dir, &COLOUR_EXTENSIONS)?.len();
    if images > frames.len() {
        notes.push(format!(
            "{} colour images in {} have no pose in {FILE} and were ignored",
            images - frames.len(),
            rgb_dir.display()
        ));
    }
    match frames[0].depth.as_ref().map(|d| read_exr_dimensions(d.path())).transpose()? {
        Some((w, h)) if (w, h) != (k.width, k.height) => notes.push(format!(
            "depth: EXR {w}x{h} in metres, upsampled to {}x{} (nearest, pixel centres aligned)",
            k.width, k.height
        )),
        Some(_) => notes.push("depth: EXR in metres".into()),
        None if !has_depth => notes.push("no depth folder: frames carry no depth (poses are metric)".into()),
        None => {}
    }
    Ok(notes)
}
