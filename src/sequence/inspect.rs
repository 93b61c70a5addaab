//! A human-readable summary of an opened sequence: what was read, what the reader decided, and
//! whether the data is fit for monocular reconstruction (depth coverage, baselines, and the
//! photometric warp check of poses against depth). `densefeat inspect` prints it.

use std::fmt;
use std::path::PathBuf;

use super::text::image_format_name;
use super::{Format, Sequence, StereoInfo, WARNING_NOTE};
use crate::error::Result;
use crate::geometry::{relative_pose, PinholeCamera, RadTan};
use crate::image::is_valid_depth;
use crate::sequence::warp_check::{photometric_warp_check, WarpCheck};

/// Most frames whose depth is loaded for [`DepthStats`].
pub const DEPTH_SAMPLE_FRAMES: usize = 12;
/// Most frame pairs run through the photometric warp check.
pub const WARP_CHECK_PAIRS: usize = 6;
/// Largest frame offset of a warp-check pair `(i, i + offset)` (capped at `n - 1`).
pub const WARP_CHECK_OFFSET: usize = 5;
/// The offset is reduced until the pair's expected translation (offset x median consecutive
/// translation) is at most this fraction of the median depth. Beyond it, occlusions and pixels
/// leaving the view dominate the error rather than pose or depth mistakes: on hololens_000 (8 cm
/// per frame, 2.3 m median depth) offset 5 keeps only 30-60% of pixels in view.
pub const WARP_CHECK_MAX_PARALLAX: f64 = 0.1;
/// Below this median consecutive translation, metres, a sequence is called rotation-dominant.
pub const MIN_MEDIAN_TRANSLATION: f64 = 0.01;
/// Rotation-dominant also when the translational parallax `t / z` (median translation over median
/// depth, radians) is below this fraction of the median rotation angle: most image motion then
/// comes from rotation, which carries no depth information.
pub const MIN_PARALLAX_TO_ROTATION: f64 = 0.25;
/// The warp check should beat no warp at least this many times over; less suggests a wrong
/// camera, pose convention or depth scale.
pub const MIN_WARP_GAIN: f64 = 2.0;

/// Ground-truth depth over a subset of frames.
#[derive(Clone, Debug, PartialEq)]
pub struct DepthStats {
    /// Frames loaded.
    pub frames: usize,
    /// Fraction of pixels with valid depth.
    pub valid_fraction: f64,
    /// Smallest valid depth (metres, or baseline units for uncalibrated stereo).
    pub min: f64,
    /// Median valid depth.
    pub median: f64,
    /// Largest valid depth.
    pub max: f64,
}

/// Camera motion between consecutive frames.
#[derive(Clone, Debug, PartialEq)]
pub struct MotionStats {
    /// Median camera-centre translation, metres.
    pub median_translation: f64,
    /// Largest translation, metres.
    pub max_translation: f64,
    /// Median rotation angle, degrees.
    pub median_rotation_deg: f64,
    /// Extent of the camera centres along x, y, z, metres.
    pub extent: [f64; 3],
    /// Largest distance of a camera centre from frame 0's, metres.
    pub max_from_first: f64,
}

/// The photometric warp check over a few frame pairs.
#[derive(Clone, Debug, PartialEq)]
pub struct Consistency {
    /// `(reference, target, result)` per pair that could be checked.
    pub pairs: Vec<(usize, usize, WarpCheck)>,
    /// Median warped grey error.
    pub median_warped: f64,
    /// Median identity (no warp) grey error.
    pub median_identity: f64,
    /// Median warped grey error after a least-squares brightness fit (exposure changes removed).
    pub median_affine: f64,
}

impl Consistency {
    /// `median_identity / median_warped`.
    pub fn gain(&self) -> f64 {
        self.median_identity / self.median_warped.max(1e-12)
    }
}

