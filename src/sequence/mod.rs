//! Posed image sequences. Every reader yields one [`Sequence`]: per-frame metadata (file paths,
//! timestamps, camera-to-world poses) read eagerly and validated up front, pixels loaded on demand
//! with [`Sequence::load_frame`] (a 373-frame sequence would not fit in memory as `f32`).
//!
//! [`open`] detects the format of a folder and dispatches to its reader; [`inspect::Summary`]
//! describes an opened sequence.

use std::path::{Path, PathBuf};

use ndarray::Array2;

use crate::error::{Error, Result};
use crate::geometry::{Camera, PinholeCamera, Pose};
use crate::image::{self, DepthMap, RgbImage, UndistortMap};

/// The on-disk layout a sequence was read from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum Format {
    /// TUM RGB-D (`rgb.txt`, `depth.txt`, `groundtruth.txt` / `associations.txt`); also ICL-NUIM's
    /// TUM-compatible release.
    Tum,
    /// DeepVideoMVS / 7-Scenes style (`images/`, `depth/`, `poses.txt`, `K.txt`); also what the
    /// synthetic renderer writes.
    DeepVideoMvs,
    /// A rectified stereo pair (Middlebury, ETH3D) read as a two-frame sequence.
    Stereo,
    /// A COLMAP sparse model (`cameras`, `images`, optional `points3D`; text or binary) with its
    /// `images/` folder. Poses have no metric scale.
    Colmap,
    /// A nerfstudio / instant-ngp `transforms.json` (OpenGL camera axes).
    Nerfstudio,
    /// 7-Scenes as distributed: `frame-XXXXXX.color.png`, `.depth.png`, `.pose.txt`.
    SevenScenes,
    /// Record3D's "EXR + JPG" export: `metadata.json`, `rgb/<i>.jpg`, `depth/<i>.exr` (ARKit poses,
    /// OpenGL camera axes, metres).
    Record3d,
    /// ScanNet's SensReader export: `color/<i>.jpg`, `depth/<i>.png`, `pose/<i>.txt`, `intrinsic/`.
    ScanNet,
}

impl std::fmt::Display for Format {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Format::Tum => "TUM RGB-D",
            Format::DeepVideoMvs => "DeepVideoMVS / 7-Scenes",
            Format::Stereo => "rectified stereo pair",
            Format::Colmap => "COLMAP sparse model",
            Format::Nerfstudio => "nerfstudio / instant-ngp transforms.json",
            Format::SevenScenes => "7-Scenes (native layout)",
            Format::Record3d => "Record3D (EXR + JPG export)",
            Format::ScanNet => "ScanNet (SensReader export)",
        })
    }
}

/// How a stored disparity map encodes disparity in pixels.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum DisparityEncoding {
    /// 8- or 16-bit grey PNG, `d = value / scale`; 0 = unknown.
    ScaledPng {
        /// Divisor (Middlebury 2001/2003: per-scene 4, 8 or 16 in `info.txt`).
        scale: f64,
    },
    /// PFM float disparity; non-finite or `<= 0` = unknown.
    Pfm,
}

