//! COLMAP sparse models (SPEC.md §4a): a folder with `images/` and the model in `sparse/0/`,
//! `sparse/` or the folder itself, as `cameras`, `images` and optionally `points3D`, each `.bin`
//! (preferred when both exist) or `.txt`.
//!
//! COLMAP poses are world-to-camera (`X_c = R(q) X_w + t`, `q = (qw, qx, qy, qz)` Hamilton) and have
//! no metric scale: the sequence is marked non-metric with a warning until `--scale` is given.

mod binary;
mod model;
mod text;
mod write;

use std::collections::HashMap;
use std::path::{Path, PathBuf};

pub use model::{colmap_params, CameraModel, SUPPORTED_MODELS};
pub use write::{write_model, ColmapExport};

use super::depth_range::depth_range_of;
use super::text::{list_colour_images, stem};
use super::{Format, FrameInfo, OpenOptions, Sequence, WARNING_NOTE};
use crate::error::{Error, Result};
use crate::image::read_dimensions;
use model::{observed_depths, RawCamera, RawImage, RawPoint};

/// Sub-folders searched for the model, in order.
pub const MODEL_DIRS: [&str; 3] = ["sparse/0", "sparse", "."];

/// The warning every COLMAP sequence carries until `--scale` is given.
pub const NO_SCALE_WARNING: &str = "COLMAP poses have no metric scale: lengths are in model units. \
     Pass --scale METRES_PER_UNIT to map/reconstruct/eval (or --scale 1 to keep model units)";

/// The model folder of `root` and whether it is binary, if `root` holds a COLMAP model and `images/`.
pub fn find_model(root: &Path) -> Option<(PathBuf, bool)> {
    if !root.join("images").is_dir() {
        return None;
    }
    MODEL_DIRS.iter().map(|d| root.join(d)).find_map(|dir| {
        let has = |n: &str| dir.join(n).is_file();
        if has("cameras.bin") && has("images.bin") {
            Some((dir, true))
        } else if has("cameras.txt") && has("images.txt") {
            Some((dir, false))
        } else {
            None
        }
    })
}

