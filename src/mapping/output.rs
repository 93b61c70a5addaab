//! Files written for a reconstructed keyframe (SPEC.md §11.4). Every file is written atomically
//! (temporary name, then rename: [`crate::io`]).
//!
//! For each estimate `E` (`wta`, `tv`): `depth_E.npy` (`[H, W]` `<f4`, metres, 0 = invalid),
//! `depth_E.pfm` (the same values), `depth_E_mm.png` (16-bit grey, millimetres),
//! `depth_E_color.png` (turbo colour map on inverse depth with a legend in metres, invalid black) and
//! `cloud_E.ply` (binary little-endian coloured points in the keyframe camera frame). Also
//! `keyframe.png` (colour at level `L`), `depth_gt_color.png` and `metrics.json` when there is
//! ground truth.

use std::io::Write;
use std::path::{Path, PathBuf};

use ndarray::{Array3, ArrayView2};
use serde_json::json;

use crate::error::{Error, Result};
use crate::image::{is_valid_depth, save_depth_png_mm, save_rgb_png};
use crate::io::{write_atomic_with, write_npy_f32};
use crate::mapping::keyframe::{DepthEstimate, KeyframeResult};

/// Default `--min-confidence` (chosen on validation scenes, SPEC.md §9.12).
pub const DEFAULT_MIN_CONFIDENCE: f32 = 0.1;

/// [`write_outputs_with`] at full coverage (no confidence mask).
///
/// # Errors
/// [`Error::Io`] naming the file on a write failure.
pub fn write_outputs(result: &KeyframeResult, dir: &Path) -> Result<Vec<PathBuf>> {
    write_outputs_with(result, dir, 0.0)
}

/// Write every output of `result` into `dir` (created if missing), depth maps and point clouds
/// masked (depth 0) where the confidence is below `min_confidence`; returns the paths written.
/// `confidence.npy` / `confidence.png` hold the unmasked confidence map, and `metrics.json` the
/// metrics at `min_confidence` and at full coverage.
///
/// # Errors
/// [`Error::Io`] naming the file on a write failure.
pub fn write_outputs_with(result: &KeyframeResult, dir: &Path, min_confidence: f32) -> Result<Vec<PathBuf>> {
    std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    let mut written = Vec::new();
    let mut push = |p: PathBuf| {
        written.push(p.clone());
        p
    };
    save_rgb_png(&push(dir.join("keyframe.png")), &result.colour)?;
    let (near, far) = colour_range(result);
    let mut full: Vec<(&str, &DepthEstimate)> = vec![("wta", &result.wta)];
    if let Some(tv) = &result.tv {
        full.push((result.tv_name(), tv));
    }
    if let Some(n) = &result.normals {
        full.push(("normals", n));
    }
    let masked: Vec<DepthEstimate> = full.iter().map(|(_, e)| result.masked(e, min_confidence)).collect();
    let estimates: Vec<(&str, &DepthEstimate)> = full.iter().map(|(n, _)| *n).zip(masked.iter()).collect();
    write_npy_f32(&push(dir.join("confidence.npy")), result.confidence.view())?;
    let conf_pic =
        Array3::from_shape_fn((result.confidence.nrows(), result.confidence.ncols(), 3), |(y, x, _)| {
            (result.confidence[[y, x]] * 255.0).round()
        });
    save_rgb_png(&push(dir.join("confidence.png")), &conf_pic)?;
    for (name, e) in &estimates {
        write_npy_f32(&push(dir.join(format!("depth_{name}.npy"))), e.depth.view())?;
        write_pfm(&push(dir.join(format!("depth_{name}.pfm"))), e.depth.view())?;
        save_depth_png_mm(&push(dir.join(format!("depth_{name}_mm.png"))), &e.depth)?;
        let pic = colour_depth_with_legend(e.depth.view(), near, far);
        save_rgb_png(&push(dir.join(format!("depth_{name}_color.png"))), &pic)?;
        write_ply(&push(dir.join(format!("cloud_{name}.ply"))), result, e)?;
    }
    if let Some(gt) = &result.gt_depth {
        let pic = colour_depth_with_legend(gt.view(), near, far);
        save_rgb_png(&push(dir.join("depth_gt_color.png")), &pic)?;
        let mut metrics = serde_json::Map::new();
        for (name, e) in &full {
            metrics.insert(name.to_string(), serde_json::to_value(result.metrics(e)?).expect("plain data"));
            if let Ok(m) = result.metrics_at(e, min_confidence) {
                metrics.insert(format!("{name}_confident"), serde_json::to_value(m).expect("plain data"));
            }
        }
        let doc = json!({
            "keyframe": result.keyframe,
            "live_frames": result.live_frames,
            "features": result.features,
            "level": result.level,
            "size": [result.camera.width, result.camera.height],
            "bins": result.bins.count,
            "depth_range_m": [1.0 / result.bins.rho_max, 1.0 / result.bins.rho_min],
            "colour_range_m": [near, far],
            "metrics": metrics,
            "min_confidence": min_confidence,
            "cost_scale": result.cost_scale,
            "truncation": (result.truncation < crate::costvolume::NO_TRUNCATION).then_some(result.truncation),
            "timings_s": result.timings,
            "dtam": result.dtam.as_ref().map(|r| json!({
                "iterations": r.iterations,
                "converged": r.converged,
                "last_gap": r.gap.last(),
                "first_energy": r.energy.first(),
                "last_energy": r.energy.last(),
                "seconds": r.seconds,
            })),
            "memory_estimate_bytes": result.memory_estimate,
            "photometric": result.photometric,
            "refined": result.refined,
        });
        let text = serde_json::to_string_pretty(&doc).expect("plain data");
        write_atomic_with(&push(dir.join("metrics.json")), |w| w.write_all(text.as_bytes()))?;
    }
    Ok(written)
}