/// Where a frame's ground-truth depth comes from.
#[derive(Clone, Debug, PartialEq)]
pub enum DepthSource {
    /// A 16-bit grey PNG with `z = value * metres_per_unit`; 0 (and `invalid` if given) = no depth.
    Png16 {
        /// The file.
        path: PathBuf,
        /// Metres per stored unit (TUM 1/5000, millimetre formats 1/1000).
        metres_per_unit: f64,
        /// An extra "no depth" value (7-Scenes: 65535).
        invalid: Option<u16>,
    },
    /// A 16-bit grey PNG smaller than the colour images, with their aspect ratio (phone depth in
    /// `transforms.json`): `z = value * metres_per_unit`, 0 = no depth, upsampled to `width x height`
    /// by nearest neighbour with pixel centres aligned (colour pixel `x` reads depth pixel
    /// `round((x + 0.5) w_d / W - 0.5)`, likewise `y`; SPEC.md §4a).
    Png16Upsampled {
        /// The file.
        path: PathBuf,
        /// Metres per stored unit.
        metres_per_unit: f64,
        /// The camera's width.
        width: usize,
        /// The camera's height.
        height: usize,
    },
    /// A single-channel OpenEXR depth map (Record3D), `f16` or `f32`, `z = value * metres_per_unit`;
    /// non-finite or `<= 0` = no depth. Smaller than the colour images (phone depth), it is
    /// upsampled to `width x height` as [`DepthSource::Png16Upsampled`] is (SPEC.md §4a).
    Exr {
        /// The file.
        path: PathBuf,
        /// Metres per stored unit (1: Record3D stores metres; [`Sequence::rescale`] changes it).
        metres_per_unit: f64,
        /// The camera's width.
        width: usize,
        /// The camera's height.
        height: usize,
    },
    /// A 16-bit grey PNG from a depth camera that shares the colour camera's centre and axes but
    /// not its intrinsics (ScanNet): `z = value * metres_per_unit`, 0 = no depth, registered to the
    /// colour camera by nearest neighbour: colour pixel `(x, y)` reads depth pixel
    /// `(round(f'x (x - cx) / fx + c'x), round(f'y (y - cy) / fy + c'y))` (primes: the depth
    /// camera), 0 where that falls outside it (SPEC.md §4a).
    Png16Reprojected {
        /// The file.
        path: PathBuf,
        /// Metres per stored unit.
        metres_per_unit: f64,
        /// The depth camera (its size is the file's).
        depth_camera: PinholeCamera,
        /// The colour camera the depth is registered to.
        colour_camera: PinholeCamera,
    },
    /// A disparity map, converted with `z = focal_baseline / (d + doffs)` (`focal_baseline = f b`, in metres
    /// times pixels, or in baseline units when uncalibrated).
    Disparity {
        /// The file.
        path: PathBuf,
        /// How the file encodes disparity.
        encoding: DisparityEncoding,
        /// `f · b`.
        focal_baseline: f64,
        /// Disparity offset added before dividing: `z = f b / (d + doffs)`.
        doffs: f64,
    },
}

impl DepthSource {
    /// The file the depth is read from.
    pub fn path(&self) -> &Path {
        match self {
            DepthSource::Png16 { path, .. }
            | DepthSource::Png16Upsampled { path, .. }
            | DepthSource::Exr { path, .. }
            | DepthSource::Png16Reprojected { path, .. }
            | DepthSource::Disparity { path, .. } => path,
        }
    }
}

/// One frame's metadata.
#[derive(Clone, Debug, PartialEq)]
pub struct FrameInfo {
    /// A short name (file stem or timestamp).
    pub name: String,
    /// Capture time in seconds, where the format has one.
    pub timestamp: Option<f64>,
    /// Camera-to-world pose `T_wc` (metres).
    pub pose: Pose,
    /// The colour image.
    pub rgb: PathBuf,
    /// Ground-truth depth, if any.
    pub depth: Option<DepthSource>,
    /// Depth range `(near, far)` of the format's sparse points seen in this frame (COLMAP
    /// `points3D`, SPEC.md §4a), in the sequence's length unit; `None` where the format has none.
    pub sparse_depth_range: Option<(f64, f64)>,
    /// Which of [`Sequence::raw_cameras`] took this frame (0 for the one-camera formats).
    pub camera: usize,
}

/// Stereo-specific facts of a two-frame [`Format::Stereo`] sequence (frame 0 = left, 1 = right).
#[derive(Clone, Debug, PartialEq)]
pub struct StereoInfo {
    /// Baseline, metres (1 "baseline unit" when uncalibrated).
    pub baseline: f64,
    /// Whether focal length and baseline come from a calibration file. When `false`, depths are in
    /// baseline units with a nominal focal length and only disparity-space evaluation is meaningful.
    pub calibrated: bool,
    /// Disparity offset `doffs` (Middlebury 2014 / ETH3D `calib.txt`), pixels; `z = f b / (d + doffs)`.
    pub doffs: f64,
}