pub(crate) fn read(root: &Path, opt: &OpenOptions) -> Result<Sequence> {
    let (dir, binary) = find_model(root).ok_or_else(|| {
        Error::bad_sequence(root, "no COLMAP model (cameras + images in sparse/0, sparse or .)")
    })?;
    let ext = if binary { "bin" } else { "txt" };
    let (cam_path, img_path, pts_path) = (
        dir.join(format!("cameras.{ext}")),
        dir.join(format!("images.{ext}")),
        dir.join(format!("points3D.{ext}")),
    );
    let (cameras, images, points) = if binary {
        let p = pts_path.is_file().then(|| binary::read_points(&pts_path)).transpose()?;
        (binary::read_cameras(&cam_path)?, binary::read_images(&img_path)?, p)
    } else {
        let p = pts_path.is_file().then(|| text::read_points(&pts_path)).transpose()?;
        (text::read_cameras(&cam_path)?, text::read_images(&img_path)?, p)
    };
    let mut notes =
        vec![format!("COLMAP {} model {}", if binary { "binary" } else { "text" }, dir.display())];
    if let Some(c) = &opt.camera {
        notes.push(format!("camera option ({c}) ignored: the COLMAP model gives the camera"));
    }
    if images.is_empty() {
        return Err(Error::bad_file(&img_path, "the model has no registered images"));
    }
    let (raw_cameras, camera_of) = camera_table(&cameras, &images, &cam_path, &img_path)?;
    let points: Option<HashMap<u64, [f64; 3]>> =
        points.map(|p| p.into_iter().map(|RawPoint { id, xyz }| (id, xyz)).collect());
    let images_dir = root.join("images");
    let mut sorted: Vec<&RawImage> = images.iter().collect();
    sorted.sort_by(|a, b| a.name.cmp(&b.name));
    if let Some(w) = sorted.windows(2).find(|w| w[0].name == w[1].name) {
        let later = if w[0].loc.order() > w[1].loc.order() { w[0] } else { w[1] };
        return Err(later.loc.error(&img_path, format!("image name {:?} is registered twice", later.name)));
    }
    let raw_of: HashMap<u32, &RawCamera> = cameras.iter().map(|c| (c.id, c)).collect();
    let mut frames = Vec::with_capacity(sorted.len());
    let mut without_range = 0;
    for im in sorted {
        let rgb = images_dir.join(&im.name);
        if !rgb.is_file() {
            return Err(im.loc.error(
                &img_path,
                format!("image {} names {:?}, but {} does not exist", im.id, im.name, rgb.display()),
            ));
        }
        // The size a camera claims is checked here, so the error points at the camera's line or
        // record (a wrong size is a camera error, not an image error).
        let k = &raw_cameras[camera_of[&im.camera_id]].pinhole;
        let (w, h) = read_dimensions(&rgb)?;
        if (w, h) != (k.width, k.height) {
            let c = raw_of[&im.camera_id];
            return Err(c.loc.error(
                &cam_path,
                format!(
                    "camera {} is {}x{}, but image {} is {w}x{h} ({})",
                    c.id,
                    k.width,
                    k.height,
                    im.id,
                    rgb.display()
                ),
            ));
        }
        let t_cw = im.t_cw(&img_path)?;
        let sparse_depth_range = match &points {
            Some(p) => {
                let z = observed_depths(&t_cw, &im.observed, p).map_err(|id| {
                    im.loc.error(
                        &img_path,
                        format!("image {} observes 3D point {id}, which points3D lacks", im.id),
                    )
                })?;
                let r = depth_range_of(z);
                without_range += usize::from(r.is_none());
                r
            }
            None => None,
        };
        frames.push(FrameInfo {
            name: stem(&rgb),
            timestamp: None,
            pose: t_cw.inverse(),
            rgb,
            depth: None,
            sparse_depth_range,
            camera: camera_of[&im.camera_id],
        });
    }
    match &points {
        None => notes.push(format!("{WARNING_NOTE}no points3D.{ext}: no sparse depth range per frame")),
        Some(p) => notes.push(format!(
            "{} sparse points; depth range from them for {} of {} frames",
            p.len(),
            frames.len() - without_range,
            frames.len()
        )),
    }
    let on_disk = list_colour_images(&images_dir).map(|v| v.len()).unwrap_or(0);
    if on_disk > frames.len() {
        notes.push(format!(
            "{} images in {} are not registered in the model",
            on_disk - frames.len(),
            images_dir.display()
        ));
    }
    if raw_cameras.len() > 1 {
        let mut sizes: Vec<(usize, usize)> =
            raw_cameras.iter().map(|c| (c.pinhole.width, c.pinhole.height)).collect();
        sizes.sort_unstable();
        sizes.dedup();
        notes.push(format!(
            "{} cameras ({} image sizes): each frame is used with its own camera",
            raw_cameras.len(),
            sizes.len()
        ));
    }
    notes.push(format!("{WARNING_NOTE}{NO_SCALE_WARNING}"));
    let mut seq = Sequence::from_cameras(
        Format::Colmap,
        root.to_path_buf(),
        raw_cameras,
        frames,
        None,
        notes,
        opt.undistort,
    )?;
    seq.metric = false;
    Ok(seq)
}

/// The distinct cameras the registered images use (COLMAP ids with identical model, size and
/// parameters merged), in order of first use by image name, and each used id's index among them.
fn camera_table(
    cameras: &[RawCamera],
    images: &[RawImage],
    cam_path: &Path,
    img_path: &Path,
) -> Result<(Vec<crate::geometry::Camera>, HashMap<u32, usize>)> {
    for (i, c) in cameras.iter().enumerate() {
        if cameras[..i].iter().any(|o| o.id == c.id) {
            return Err(c.loc.error(cam_path, format!("camera id {} is defined twice", c.id)));
        }
    }
    let mut sorted: Vec<&RawImage> = images.iter().collect();
    sorted.sort_by(|a, b| a.name.cmp(&b.name));
    let mut distinct: Vec<&RawCamera> = Vec::new();
    let mut index = HashMap::new();
    for im in sorted {
        if index.contains_key(&im.camera_id) {
            continue;
        }
        let c = cameras.iter().find(|c| c.id == im.camera_id).ok_or_else(|| {
            im.loc.error(
                img_path,
                format!("image {} uses camera {}, which {} lacks", im.id, im.camera_id, cam_path.display()),
            )
        })?;
        let same = |u: &&RawCamera| {
            (u.model, u.width, u.height, &u.params) == (c.model, c.width, c.height, &c.params)
        };
        let i = match distinct.iter().position(same) {
            Some(i) => i,
            None => {
                distinct.push(c);
                distinct.len() - 1
            }
        };
        index.insert(im.camera_id, i);
    }
    if distinct.is_empty() {
        return Err(Error::bad_file(img_path, "the model has no registered images"));
    }
    let cams = distinct.iter().map(|c| c.to_camera(cam_path)).collect::<Result<Vec<_>>>()?;
    Ok((cams, index))
}