/// Everything `densefeat inspect` reports about a sequence.
#[derive(Clone, Debug)]
pub struct Summary {
    /// Layout read.
    pub format: Format,
    /// Folder read.
    pub root: PathBuf,
    /// Number of frames.
    pub frames: usize,
    /// Colour image formats of the frames and how many of each, e.g. `[("JPEG", 50)]`.
    pub colour_formats: Vec<(String, usize)>,
    /// Camera of the loaded frames.
    pub camera: PinholeCamera,
    /// Number of distinct cameras (1 unless frames have their own intrinsics or sizes).
    pub cameras: usize,
    /// Distinct image sizes `(width, height)` and how many frames have each, most common first.
    pub sizes: Vec<((usize, usize), usize)>,
    /// Distortion of the raw files.
    pub distortion: Option<RadTan>,
    /// Whether frames are undistorted on load.
    pub undistorted: bool,
    /// Reader notes that are not warnings.
    pub notes: Vec<String>,
    /// Depth statistics (`None` when no sampled frame has depth).
    pub depth: Option<DepthStats>,
    /// Ground-truth disparity range per view, pixels (stereo only).
    pub disparity: Vec<(String, f32, f32)>,
    /// Consecutive-frame motion (non-stereo sequences with at least two frames).
    pub motion: Option<MotionStats>,
    /// Stereo facts.
    pub stereo: Option<StereoInfo>,
    /// Frames per second from timestamps, if any.
    pub frame_rate: Option<f64>,
    /// Photometric warp check.
    pub consistency: Option<Consistency>,
    /// Whether lengths are metres (`false`: COLMAP or `transforms.json` without depth, no `--scale`).
    pub metric: bool,
    /// Per-frame depth ranges from sparse points (COLMAP `points3D`).
    pub sparse_range: Option<SparseRangeStats>,
    /// Reader warnings and the summary's own.
    pub warnings: Vec<String>,
}

/// The per-frame sparse depth ranges over the sequence (`--depth-range auto`, SPEC.md §4a).
#[derive(Clone, Debug, PartialEq)]
pub struct SparseRangeStats {
    /// Frames that have one.
    pub frames: usize,
    /// Smallest and median `near`.
    pub near: (f64, f64),
    /// Median and largest `far`.
    pub far: (f64, f64),
}

fn sparse_range_stats(seq: &Sequence) -> Option<SparseRangeStats> {
    let (mut near, mut far): (Vec<f64>, Vec<f64>) =
        seq.frames.iter().filter_map(|f| f.sparse_depth_range).unzip();
    if near.is_empty() {
        return None;
    }
    let lo = near.iter().copied().fold(f64::INFINITY, f64::min);
    let hi = far.iter().copied().fold(0.0, f64::max);
    Some(SparseRangeStats {
        frames: near.len(),
        near: (lo, crate::runtime::median(&mut near)),
        far: (crate::runtime::median(&mut far), hi),
    })
}

/// How many frames have each colour image format, in order of first appearance.
fn colour_formats(seq: &Sequence) -> Vec<(String, usize)> {
    let mut out: Vec<(String, usize)> = Vec::new();
    for f in &seq.frames {
        let name = image_format_name(&f.rgb);
        match out.iter_mut().find(|(n, _)| *n == name) {
            Some((_, c)) => *c += 1,
            None => out.push((name, 1)),
        }
    }
    out
}

/// `k` indices spread evenly over `0..=last`.
fn spread(last: usize, k: usize) -> Vec<usize> {
    let k = k.min(last + 1).max(1);
    let mut v: Vec<usize> = (0..k).map(|i| if k == 1 { 0 } else { i * last / (k - 1) }).collect();
    v.dedup();
    v
}