/// A posed image sequence: one camera, or one per frame (SPEC.md §4a: each frame may have its own
/// intrinsics and image size; [`FrameInfo::camera`] says which).
#[derive(Clone, Debug)]
pub struct Sequence {
    /// Layout it was read from.
    pub format: Format,
    /// The folder it was read from.
    pub root: PathBuf,
    /// The camera of frame 0's images as [`Sequence::load_frame`] returns them (undistorted when the
    /// raw images were distorted and undistortion is on). With several cameras, use
    /// [`Sequence::frame_camera`] for any other frame.
    pub camera: PinholeCamera,
    /// The camera of frame 0's raw image files, with its distortion.
    pub raw_camera: Camera,
    /// Every distinct camera of the sequence (raw, with distortion), indexed by
    /// [`FrameInfo::camera`]; one element for the one-camera formats.
    pub raw_cameras: Vec<Camera>,
    /// Frames in capture order.
    pub frames: Vec<FrameInfo>,
    /// Present for stereo pairs.
    pub stereo: Option<StereoInfo>,
    /// Whether lengths (pose translations, depths) are metres: `false` for formats without a metric
    /// scale (COLMAP, `transforms.json` without depth) unless [`OpenOptions::scale`] was given.
    pub metric: bool,
    /// What the reader decided on the user's behalf (calibration used, frames dropped, ...). Notes
    /// starting with [`WARNING_NOTE`] are warnings.
    pub notes: Vec<String>,
    /// Undistortion maps of the distorted cameras (by camera index), when undistortion is on.
    undistort: Vec<Option<UndistortMap>>,
}

/// A loaded frame.
#[derive(Clone, Debug)]
pub struct Frame {
    /// Index in the sequence.
    pub index: usize,
    /// Colour, `[H, W, 3]`, `0..=255`, in the sequence's (undistorted) camera.
    pub rgb: RgbImage,
    /// Depth in metres, `0` = invalid, in the same camera.
    pub depth: Option<DepthMap>,
    /// Camera-to-world pose `T_wc`.
    pub pose: Pose,
    /// The (undistorted) camera of this frame's images.
    pub camera: PinholeCamera,
}

impl Sequence {
    /// Assemble a one-camera sequence from a reader's parts and validate it: at least one frame,
    /// every colour and depth file present with the camera's size (read from the headers). With
    /// `undistort`, frames are resampled into the pinhole camera when `raw_camera` has distortion.
    ///
    /// # Errors
    /// [`Error::BadSequence`] for an empty sequence, [`Error::Io`] for a missing file,
    /// [`Error::BadFile`] for an image whose size differs from the camera's.
    pub fn from_parts(
        format: Format,
        root: PathBuf,
        raw_camera: Camera,
        frames: Vec<FrameInfo>,
        stereo: Option<StereoInfo>,
        notes: Vec<String>,
        undistort: bool,
    ) -> Result<Self> {
        Self::from_cameras(format, root, vec![raw_camera], frames, stereo, notes, undistort)
    }

