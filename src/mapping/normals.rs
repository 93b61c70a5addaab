//! Where the normal prior's normals come from (SPEC.md §10.2, `--normals gt|DIR|learned`): the
//! keyframe's ground-truth depth, a folder of `.npy` files, or the built-in predictor (§13.11). All
//! give camera-frame normals `[H, W, 3]` at level 0 (NaN where there is none), resampled to the
//! mapper's level by nearest neighbour (level-`L` pixel `j` = level-0 pixel `2^L j`, SPEC.md §2.6).

use std::path::{Path, PathBuf};

use ndarray::{Array3, ArrayView3};

use crate::error::{Error, Result};
use crate::geometry::PinholeCamera;
use crate::image::DepthMap;
use crate::normals_net::predict::{angular_errors, mean_and_median};
use crate::normals_net::{NormalNet, NormalNetWeights, SHIPPED_NORMAL_WEIGHTS, SHIPPED_NORMAL_WEIGHTS_NAME};
use crate::sequence::Sequence;

pub use super::depth_normals::{fit_radius, normals_from_depth, FIT_DEPTH_GATE, FIT_RADIUS_PER_256PX};

/// How far a stored normal's norm may be from 1.
pub const NORM_TOLERANCE: f32 = 1e-2;

/// `--normals`: where the keyframe's normals come from.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum NormalsSource {
    /// From the keyframe's ground-truth depth ([`normals_from_depth`]): the upper bound.
    GroundTruth,
    /// `DIR/NNNNN.npy` (keyframe index, 5 digits) or `DIR/<frame name>.npy`: `[H, W, 3]` f32
    /// camera-frame unit normals at level 0.
    Dir(PathBuf),
    /// The built-in predictor (SPEC.md §13.11) with these weights (`--normal-weights`), or the
    /// shipped ones (`None`).
    Learned(Option<PathBuf>),
}

impl std::str::FromStr for NormalsSource {
    type Err = Error;

    /// `gt`, `learned` (weights from `--normal-weights` or the shipped ones), or a folder that
    /// exists.
    fn from_str(s: &str) -> Result<Self> {
        if s == "gt" {
            return Ok(Self::GroundTruth);
        }
        if s == "learned" {
            return Ok(Self::Learned(None));
        }
        let p = PathBuf::from(s);
        if !p.is_dir() {
            return Err(Error::invalid_argument(
                "--normals",
                format!("{s:?}: expected gt, learned or a folder of NNNNN.npy normal maps, and no such folder exists"),
            ));
        }
        Ok(Self::Dir(p))
    }
}

/// Level-`level` normals: level-0 pixel `2^level j` (nearest, SPEC.md §2.6).
pub fn normals_at_level(normals: ArrayView3<f32>, level: u32) -> Array3<f32> {
    let (h, w, _) = normals.dim();
    let s = 1usize << level;
    Array3::from_shape_fn((h.div_ceil(s), w.div_ceil(s), 3), |(y, x, k)| normals[[y * s, x * s, k]])
}

/// The file `--normals DIR` holds for `keyframe`: `DIR/NNNNN.npy` if it exists, else
/// `DIR/<frame name>.npy`.
///
/// # Errors
/// [`Error::InvalidArgument`] (flag `--normals`) naming both candidates when neither exists.
pub fn normals_file(dir: &Path, seq: &Sequence, keyframe: usize) -> Result<PathBuf> {
    let by_index = dir.join(format!("{keyframe:05}.npy"));
    if by_index.is_file() {
        return Ok(by_index);
    }
    let by_name = seq.frames.get(keyframe).map(|f| dir.join(format!("{}.npy", f.name)));
    match by_name {
        Some(p) if p.is_file() => Ok(p),
        other => Err(Error::invalid_argument(
            "--normals",
            format!(
                "no normals for keyframe {keyframe}: neither {} nor {} exists",
                by_index.display(),
                other.map_or("a file named after the frame".into(), |p| p.display().to_string())
            ),
        )),
    }
}

