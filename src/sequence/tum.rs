//! TUM RGB-D reader (also ICL-NUIM's TUM-compatible release).
//!
//! ```text
//! rgb.txt, depth.txt   `timestamp filename` per line, `#` comments
//! groundtruth.txt      `timestamp tx ty tz qx qy qz qw` (~100 Hz motion capture, T_wc)
//! *.gt.freiburg        ICL-NUIM: `id tx ty tz qx qy qz qw`, ids matching the list "timestamps"
//! associations.txt     optional: `rgb_ts rgb_file depth_ts depth_file` (ICL-NUIM: depth first;
//!                      the rgb column is the one whose path starts with `rgb/`)
//! depth/*.png          16-bit, metres = value / 5000, 0 = no measurement
//! ```
//! Without `associations.txt`, each rgb frame takes the depth map with the nearest timestamp if it
//! is within [`OpenOptions::max_time_gap`] (a depth map may serve two rgb frames). Each frame's pose
//! is interpolated at its rgb timestamp between the two bracketing ground-truth samples (linear
//! translation, slerp rotation); frames outside the ground-truth time range, or between samples
//! more than [`OpenOptions::max_pose_gap`] apart, are dropped and counted in a note. Exact
//! timestamp matches (ICL-NUIM frame ids) need no bracketing.
//!
//! Undistortion (on by default) resamples colour and depth with the published distortion. Measured
//! on fr1/rpy it does not improve the photometric warp check (median gain 3.9 undistorted vs 4.1
//! raw, 4.5 with the ROS default camera): the Kinect driver registers depth to colour with its own
//! distortion-free model, as TUM notes when recommending the ROS default for registered depth.

use std::path::{Path, PathBuf};

use super::calib::{guess_from_text, resolve_camera, CameraChoice};
use super::text::{check_depth_png16, comment_and_data_lines, existing_file, stem, Line};
use super::{DepthSource, Format, FrameInfo, OpenOptions, Sequence, WARNING_NOTE};
use crate::error::{Error, Result};
use crate::geometry::{pose_from_tum, slerp_pose, Pose};
use crate::image::read_dimensions;

/// TUM depth PNGs store 5000 units per metre.
const TUM_DEPTH_UNITS_PER_METRE: f64 = 5000.0;

/// A `timestamp filename` entry.
#[derive(Clone, Debug)]
struct Stamped {
    t: f64,
    file: String,
    list: PathBuf,
    line: usize,
}

/// Why a frame got no pose.
enum NoPose {
    OutsideRange,
    GapTooLong,
}

pub(crate) fn read(root: &Path, opt: &OpenOptions) -> Result<Sequence> {
    let mut notes = Vec::new();
    let rgb_txt = root.join("rgb.txt");
    let assoc_txt = root.join("associations.txt");
    let mut header_text = String::new();

    // 1. rgb frames with their (optional) depth.
    let (pairs, list_desc) = if assoc_txt.is_file() {
        let (comments, lines) = comment_and_data_lines(&assoc_txt)?;
        header_text.push_str(&comments.join("\n"));
        (read_associations(&assoc_txt, &lines)?, "associations.txt".to_string())
    } else {
        let (comments, rgb) = read_list(&rgb_txt)?;
        header_text.push_str(&comments.join("\n"));
        let depth_txt = root.join("depth.txt");
        if !depth_txt.is_file() {
            notes.push(format!("{WARNING_NOTE}no depth.txt: frames have no ground-truth depth"));
            (rgb.into_iter().map(|r| (r, None)).collect(), "rgb.txt".to_string())
        } else {
            let (_, depth) = read_list(&depth_txt)?;
            (
                associate(&rgb_txt, rgb, &depth_txt, depth, opt.max_time_gap, &mut notes)?,
                "rgb.txt".to_string(),
            )
        }
    };
    if rgb_txt.is_file() && assoc_txt.is_file() {
        let (comments, _) = comment_and_data_lines(&rgb_txt)?;
        header_text.push('\n');
        header_text.push_str(&comments.join("\n"));
    }

    // 2. Ground truth and per-frame poses.
    let (gt_path, gt) = read_ground_truth(root)?;
    let n_pairs = pairs.len();
    let pairs_range = range(&pairs.iter().map(|p| p.0.clone()).collect::<Vec<_>>());
    let (mut outside, mut gap) = (0usize, 0usize);
    let mut frames = Vec::new();
    for (rgb, depth) in pairs {
        let pose = match interpolate(&gt, rgb.t, opt.max_pose_gap) {
            Ok(p) => p,
            Err(NoPose::OutsideRange) => {
                outside += 1;
                continue;
            }
            Err(NoPose::GapTooLong) => {
                gap += 1;
                continue;
            }
        };
        let rgb_path = existing_file(root, &rgb.file, &rgb.list, rgb.line)?;
        let depth = match depth {
            None => None,
            Some(d) => {
                let path = existing_file(root, &d.file, &d.list, d.line)?;
                check_depth_png16(&path)?;
                Some(DepthSource::Png16 {
                    path,
                    metres_per_unit: 1.0 / TUM_DEPTH_UNITS_PER_METRE,
                    invalid: None,
                })
            }
        };
        frames.push(FrameInfo {
            name: stem(&rgb_path),
            timestamp: Some(rgb.t),
            pose,
            rgb: rgb_path,
            depth,
            sparse_depth_range: None,
            camera: 0,
        });
    }
    if frames.is_empty() {
        let (g0, g1) = (gt.first().map_or(0.0, |g| g.0), gt.last().map_or(0.0, |g| g.0));
        return Err(Error::bad_sequence(
            root,
            format!(
                "no frame has a ground-truth pose: {} lists {pairs_range}, but {} has {} samples, \
                 t = {g0:.6}..{g1:.6} s ({outside} frames outside that range, {gap} between samples \
                 more than {} s apart)",
                root.join(&list_desc).display(),
                gt_path.display(),
                gt.len(),
                opt.max_pose_gap
            ),
        ));
    }
    if outside + gap > 0 {
        notes.push(format!(
            "{WARNING_NOTE}dropped {} of {n_pairs} frames without a ground-truth pose: {outside} outside \
             the range of {}, {gap} between samples more than {} s apart",
            outside + gap,
            gt_path.display(),
            opt.max_pose_gap
        ));
    }

    // 3. Camera.
    let size = read_dimensions(&frames[0].rgb)?;
    let choice = choose_camera(root, opt, &header_text, &gt_path, &mut notes);
    let camera = resolve_camera(&choice, size)?;
    Sequence::from_parts(Format::Tum, root.to_path_buf(), camera, frames, None, notes, opt.undistort)
}