impl Summary {
    /// Compute the summary; loads up to [`DEPTH_SAMPLE_FRAMES`] frames and `2 x` [`WARP_CHECK_PAIRS`].
    ///
    /// # Errors
    /// Any error loading a frame (naming the file).
    pub fn new(seq: &Sequence) -> Result<Self> {
        let mut warnings: Vec<String> = Vec::new();
        let mut notes = Vec::new();
        for n in &seq.notes {
            match n.strip_prefix(WARNING_NOTE) {
                Some(w) => warnings.push(w.to_string()),
                None => notes.push(n.clone()),
            }
        }
        let depth = depth_stats(seq)?;
        if seq.frames.iter().all(|f| f.depth.is_none()) {
            warnings.push("no ground-truth depth: the warp check and depth metrics cannot run".into());
        }
        let mut disparity = Vec::new();
        if seq.stereo.is_some() {
            for i in 0..seq.len() {
                if let Some(d) = seq.load_disparity(i)? {
                    let valid = d.iter().copied().filter(|v| *v > 0.0 && v.is_finite());
                    let (lo, hi) = valid.fold((f32::INFINITY, 0.0f32), |(a, b), v| (a.min(v), b.max(v)));
                    disparity.push((seq.frames[i].name.clone(), lo, hi));
                }
            }
        }
        let motion = if seq.stereo.is_none() { motion_stats(seq) } else { None };
        if let Some(m) = &motion {
            if m.median_translation < MIN_MEDIAN_TRANSLATION {
                warnings.push(format!(
                    "rotation-dominant: median baseline {} between consecutive frames (< {}); weak for monocular triangulation",
                    length(m.median_translation),
                    length(MIN_MEDIAN_TRANSLATION)
                ));
            } else if let Some(d) = &depth {
                let parallax = m.median_translation / d.median;
                let rot = m.median_rotation_deg.to_radians();
                if parallax < MIN_PARALLAX_TO_ROTATION * rot {
                    warnings.push(format!(
                        "rotation-dominant: translational parallax t/z = {parallax:.4} rad is under {MIN_PARALLAX_TO_ROTATION} x the median rotation {rot:.4} rad"
                    ));
                }
            }
        }
        let offset = warp_offset(seq.len(), motion.as_ref(), depth.as_ref());
        let consistency = consistency(seq, offset)?;
        if let Some(c) = &consistency {
            if c.gain() < MIN_WARP_GAIN {
                warnings.push(format!(
                    "pose/depth consistency gain {:.2} < {MIN_WARP_GAIN}: check the camera, the pose convention and the depth scale",
                    c.gain()
                ));
            }
        }
        let mut dts: Vec<f64> =
            seq.frames.windows(2).filter_map(|w| Some(w[1].timestamp? - w[0].timestamp?)).collect();
        let frame_rate = (!dts.is_empty()).then(|| 1.0 / crate::runtime::median(&mut dts));
        Ok(Self {
            format: seq.format,
            root: seq.root.clone(),
            frames: seq.len(),
            colour_formats: colour_formats(seq),
            camera: seq.camera,
            cameras: seq.raw_cameras.len(),
            sizes: frame_sizes(seq),
            distortion: seq.raw_camera.distortion,
            undistorted: seq.undistorts(),
            notes,
            depth,
            disparity,
            motion,
            stereo: seq.stereo.clone(),
            frame_rate,
            consistency,
            metric: seq.metric,
            sparse_range: sparse_range_stats(seq),
            warnings,
        })
    }
}

fn depth_stats(seq: &Sequence) -> Result<Option<DepthStats>> {
    let (mut values, mut pixels, mut frames) = (Vec::new(), 0usize, 0usize);
    for i in spread(seq.len() - 1, DEPTH_SAMPLE_FRAMES) {
        if seq.frames[i].depth.is_none() {
            continue;
        }
        if let Some(d) = seq.load_frame(i)?.depth {
            frames += 1;
            pixels += d.len();
            values.extend(d.iter().copied().filter(|&z| is_valid_depth(z)).map(f64::from));
        }
    }
    if values.is_empty() {
        return Ok(None);
    }
    let (min, max) = values.iter().fold((f64::INFINITY, 0.0f64), |(a, b), &v| (a.min(v), b.max(v)));
    let valid_fraction = values.len() as f64 / pixels as f64;
    Ok(Some(DepthStats { frames, valid_fraction, min, median: crate::runtime::median(&mut values), max }))
}

