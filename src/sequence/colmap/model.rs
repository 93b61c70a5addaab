//! The parts of a COLMAP sparse model we read, shared by the text and binary parsers, and the
//! conversion of COLMAP cameras and poses to ours (SPEC.md §4a).

use std::path::Path;

use nalgebra::Vector3;

use crate::error::{Error, Result};
use crate::geometry::{pose_from_tum, Camera, PinholeCamera, Pose, RadTan};

/// COLMAP camera models, with the ids of COLMAP's `cameras.bin` and names of `cameras.txt`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum CameraModel {
    /// Id 0: `f cx cy`.
    SimplePinhole,
    /// Id 1: `fx fy cx cy`.
    Pinhole,
    /// Id 2: `f cx cy k`.
    SimpleRadial,
    /// Id 3: `f cx cy k1 k2`.
    Radial,
    /// Id 4: `fx fy cx cy k1 k2 p1 p2`.
    Opencv,
    /// A model COLMAP defines that we do not read (fisheye, FOV, thin prism, ...): its id and name.
    Unsupported(i32, &'static str),
}

/// `(id, name, parameter count)` of every model COLMAP 3.x defines.
const MODELS: [(i32, &str, usize); 11] = [
    (0, "SIMPLE_PINHOLE", 3),
    (1, "PINHOLE", 4),
    (2, "SIMPLE_RADIAL", 4),
    (3, "RADIAL", 5),
    (4, "OPENCV", 8),
    (5, "OPENCV_FISHEYE", 8),
    (6, "FULL_OPENCV", 12),
    (7, "FOV", 5),
    (8, "SIMPLE_RADIAL_FISHEYE", 4),
    (9, "RADIAL_FISHEYE", 5),
    (10, "THIN_PRISM_FISHEYE", 12),
];

/// What the error messages list as readable.
pub const SUPPORTED_MODELS: &str = "SIMPLE_PINHOLE, PINHOLE, SIMPLE_RADIAL, RADIAL, OPENCV";

impl CameraModel {
    fn from_entry(id: i32, name: &'static str) -> Self {
        match id {
            0 => CameraModel::SimplePinhole,
            1 => CameraModel::Pinhole,
            2 => CameraModel::SimpleRadial,
            3 => CameraModel::Radial,
            4 => CameraModel::Opencv,
            _ => CameraModel::Unsupported(id, name),
        }
    }

    /// The model with COLMAP id `id` and its parameter count; `None` for an id COLMAP does not define.
    pub fn from_id(id: i32) -> Option<(Self, usize)> {
        MODELS.iter().find(|m| m.0 == id).map(|&(i, n, c)| (Self::from_entry(i, n), c))
    }

    /// The model named `name` (as in `cameras.txt`) and its parameter count.
    pub fn from_name(name: &str) -> Option<(Self, usize)> {
        MODELS.iter().find(|m| m.1 == name).map(|&(i, n, c)| (Self::from_entry(i, n), c))
    }

    /// COLMAP's id.
    pub fn id(self) -> i32 {
        match self {
            CameraModel::SimplePinhole => 0,
            CameraModel::Pinhole => 1,
            CameraModel::SimpleRadial => 2,
            CameraModel::Radial => 3,
            CameraModel::Opencv => 4,
            CameraModel::Unsupported(id, _) => id,
        }
    }

    /// COLMAP's name.
    pub fn name(self) -> &'static str {
        MODELS.iter().find(|m| m.0 == self.id()).map_or("UNKNOWN", |m| m.1)
    }
}

/// Where a record came from, for messages: a text line or a binary record.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Loc {
    /// 1-based line of a text file.
    Line(usize),
    /// 0-based record of a binary file and its byte offset.
    Record { index: usize, offset: usize },
}

impl Loc {
    /// Position in the file, for ordering records.
    pub fn order(self) -> usize {
        match self {
            Loc::Line(n) => n,
            Loc::Record { index, .. } => index,
        }
    }

    /// An error about this record of `path`.
    pub fn error(self, path: &Path, what: impl Into<String>) -> Error {
        match self {
            Loc::Line(n) => Error::parse(path, n, what),
            Loc::Record { index, offset } => {
                Error::bad_file(path, format!("record {index} (byte offset {offset}): {}", what.into()))
            }
        }
    }
}

/// One `cameras` entry.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct RawCamera {
    pub id: u32,
    pub model: CameraModel,
    pub width: usize,
    pub height: usize,
    pub params: Vec<f64>,
    pub loc: Loc,
}

/// One `images` entry: world-to-camera `q = (qw, qx, qy, qz)`, `t`.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct RawImage {
    pub id: u32,
    pub q_wxyz: [f64; 4],
    pub t: [f64; 3],
    pub camera_id: u32,
    pub name: String,
    /// Ids of the 3D points its 2D points observe (`-1` entries dropped).
    pub observed: Vec<u64>,
    pub loc: Loc,
}