/// Write `[H, W]` f32 as a grey PFM (`Pf`, scale `-1` = little-endian, rows bottom to top),
/// atomically.
///
/// # Errors
/// [`Error::Io`] naming `path`.
pub fn write_pfm(path: &Path, a: ArrayView2<f32>) -> Result<()> {
    let (h, w) = a.dim();
    write_atomic_with(path, |out| {
        write!(out, "Pf\n{w} {h}\n-1.0\n")?;
        for y in (0..h).rev() {
            for x in 0..w {
                out.write_all(&a[[y, x]].to_le_bytes())?;
            }
        }
        Ok(())
    })
}

/// Write the valid pixels of `e` as a binary little-endian PLY: `x y z` float (metres, keyframe
/// camera frame: x right, y down, z forward) and `red green blue` uchar from the keyframe colour.
///
/// # Errors
/// [`Error::Io`] naming `path`.
pub fn write_ply(path: &Path, result: &KeyframeResult, e: &DepthEstimate) -> Result<()> {
    let cam = &result.camera;
    let mut points = Vec::new();
    for ((y, x), &z) in e.depth.indexed_iter() {
        if !is_valid_depth(z) {
            continue;
        }
        let p = cam.backproject(x as f64, y as f64, 1.0 / z as f64);
        let c = |k: usize| result.colour[[y, x, k]].round().clamp(0.0, 255.0) as u8;
        points.push(([p.x as f32, p.y as f32, p.z as f32], [c(0), c(1), c(2)]));
    }
    write_atomic_with(path, |out| {
        write!(
            out,
            "ply\nformat binary_little_endian 1.0\ncomment densefeat keyframe {} level {} ({}), metres, \
             keyframe camera frame\nelement vertex {}\nproperty float x\nproperty float y\n\
             property float z\nproperty uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n",
            result.keyframe,
            result.level,
            result.features,
            points.len()
        )?;
        for (p, c) in &points {
            for v in p {
                out.write_all(&v.to_le_bytes())?;
            }
            out.write_all(c)?;
        }
        Ok(())
    })
}

/// Google's Turbo colour map, `t` in `[0, 1]`, as Ruofei Du's polynomial approximation
/// (<https://www.shadertoy.com/view/3lBXR3>; Turbo by Anton Mikhailov, Apache-2.0). Returns 0-255.
pub fn turbo(t: f64) -> [f32; 3] {
    const R: [f64; 6] = [0.13572138, 4.61539260, -42.66032258, 132.13108234, -152.94239396, 59.28637943];
    const G: [f64; 6] = [0.09140261, 2.19418839, 4.84296658, -14.18503333, 4.27729857, 2.82956604];
    const B: [f64; 6] = [0.10667330, 12.64194608, -60.58204836, 110.36276771, -89.90310912, 27.34824973];
    let t = t.clamp(0.0, 1.0);
    let poly = |c: &[f64; 6]| {
        let v = c.iter().rev().fold(0.0, |acc, &k| acc * t + k);
        (v.clamp(0.0, 1.0) * 255.0) as f32
    };
    [poly(&R), poly(&G), poly(&B)]
}

/// Depth range of the colour maps: the 2nd to 98th percentile of the valid ground-truth depths
/// (else of the regularised, else the WTA estimate), within the search range; the same for every
/// picture of a keyframe so that they can be compared.
pub fn colour_range(result: &KeyframeResult) -> (f64, f64) {
    let (lo, hi) = (1.0 / result.bins.rho_max, 1.0 / result.bins.rho_min);
    let source = result.gt_depth.as_ref().unwrap_or(&result.best().depth);
    let mut z: Vec<f32> = source.iter().copied().filter(|&v| is_valid_depth(v)).collect();
    if z.len() < 2 {
        return (lo, hi.min(lo * 100.0));
    }
    z.sort_by(f32::total_cmp);
    let pick = |q: f64| z[((z.len() - 1) as f64 * q).round() as usize] as f64;
    let (near, far) = (pick(0.02).max(lo), pick(0.98).min(hi));
    if near < far {
        (near, far)
    } else {
        (lo, hi.min(lo * 100.0))
    }
}