fn motion_stats(seq: &Sequence) -> Option<MotionStats> {
    if seq.len() < 2 {
        return None;
    }
    let (mut t, mut r) = (Vec::new(), Vec::new());
    for w in seq.frames.windows(2) {
        let rel = relative_pose(&w[0].pose, &w[1].pose);
        t.push(rel.translation.vector.norm());
        r.push(rel.rotation.angle().to_degrees());
    }
    let centres: Vec<_> = seq.frames.iter().map(|f| f.pose.translation.vector).collect();
    let mut extent = [0.0; 3];
    for (k, e) in extent.iter_mut().enumerate() {
        let (lo, hi) =
            centres.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), c| (a.min(c[k]), b.max(c[k])));
        *e = hi - lo;
    }
    let max_from_first = centres.iter().map(|c| (c - centres[0]).norm()).fold(0.0, f64::max);
    let max_translation = t.iter().copied().fold(0.0, f64::max);
    Some(MotionStats {
        median_translation: crate::runtime::median(&mut t),
        max_translation,
        median_rotation_deg: crate::runtime::median(&mut r),
        extent,
        max_from_first,
    })
}

/// [`WARP_CHECK_OFFSET`], reduced per [`WARP_CHECK_MAX_PARALLAX`]; at least 1.
fn warp_offset(n: usize, motion: Option<&MotionStats>, depth: Option<&DepthStats>) -> usize {
    let mut offset = WARP_CHECK_OFFSET.min(n.saturating_sub(1)).max(1);
    if let (Some(m), Some(d)) = (motion, depth) {
        while offset > 1 && offset as f64 * m.median_translation > WARP_CHECK_MAX_PARALLAX * d.median {
            offset -= 1;
        }
    }
    offset
}

fn consistency(seq: &Sequence, offset: usize) -> Result<Option<Consistency>> {
    if seq.len() < 2 {
        return Ok(None);
    }
    let mut pairs = Vec::new();
    for i in spread(seq.len() - 1 - offset, WARP_CHECK_PAIRS) {
        if seq.frames[i].depth.is_none() {
            continue;
        }
        let (r, t) = (seq.load_frame(i)?, seq.load_frame(i + offset)?);
        if let Ok(c) = photometric_warp_check(&r, &t) {
            pairs.push((i, i + offset, c));
        }
    }
    if pairs.is_empty() {
        return Ok(None);
    }
    let mut w: Vec<f64> = pairs.iter().map(|p| p.2.warped_error).collect();
    let mut id: Vec<f64> = pairs.iter().map(|p| p.2.identity_error).collect();
    let mut af: Vec<f64> = pairs.iter().map(|p| p.2.affine_error).collect();
    Ok(Some(Consistency {
        median_warped: crate::runtime::median(&mut w),
        median_identity: crate::runtime::median(&mut id),
        median_affine: crate::runtime::median(&mut af),
        pairs,
    }))
}

/// A length in metres in a readable unit.
fn length(m: f64) -> String {
    if m < 0.01 {
        format!("{:.1} mm", m * 1e3)
    } else if m < 1.0 {
        format!("{:.1} cm", m * 1e2)
    } else {
        format!("{m:.2} m")
    }
}