fn choose_camera(
    root: &Path,
    opt: &OpenOptions,
    header: &str,
    gt_path: &Path,
    notes: &mut Vec<String>,
) -> CameraChoice {
    if let Some(c) = &opt.camera {
        notes.push(format!("camera: {c} (chosen by the caller)"));
        return c.clone();
    }
    let folder = std::fs::canonicalize(root).unwrap_or_else(|_| root.to_path_buf());
    let folder_name = folder.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    if let Some(c) = guess_from_text(&folder_name) {
        notes.push(format!("camera: {c} (from the folder name {folder_name:?})"));
        return c;
    }
    if let Some(line) = header.lines().find(|l| l.starts_with("file:") && guess_from_text(l).is_some()) {
        if let Some(c) = guess_from_text(line) {
            notes.push(format!("camera: {c} (from the header line `# {line}`)"));
            return c;
        }
    }
    if gt_path.extension().is_some_and(|e| e == "freiburg") {
        notes.push(format!(
            "camera: {} (ground truth is ICL-NUIM's {})",
            CameraChoice::Icl,
            gt_path.display()
        ));
        return CameraChoice::Icl;
    }
    notes.push(format!(
        "{WARNING_NOTE}camera unknown (no freiburg1/2/3 or ICL in the folder name or rgb.txt header): \
         guessed the ROS default 525 525 319.5 239.5; pass --camera fr1|fr2|fr3|icl|ros|FILE"
    ));
    CameraChoice::Ros
}

fn stamped(path: &Path, l: &Line, ts: usize, file: usize) -> Result<Stamped> {
    Ok(Stamped {
        t: l.float(path, ts, "timestamp")?,
        file: l.fields[file].clone(),
        list: path.into(),
        line: l.number,
    })
}

/// `timestamp filename` lines, sorted by time; also the comment lines.
fn read_list(path: &Path) -> Result<(Vec<String>, Vec<Stamped>)> {
    let (comments, lines) = comment_and_data_lines(path)?;
    let mut out = Vec::with_capacity(lines.len());
    for l in &lines {
        l.expect_at_least(path, 2, "`timestamp filename`")?;
        out.push(stamped(path, l, 0, 1)?);
    }
    if out.is_empty() {
        return Err(Error::bad_file(path, "lists no frames (only comments or blank lines)"));
    }
    out.sort_by(|a, b| a.t.total_cmp(&b.t));
    Ok((comments, out))
}