    /// [`Sequence::from_parts`] with one camera per [`FrameInfo::camera`] index: each frame's files
    /// must have its own camera's size.
    ///
    /// # Errors
    /// As [`Sequence::from_parts`]; [`Error::BadSequence`] when a frame names a camera that
    /// `raw_cameras` lacks.
    pub fn from_cameras(
        format: Format,
        root: PathBuf,
        raw_cameras: Vec<Camera>,
        frames: Vec<FrameInfo>,
        stereo: Option<StereoInfo>,
        notes: Vec<String>,
        undistort: bool,
    ) -> Result<Self> {
        if frames.is_empty() {
            return Err(Error::bad_sequence(&root, "the sequence has no frames"));
        }
        for f in &frames {
            let Some(raw) = raw_cameras.get(f.camera) else {
                return Err(Error::bad_sequence(
                    &root,
                    format!("frame {} uses camera {} of {}", f.name, f.camera, raw_cameras.len()),
                ));
            };
            let k = raw.pinhole;
            let mut files = vec![f.rgb.as_path()];
            if let Some(d) = &f.depth {
                files.push(d.path());
            }
            for path in files {
                if d_is_pfm(path)
                    || matches!(
                        &f.depth,
                        Some(
                            DepthSource::Png16Upsampled { path: p, .. }
                                | DepthSource::Exr { path: p, .. }
                                | DepthSource::Png16Reprojected { path: p, .. }
                        ) if p == path
                    )
                {
                    // PFM sizes are checked when loaded; upsampled, reprojected and EXR depth by its
                    // reader.
                    continue;
                }
                let (w, h) = image::read_dimensions(path)?;
                if (w, h) != (k.width, k.height) {
                    return Err(Error::bad_file(
                        path,
                        format!("image is {w}x{h}, but its camera is {}x{}", k.width, k.height),
                    ));
                }
            }
        }
        let maps = raw_cameras
            .iter()
            .map(|c| match (&c.distortion, undistort) {
                (Some(d), true) if !d.is_identity() => Some(UndistortMap::new(&c.pinhole, d)),
                _ => None,
            })
            .collect();
        let raw_camera = raw_cameras[frames[0].camera];
        Ok(Self {
            format,
            root,
            camera: raw_camera.pinhole,
            raw_camera,
            raw_cameras,
            frames,
            stereo,
            metric: true,
            notes,
            undistort: maps,
        })
    }

    /// The (undistorted) camera of frame `index`'s images: [`Sequence::camera`] for one-camera
    /// sequences.
    ///
    /// # Panics
    /// If `index` is out of range.
    pub fn frame_camera(&self, index: usize) -> PinholeCamera {
        self.raw_cameras[self.frames[index].camera].pinhole
    }

    /// The raw camera (with distortion) of frame `index`.
    ///
    /// # Panics
    /// If `index` is out of range.
    pub fn frame_raw_camera(&self, index: usize) -> &Camera {
        &self.raw_cameras[self.frames[index].camera]
    }

    /// Whether every frame has the same camera (intrinsics and size).
    pub fn single_camera(&self) -> bool {
        let first = self.frame_camera(0);
        (0..self.len()).all(|i| self.frame_camera(i) == first)
    }