impl fmt::Display for Summary {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let k = &self.camera;
        writeln!(f, "sequence     {}", self.root.display())?;
        writeln!(f, "format       {}", self.format)?;
        if self.sizes.len() > 1 {
            // The four commonest sizes, then how many more.
            let mut sizes: Vec<String> =
                self.sizes.iter().take(4).map(|((w, h), n)| format!("{w}x{h} x{n}")).collect();
            if self.sizes.len() > 4 {
                sizes.push(format!("{} more", self.sizes.len() - 4));
            }
            writeln!(f, "frames       {} ({} sizes: {})", self.frames, self.sizes.len(), sizes.join(", "))?;
        } else {
            writeln!(f, "frames       {} ({}x{})", self.frames, k.width, k.height)?;
        }
        let colour: Vec<String> = self.colour_formats.iter().map(|(n, c)| format!("{n} x{c}")).collect();
        writeln!(f, "colour       {}", colour.join(", "))?;
        if self.cameras > 1 {
            writeln!(
                f,
                "cameras      {} (each frame is used with its own); frame 0: fx {} fy {} cx {} cy {}",
                self.cameras, k.fx, k.fy, k.cx, k.cy
            )?;
        } else {
            writeln!(f, "camera       fx {} fy {} cx {} cy {}", k.fx, k.fy, k.cx, k.cy)?;
        }
        match &self.distortion {
            Some(d) if !d.is_identity() => writeln!(
                f,
                "distortion   k1 {} k2 {} p1 {} p2 {} k3 {}; frames {}",
                d.k1,
                d.k2,
                d.p1,
                d.p2,
                d.k3,
                if self.undistorted { "undistorted on load" } else { "NOT undistorted (--no-undistort)" }
            )?,
            _ => writeln!(f, "distortion   none")?,
        }
        match self.frame_rate {
            Some(r) => writeln!(f, "frame rate   {r:.1} Hz (median timestamp interval)")?,
            None => writeln!(f, "frame rate   unknown (no timestamps)")?,
        }
        let unit = if self.stereo.as_ref().is_some_and(|s| !s.calibrated) {
            "baseline units"
        } else if !self.metric {
            "model units"
        } else {
            "m"
        };
        if self.metric {
            writeln!(f, "scale        metric (lengths in metres)")?;
        } else {
            writeln!(
                f,
                "scale        NONE: lengths in model units; --scale METRES_PER_UNIT makes them metres"
            )?;
        }
        match &self.depth {
            Some(d) => writeln!(
                f,
                "depth        {} frames sampled: {:.1}% valid, min {:.3} / median {:.3} / max {:.3} {unit}",
                d.frames,
                100.0 * d.valid_fraction,
                d.min,
                d.median,
                d.max
            )?,
            None => writeln!(f, "depth        none")?,
        }
        if let Some(r) = &self.sparse_range {
            writeln!(
                f,
                "sparse depth {} of {} frames: near min {:.3} / median {:.3}, far median {:.3} / max {:.3} {unit} (--depth-range auto)",
                r.frames, self.frames, r.near.0, r.near.1, r.far.0, r.far.1
            )?;
        }
        for (name, lo, hi) in &self.disparity {
            writeln!(f, "disparity    {name}: {lo:.2} .. {hi:.2} px")?;
        }
        if let Some(s) = &self.stereo {
            let cal = if s.calibrated { "calibrated" } else { "UNCALIBRATED (nominal camera)" };
            let b = if s.calibrated { length(s.baseline) } else { format!("{} baseline unit", s.baseline) };
            writeln!(f, "stereo       baseline {b}, doffs {} px, {cal}", s.doffs)?;
        }
        if let Some(m) = &self.motion {
            writeln!(
                f,
                "motion       consecutive frames: median {} / max {} translation, median {:.2} deg rotation",
                length(m.median_translation),
                length(m.max_translation),
                m.median_rotation_deg
            )?;
            writeln!(
                f,
                "trajectory   extent {:.2} x {:.2} x {:.2} m; farthest {} from frame 0",
                m.extent[0],
                m.extent[1],
                m.extent[2],
                length(m.max_from_first)
            )?;
        }
        match &self.consistency {
            Some(c) => {
                let pairs: Vec<String> = c.pairs.iter().map(|(i, j, _)| format!("{j}->{i}")).collect();
                writeln!(
                    f,
                    "consistency  pose/depth warp check over {} pairs ({}): median grey error {:.2} warped ({:.2} after a brightness fit) vs {:.2} identity, gain {:.2}x",
                    c.pairs.len(),
                    pairs.join(", "),
                    c.median_warped,
                    c.median_affine,
                    c.median_identity,
                    c.gain()
                )?;
            }
            None => writeln!(f, "consistency  not checked (needs depth and two frames)")?,
        }
        for n in &self.notes {
            writeln!(f, "note         {n}")?;
        }
        for w in &self.warnings {
            writeln!(f, "WARNING      {w}")?;
        }
        Ok(())
    }
}

/// Distinct frame sizes and their frame counts, most common first (ties by size).
fn frame_sizes(seq: &Sequence) -> Vec<((usize, usize), usize)> {
    let mut counts: std::collections::BTreeMap<(usize, usize), usize> = std::collections::BTreeMap::new();
    for i in 0..seq.len() {
        let c = seq.frame_camera(i);
        *counts.entry((c.width, c.height)).or_default() += 1;
    }
    let mut v: Vec<_> = counts.into_iter().collect();
    v.sort_by(|a, b| b.1.cmp(&a.1).then(a.0.cmp(&b.0)));
    v
}