fn read_associations(path: &Path, lines: &[Line]) -> Result<Vec<(Stamped, Option<Stamped>)>> {
    let mut out = Vec::with_capacity(lines.len());
    for l in lines {
        l.expect_at_least(path, 4, "`rgb_ts rgb_file depth_ts depth_file`")?;
        let depth_first = l.fields[1].starts_with("depth") && l.fields[3].starts_with("rgb");
        let (r, d) = if depth_first { (2, 0) } else { (0, 2) };
        out.push((stamped(path, l, r, r + 1)?, Some(stamped(path, l, d, d + 1)?)));
    }
    if out.is_empty() {
        return Err(Error::bad_file(path, "lists no frames (only comments or blank lines)"));
    }
    out.sort_by(|a, b| a.0.t.total_cmp(&b.0.t));
    Ok(out)
}

fn range(v: &[Stamped]) -> String {
    match (v.first(), v.last()) {
        (Some(a), Some(b)) => format!("{} frames, t = {:.6}..{:.6} s", v.len(), a.t, b.t),
        _ => "no frames".into(),
    }
}

/// Nearest-timestamp association (both lists sorted).
fn associate(
    rgb_txt: &Path,
    rgb: Vec<Stamped>,
    depth_txt: &Path,
    depth: Vec<Stamped>,
    max_gap: f64,
    notes: &mut Vec<String>,
) -> Result<Vec<(Stamped, Option<Stamped>)>> {
    let (rgb_range, depth_range, n) = (range(&rgb), range(&depth), rgb.len());
    let mut out = Vec::with_capacity(n);
    for r in rgb {
        let i = depth.partition_point(|d| d.t < r.t);
        let best = [i.checked_sub(1), Some(i)]
            .into_iter()
            .flatten()
            .filter_map(|j| depth.get(j))
            .min_by(|a, b| (a.t - r.t).abs().total_cmp(&(b.t - r.t).abs()));
        if let Some(d) = best.filter(|d| (d.t - r.t).abs() <= max_gap) {
            let d = d.clone();
            out.push((r, Some(d)));
        }
    }
    if out.is_empty() {
        return Err(Error::bad_sequence(
            rgb_txt.parent().unwrap_or(rgb_txt),
            format!(
                "no rgb frame can be associated with a depth map within {max_gap} s: {} has {rgb_range}, \
                 {} has {depth_range}",
                rgb_txt.display(),
                depth_txt.display()
            ),
        ));
    }
    if out.len() < n {
        notes.push(format!(
            "{WARNING_NOTE}dropped {} of {n} rgb frames with no depth map within {max_gap} s",
            n - out.len()
        ));
    }
    Ok(out)
}

/// `groundtruth.txt`, else the folder's one `*.gt.freiburg`; samples sorted by time.
fn read_ground_truth(root: &Path) -> Result<(PathBuf, Vec<(f64, Pose)>)> {
    let mut path = root.join("groundtruth.txt");
    if !path.is_file() {
        let rd = std::fs::read_dir(root).map_err(|e| Error::io(root, e))?;
        let mut found: Vec<PathBuf> = rd
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.to_string_lossy().ends_with(".gt.freiburg"))
            .collect();
        found.sort();
        path = found.into_iter().next().ok_or_else(|| {
            Error::bad_sequence(root, "no ground truth: looked for groundtruth.txt and *.gt.freiburg")
        })?;
    }
    let (_, lines) = comment_and_data_lines(&path)?;
    let mut gt = Vec::with_capacity(lines.len());
    for l in &lines {
        l.expect_at_least(&path, 8, "`timestamp tx ty tz qx qy qz qw`")?;
        let t = l.float(&path, 0, "timestamp")?;
        let tr = l.floats::<3>(&path, 1, "translation")?;
        let q = l.floats::<4>(&path, 4, "quaternion")?;
        let pose = pose_from_tum(tr, q).map_err(|e| Error::parse(&path, l.number, e))?;
        gt.push((t, pose));
    }
    if gt.is_empty() {
        return Err(Error::bad_file(&path, "ground truth has no samples"));
    }
    gt.sort_by(|a, b| a.0.total_cmp(&b.0));
    Ok((path, gt))
}

/// The pose at time `t` from sorted samples.
fn interpolate(gt: &[(f64, Pose)], t: f64, max_gap: f64) -> Result<Pose, NoPose> {
    let i = gt.partition_point(|g| g.0 < t);
    if let Some(g) = gt.get(i).filter(|g| g.0 == t) {
        return Ok(g.1);
    }
    let (Some(a), Some(b)) = (i.checked_sub(1).and_then(|j| gt.get(j)), gt.get(i)) else {
        return Err(NoPose::OutsideRange);
    };
    if b.0 - a.0 > max_gap {
        return Err(NoPose::GapTooLong);
    }
    Ok(slerp_pose(&a.1, &b.1, (t - a.0) / (b.0 - a.0)))
}