    /// The one camera of the sequence, for work that needs one (training crops, the photometric
    /// check of `inspect`).
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] naming `what` when frames have different cameras.
    pub fn the_camera(&self, what: &str) -> Result<PinholeCamera> {
        if self.single_camera() {
            Ok(self.camera)
        } else {
            Err(Error::invalid_argument(
                what,
                format!(
                    "{} has {} cameras (per-frame intrinsics or image sizes); this needs one camera",
                    self.root.display(),
                    self.raw_cameras.len()
                ),
            ))
        }
    }

    /// Number of frames.
    pub fn len(&self) -> usize {
        self.frames.len()
    }

    /// Whether there are no frames (never true for a constructed sequence).
    pub fn is_empty(&self) -> bool {
        self.frames.is_empty()
    }

    /// Multiply every length by `scale` (pose translations, depth units, disparity `f b`, sparse
    /// depth ranges, stereo baseline) and mark the sequence metric: `--scale` (SPEC.md §4a).
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] unless `scale` is finite and positive.
    pub fn rescale(&mut self, scale: f64) -> Result<()> {
        if !(scale.is_finite() && scale > 0.0) {
            return Err(Error::invalid_argument("--scale", format!("{scale}: must be a finite number > 0")));
        }
        for f in &mut self.frames {
            f.pose.translation.vector *= scale;
            f.sparse_depth_range = f.sparse_depth_range.map(|(a, b)| (a * scale, b * scale));
            match &mut f.depth {
                Some(
                    DepthSource::Png16 { metres_per_unit, .. }
                    | DepthSource::Png16Upsampled { metres_per_unit, .. }
                    | DepthSource::Png16Reprojected { metres_per_unit, .. }
                    | DepthSource::Exr { metres_per_unit, .. },
                ) => *metres_per_unit *= scale,
                Some(DepthSource::Disparity { focal_baseline, .. }) => *focal_baseline *= scale,
                None => {}
            }
        }
        if let Some(s) = &mut self.stereo {
            s.baseline *= scale;
        }
        self.metric = true;
        self.notes.push(format!("lengths scaled by {scale} (--scale): poses and depths are in metres"));
        Ok(())
    }

    /// Whether frames are undistorted on load.
    pub fn undistorts(&self) -> bool {
        self.undistort.iter().any(Option::is_some)
    }

    /// Load frame `index`: colour, depth (if any) and pose, in [`Sequence::camera`].
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] for an index out of range; any image error naming the file.
    pub fn load_frame(&self, index: usize) -> Result<Frame> {
        self.load(index, true)
    }

    /// [`Sequence::load_frame`] without the depth (`Frame::depth` is `None`): what a live frame of
    /// the mapper needs. The depth file is neither read nor checked.
    ///
    /// # Errors
    /// As [`Sequence::load_frame`], for the colour image.
    pub fn load_frame_rgb(&self, index: usize) -> Result<Frame> {
        self.load(index, false)
    }

    fn load(&self, index: usize, with_depth: bool) -> Result<Frame> {
        let info = self.frames.get(index).ok_or_else(|| {
            Error::invalid_argument(
                "frame index",
                format!("{index} is out of range: the sequence has {} frames", self.len()),
            )
        })?;
        let rgb = image::load_rgb(&info.rgb)?;
        self.check_size(index, &info.rgb, rgb.dim().0, rgb.dim().1)?;
        let depth = match &info.depth {
            Some(src) if with_depth => {
                let d = load_depth(src)?;
                self.check_size(index, src.path(), d.dim().0, d.dim().1)?;
                Some(d)
            }
            _ => None,
        };
        let (rgb, depth) = match &self.undistort[info.camera] {
            Some(map) => (map.rgb(&rgb), depth.map(|d| map.depth(&d))),
            None => (rgb, depth),
        };
        Ok(Frame { index, rgb, depth, pose: info.pose, camera: self.frame_camera(index) })
    }

    /// Load frame `index`'s ground-truth disparity in pixels (stereo sequences only; 0 = unknown).
    ///
    /// # Errors
    /// As [`Sequence::load_frame`].
    pub fn load_disparity(&self, index: usize) -> Result<Option<Array2<f32>>> {
        match self.frames.get(index).and_then(|f| f.depth.as_ref()) {
            Some(DepthSource::Disparity { path, encoding, .. }) => {
                let d = crate::sequence::disparity::load_disparity(path, *encoding)?;
                self.check_size(index, path, d.dim().0, d.dim().1)?;
                Ok(Some(d))
            }
            _ => Ok(None),
        }
    }

    fn check_size(&self, index: usize, path: &Path, h: usize, w: usize) -> Result<()> {
        let k = &self.frame_raw_camera(index).pinhole;
        if (w, h) != (k.width, k.height) {
            return Err(Error::bad_file(
                path,
                format!("image is {w}x{h}, but its camera is {}x{}", k.width, k.height),
            ));
        }
        Ok(())
    }
}

fn d_is_pfm(path: &Path) -> bool {
    path.extension().is_some_and(|e| e.eq_ignore_ascii_case("pfm"))
}