/// Colour of depth `z` on the map: turbo of `(1/z - 1/far) / (1/near - 1/far)` (near red, far blue).
pub(crate) fn depth_colour(z: f64, near: f64, far: f64) -> [f32; 3] {
    let (lo, hi) = (1.0 / far, 1.0 / near);
    turbo((1.0 / z - lo) / (hi - lo))
}

/// Width of the legend panel right of the picture, pixels.
const LEGEND_WIDTH: usize = 56;

/// A colour-mapped depth picture (invalid pixels black) with a legend to its right: a colour bar
/// over `[near, far]` (uniform in inverse depth, near at the top) and tick labels in metres.
pub fn colour_depth_with_legend(depth: ArrayView2<f32>, near: f64, far: f64) -> Array3<f32> {
    let (h, w) = depth.dim();
    let height = h.max(40);
    let mut img = Array3::from_elem((height, w + LEGEND_WIDTH, 3), 255.0f32);
    for y in 0..height {
        for x in 0..w {
            let c = match depth.get((y, x)) {
                Some(&z) if is_valid_depth(z) => depth_colour(z as f64, near, far),
                _ => [0.0; 3],
            };
            for k in 0..3 {
                img[[y, x, k]] = c[k];
            }
        }
    }
    // Bar: columns w+4 .. w+12, rows 4 .. height-4, inverse depth from 1/near (top) to 1/far.
    let (top, bottom) = (4usize, height - 5);
    let (lo, hi) = (1.0 / far, 1.0 / near);
    let rho_at = |y: usize| hi - (hi - lo) * (y - top) as f64 / (bottom - top) as f64;
    for y in top..=bottom {
        let c = turbo((rho_at(y) - lo) / (hi - lo));
        for x in w + 4..w + 12 {
            for k in 0..3 {
                img[[y, x, k]] = c[k];
            }
        }
    }
    let ticks = ((bottom - top) / 12).clamp(2, 5);
    for i in 0..ticks {
        let y = top + (bottom - top) * i / (ticks - 1);
        for x in w + 12..w + 15 {
            set_black(&mut img, y, x);
        }
        let z = 1.0 / rho_at(y);
        let label = if z.is_finite() {
            if z < 10.0 {
                format!("{z:.2}m")
            } else {
                format!("{z:.1}m")
            }
        } else {
            "inf".to_string()
        };
        let ty = y.saturating_sub(3).min(height - 7);
        draw_text(&mut img, w + 16, ty, &label);
    }
    img
}

fn set_black(img: &mut Array3<f32>, y: usize, x: usize) {
    if y < img.dim().0 && x < img.dim().1 {
        for k in 0..3 {
            img[[y, x, k]] = 0.0;
        }
    }
}

/// 5x7 glyphs, one row per byte, bit 4 = leftmost column.
fn glyph(c: char) -> Option<[u8; 7]> {
    Some(match c {
        '0' => [0x0e, 0x11, 0x13, 0x15, 0x19, 0x11, 0x0e],
        '1' => [0x04, 0x0c, 0x04, 0x04, 0x04, 0x04, 0x0e],
        '2' => [0x0e, 0x11, 0x01, 0x02, 0x04, 0x08, 0x1f],
        '3' => [0x1f, 0x02, 0x04, 0x02, 0x01, 0x11, 0x0e],
        '4' => [0x02, 0x06, 0x0a, 0x12, 0x1f, 0x02, 0x02],
        '5' => [0x1f, 0x10, 0x1e, 0x01, 0x01, 0x11, 0x0e],
        '6' => [0x06, 0x08, 0x10, 0x1e, 0x11, 0x11, 0x0e],
        '7' => [0x1f, 0x01, 0x02, 0x04, 0x08, 0x08, 0x08],
        '8' => [0x0e, 0x11, 0x11, 0x0e, 0x11, 0x11, 0x0e],
        '9' => [0x0e, 0x11, 0x11, 0x0f, 0x01, 0x02, 0x0c],
        '.' => [0x00, 0x00, 0x00, 0x00, 0x00, 0x0c, 0x0c],
        'm' => [0x00, 0x00, 0x1a, 0x15, 0x15, 0x11, 0x11],
        'i' => [0x04, 0x00, 0x0c, 0x04, 0x04, 0x04, 0x0e],
        'n' => [0x00, 0x00, 0x16, 0x19, 0x11, 0x11, 0x11],
        'f' => [0x06, 0x09, 0x08, 0x1c, 0x08, 0x08, 0x08],
        _ => return None,
    })
}

/// Draw `text` in black with the 5x7 font, top-left at `(x, y)`, 6 pixels per character; pixels
/// outside the image are skipped, unknown characters left blank.
pub fn draw_text(img: &mut Array3<f32>, x: usize, y: usize, text: &str) {
    for (i, c) in text.chars().enumerate() {
        let Some(rows) = glyph(c) else { continue };
        for (dy, row) in rows.iter().enumerate() {
            for dx in 0..5 {
                if row & (0x10 >> dx) != 0 {
                    set_black(img, y + dy, x + 6 * i + dx);
                }
            }
        }
    }
}