/// One `points3D` entry (only what the depth range needs).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct RawPoint {
    pub id: u64,
    pub xyz: [f64; 3],
}

impl RawCamera {
    /// Our camera: COLMAP's principal point minus 0.5 px (COLMAP puts the centre of the top-left
    /// pixel at (0.5, 0.5), we at (0, 0); SPEC.md §2.1), distortion as radial-tangential.
    pub fn to_camera(&self, path: &Path) -> Result<Camera> {
        let p = &self.params;
        if let Some(v) = p.iter().find(|v| !v.is_finite()) {
            return Err(self.loc.error(path, format!("camera {} has a non-finite parameter {v}", self.id)));
        }
        let (fx, fy, cx, cy, d) = match self.model {
            CameraModel::SimplePinhole => (p[0], p[0], p[1], p[2], None),
            CameraModel::Pinhole => (p[0], p[1], p[2], p[3], None),
            CameraModel::SimpleRadial => {
                (p[0], p[0], p[1], p[2], Some(RadTan { k1: p[3], ..RadTan::default() }))
            }
            CameraModel::Radial => {
                (p[0], p[0], p[1], p[2], Some(RadTan { k1: p[3], k2: p[4], ..RadTan::default() }))
            }
            CameraModel::Opencv => {
                (p[0], p[1], p[2], p[3], Some(RadTan { k1: p[4], k2: p[5], p1: p[6], p2: p[7], k3: 0.0 }))
            }
            CameraModel::Unsupported(id, name) => {
                return Err(self.loc.error(
                    path,
                    format!(
                        "camera {} uses model {name} (id {id}), which we do not read; supported: \
                         {SUPPORTED_MODELS} (undistort with `colmap image_undistorter` first)",
                        self.id
                    ),
                ))
            }
        };
        let pinhole = PinholeCamera::new(fx, fy, cx - 0.5, cy - 0.5, self.width, self.height)
            .map_err(|e| self.loc.error(path, format!("camera {}: {e}", self.id)))?;
        Ok(Camera { pinhole, distortion: d.filter(|d| !d.is_identity()) })
    }
}

impl RawImage {
    /// World-to-camera rotation and translation as `T_cw`.
    pub fn t_cw(&self, path: &Path) -> Result<Pose> {
        let [w, x, y, z] = self.q_wxyz;
        pose_from_tum(self.t, [x, y, z, w])
            .map_err(|e| self.loc.error(path, format!("image {} ({}): {e}", self.id, self.name)))
    }
}

/// The camera parameters of `camera` in COLMAP's convention for `model` (principal point plus 0.5).
///
/// # Errors
/// [`Error::InvalidArgument`] when the model cannot express the camera (unequal focal lengths for a
/// single-focal model, distortion terms the model lacks).
pub fn colmap_params(model: CameraModel, camera: &Camera) -> Result<Vec<f64>> {
    let k = &camera.pinhole;
    let d = camera.distortion.unwrap_or_default();
    let (cx, cy) = (k.cx + 0.5, k.cy + 0.5);
    let bad =
        |what: &str| Error::invalid_argument("COLMAP camera model", format!("{}: {what}", model.name()));
    let single = || if k.fx == k.fy { Ok(()) } else { Err(bad("needs fx == fy")) };
    let only = |ok: bool| if ok { Ok(()) } else { Err(bad("cannot hold this camera's distortion")) };
    Ok(match model {
        CameraModel::SimplePinhole => {
            single()?;
            only(d.is_identity())?;
            vec![k.fx, cx, cy]
        }
        CameraModel::Pinhole => {
            only(d.is_identity())?;
            vec![k.fx, k.fy, cx, cy]
        }
        CameraModel::SimpleRadial => {
            single()?;
            only(d.k2 == 0.0 && d.p1 == 0.0 && d.p2 == 0.0 && d.k3 == 0.0)?;
            vec![k.fx, cx, cy, d.k1]
        }
        CameraModel::Radial => {
            single()?;
            only(d.p1 == 0.0 && d.p2 == 0.0 && d.k3 == 0.0)?;
            vec![k.fx, cx, cy, d.k1, d.k2]
        }
        CameraModel::Opencv => {
            only(d.k3 == 0.0)?;
            vec![k.fx, k.fy, cx, cy, d.k1, d.k2, d.p1, d.p2]
        }
        CameraModel::Unsupported(..) => return Err(bad("not a model we write")),
    })
}

/// Depths in camera `t_cw` of the points `ids` (looked up in `points`).
pub(crate) fn observed_depths(
    t_cw: &Pose,
    ids: &[u64],
    points: &std::collections::HashMap<u64, [f64; 3]>,
) -> std::result::Result<Vec<f64>, u64> {
    ids.iter()
        .map(|id| {
            let p = points.get(id).ok_or(*id)?;
            Ok((t_cw * nalgebra::Point3::from(Vector3::from(*p))).z)
        })
        .collect()
}