/// Read a `[H, W, 3]` little-endian f32 C-order `.npy` of camera-frame unit normals and check it:
/// the shape, every value finite, every vector's norm within [`NORM_TOLERANCE`] of 1 (or the zero
/// vector: no normal, returned as NaN).
///
/// # Errors
/// [`Error::BadFile`] naming `path` for anything else.
pub fn read_normals(path: &Path, height: usize, width: usize) -> Result<Array3<f32>> {
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    let bad = |what: String| Error::bad_file(path, what);
    if bytes.len() < 10 || &bytes[..6] != b"\x93NUMPY" {
        return Err(bad("not a .npy file (no \\x93NUMPY magic)".into()));
    }
    let (hlen, start) = match bytes[6] {
        1 => (u16::from_le_bytes([bytes[8], bytes[9]]) as usize, 10),
        2 | 3 if bytes.len() >= 12 => {
            (u32::from_le_bytes([bytes[8], bytes[9], bytes[10], bytes[11]]) as usize, 12)
        }
        v => return Err(bad(format!("unsupported .npy version {v}"))),
    };
    let header = bytes.get(start..start + hlen).ok_or_else(|| bad("truncated header".into()))?;
    let header = String::from_utf8_lossy(header).replace(' ', "");
    if !header.contains("'descr':'<f4'") {
        return Err(bad(format!("need little-endian float32 ('<f4'), header {header:?}")));
    }
    if !header.contains("'fortran_order':False") {
        return Err(bad("need C order (fortran_order False)".into()));
    }
    let want = format!("'shape':({height},{width},3)");
    if !header.contains(&want) {
        return Err(bad(format!(
            "need shape ({height}, {width}, 3) (the keyframe at level 0), header {header:?}"
        )));
    }
    let data = &bytes[start + hlen..];
    if data.len() != height * width * 3 * 4 {
        return Err(bad(format!("{} data bytes for shape ({height}, {width}, 3)", data.len())));
    }
    let values: Vec<f32> =
        data.chunks_exact(4).map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]])).collect();
    let mut out = Array3::from_shape_vec((height, width, 3), values).expect("length checked");
    for y in 0..height {
        for x in 0..width {
            let n = [out[[y, x, 0]], out[[y, x, 1]], out[[y, x, 2]]];
            if n.iter().any(|v| !v.is_finite()) {
                return Err(bad(format!("non-finite normal {n:?} at pixel ({x}, {y})")));
            }
            let norm = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
            if norm == 0.0 {
                out.slice_mut(ndarray::s![y, x, ..]).fill(f32::NAN);
            } else if (norm - 1.0).abs() > NORM_TOLERANCE {
                return Err(bad(format!("normal {n:?} at pixel ({x}, {y}) has norm {norm}, not 1")));
            }
        }
    }
    Ok(out)
}

/// The normal predictor of `--normals learned`: the file `weights`, else the shipped one.
///
/// # Errors
/// [`Error::InvalidArgument`] (flag `--normals`) when no file is given and none is shipped; the
/// file's load errors.
pub fn load_predictor(weights: Option<&Path>) -> Result<NormalNetWeights> {
    match (weights, SHIPPED_NORMAL_WEIGHTS) {
        (Some(p), _) => NormalNetWeights::load(p),
        (None, Some(bytes)) => {
            NormalNetWeights::from_safetensors_bytes(bytes, Path::new(SHIPPED_NORMAL_WEIGHTS_NAME))
        }
        (None, None) => Err(Error::invalid_argument(
            "--normals",
            "learned: this build has no trained normal predictor built in; give --normal-weights FILE \
             (a normalnet.safetensors written by densefeat train-normals), or use --normals gt|DIR",
        )),
    }
}

/// How far predicted normals are from the ground truth's ([`normals_from_depth`]), over the pixels
/// where both exist.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NormalsError {
    /// Pixels compared.
    pub pixels: usize,
    /// Mean angular error, degrees.
    pub mean_deg: f64,
    /// Median angular error, degrees (the lower middle value for an even count).
    pub median_deg: f64,
}

/// [`NormalsError`] of `predicted` (`[H, W, 3]`, level 0) against the normals of `depth`; `None`
/// when no pixel has both.
///
/// # Panics
/// If the shapes differ.
pub fn normals_error(
    predicted: ArrayView3<f32>,
    depth: &DepthMap,
    camera: &PinholeCamera,
) -> Option<NormalsError> {
    let gt = normals_from_depth(depth, camera);
    let errors = angular_errors(predicted, gt.view());
    mean_and_median(&errors).map(|(mean_deg, median_deg)| NormalsError {
        pixels: errors.len(),
        mean_deg,
        median_deg,
    })
}

/// The keyframe's normals at level 0 (`rgb` is its image, used by `learned`).
///
/// # Errors
/// [`Error::InvalidArgument`] (flag `--normals`) for `gt` without ground-truth depth or `learned`
/// without weights; the errors of [`normals_file`], [`read_normals`] and [`load_predictor`].
pub fn keyframe_normals_level0(
    source: &NormalsSource,
    seq: &Sequence,
    keyframe: usize,
    rgb: ArrayView3<f32>,
    depth: Option<&DepthMap>,
    camera: &PinholeCamera,
) -> Result<Array3<f32>> {
    match source {
        NormalsSource::GroundTruth => {
            let depth = depth.ok_or_else(|| {
                Error::invalid_argument(
                    "--normals",
                    format!("gt: keyframe {keyframe} has no ground-truth depth to take normals from"),
                )
            })?;
            Ok(normals_from_depth(depth, camera))
        }
        NormalsSource::Dir(dir) => {
            read_normals(&normals_file(dir, seq, keyframe)?, camera.height, camera.width)
        }
        NormalsSource::Learned(weights) => {
            NormalNet::new(load_predictor(weights.as_deref())?)?.predict(rgb, camera)
        }
    }
}

/// The keyframe's normals at `level`: [`keyframe_normals_level0`], then [`normals_at_level`].
///
/// # Errors
/// As [`keyframe_normals_level0`].
pub fn keyframe_normals(
    source: &NormalsSource,
    seq: &Sequence,
    keyframe: usize,
    rgb: ArrayView3<f32>,
    depth: Option<&DepthMap>,
    camera: &PinholeCamera,
    level: u32,
) -> Result<Array3<f32>> {
    let level0 = keyframe_normals_level0(source, seq, keyframe, rgb, depth, camera)?;
    Ok(normals_at_level(level0.view(), level))
}