/// Load any depth source as metres (`0` = invalid).
///
/// # Errors
/// Any image error naming the file.
pub fn load_depth(src: &DepthSource) -> Result<DepthMap> {
    match src {
        DepthSource::Png16 { path, metres_per_unit, invalid } => {
            image::load_depth_png(path, *metres_per_unit, *invalid)
        }
        DepthSource::Png16Upsampled { path, metres_per_unit, width, height } => {
            let d = image::load_depth_png(path, *metres_per_unit, None)?;
            Ok(upsample_nearest(&d, *width, *height))
        }
        DepthSource::Exr { path, metres_per_unit, width, height } => {
            // Depth is never larger than the colour image it is upsampled to.
            let d = image::load_depth_exr(path, *width, *height)?;
            let d =
                if *metres_per_unit == 1.0 { d } else { d.mapv(|z| (f64::from(z) * metres_per_unit) as f32) };
            Ok(upsample_nearest(&d, *width, *height))
        }
        DepthSource::Png16Reprojected { path, metres_per_unit, depth_camera: d, colour_camera: c } => {
            let z = image::load_depth_png(path, *metres_per_unit, None)?;
            if z.dim() != (d.height, d.width) {
                return Err(Error::bad_file(
                    path,
                    format!(
                        "depth image is {}x{}, but its camera is {}x{}",
                        z.dim().1,
                        z.dim().0,
                        d.width,
                        d.height
                    ),
                ));
            }
            Ok(reproject_nearest(&z, d, c))
        }
        DepthSource::Disparity { path, encoding, focal_baseline, doffs } => {
            let d = disparity::load_disparity(path, *encoding)?;
            Ok(d.mapv(|v| {
                let den = v as f64 + doffs;
                if v > 0.0 && v.is_finite() && den > 0.0 {
                    (*focal_baseline / den) as f32
                } else {
                    0.0
                }
            }))
        }
    }
}

/// Depth `z` of camera `d` registered to camera `c` of the same centre and axes, by nearest
/// neighbour: colour pixel `(x, y)` reads `z` at `(round(d.fx (x - c.cx) / c.fx + d.cx),
/// round(d.fy (y - c.cy) / c.fy + d.cy))` (half away from zero), 0 outside it.
pub fn reproject_nearest(z: &DepthMap, d: &PinholeCamera, c: &PinholeCamera) -> DepthMap {
    let (hd, wd) = z.dim();
    let src = |v: f64, f_d: f64, c_d: f64, f_c: f64, c_c: f64, n: usize| {
        let s = (f_d * (v - c_c) / f_c + c_d).round();
        (s >= 0.0 && s <= (n - 1) as f64).then_some(s as usize)
    };
    Array2::from_shape_fn((c.height, c.width), |(y, x)| {
        match (src(x as f64, d.fx, d.cx, c.fx, c.cx, wd), src(y as f64, d.fy, d.cy, c.fy, c.cy, hd)) {
            (Some(u), Some(v)) => z[[v, u]],
            _ => 0.0,
        }
    })
}

/// `d` resampled to `width x height` by nearest neighbour with pixel centres aligned: output pixel
/// `x` reads `round((x + 0.5) w_d / width - 0.5)` (half away from zero, clamped), likewise `y`.
pub fn upsample_nearest(d: &DepthMap, width: usize, height: usize) -> DepthMap {
    let (hd, wd) = d.dim();
    let src = |x: usize, n_out: usize, n_in: usize| {
        let s = ((x as f64 + 0.5) * n_in as f64 / n_out as f64 - 0.5).round();
        (s.max(0.0) as usize).min(n_in - 1)
    };
    Array2::from_shape_fn((height, width), |(y, x)| d[[src(y, height, hd), src(x, width, wd)]])
}

pub mod calib;
pub mod colmap;
pub mod depth_range;
mod detect;
pub mod disparity;
mod dvmvs;
mod dvmvs_write;
pub mod inspect;
mod nerfstudio;
pub mod nerfstudio_write;
mod record3d;
mod scannet;
mod sevenscenes;
pub mod sevenscenes_write;
mod stereo;
mod text;
mod tum;
pub mod warp_check;

pub use calib::{read_camera_file, CameraChoice};
pub use detect::{detect, open, open_with, OpenOptions, DEFAULT_MAX_POSE_GAP, DEFAULT_MAX_TIME_GAP};
pub use dvmvs_write::{frame_file_name, DvmvsWriter};
pub use text::{image_format_name, COLOUR_EXTENSIONS};

/// Prefix of the [`Sequence::notes`] that are warnings (dropped frames, guessed camera, missing
/// depth, uncalibrated stereo); `densefeat inspect` lists them as warnings.
pub const WARNING_NOTE: &str = "warning: ";
