//! Cost curves `E(u, ρ)` of a few keyframe pixels, for RGB and learned features, as the volume
//! fills up (the paper's cost-volume figures; SPEC.md §12.1; `densefeat costcurve` prints them).
//!
//! For each feature kind a cost volume is built on the features' grid (level `L`, the network's
//! output level for both kinds so they are compared on one grid) on the given backend, and live
//! frames are added one at a time in the order of [`frame_order`]. After each requested frame count
//! the curve of every pixel is recorded. [`panels`] lays them out as a grid (rows: frames added,
//! columns: pixels) of cost against inverse depth, every curve min-max normalised to `[0, 1]` over
//! its seen hypotheses, with a vertical line at each curve's minimum (its colour) and a green one at
//! the ground-truth inverse depth; [`curves_csv`] writes the raw curves.

use std::fmt::Write as _;
use std::sync::Arc;

use crate::backend::Backend;
use crate::error::{Error, Result};
use crate::geometry::{relative_pose, InverseDepthBins};
use crate::image::{is_valid_depth, DepthMap};
use crate::mapping::features::{FeatureExtractor, FeatureKind};
use crate::plot::{Marker, Panel, Series};
use crate::sequence::Sequence;

/// One recorded cost curve.
#[derive(Clone, Debug)]
pub struct Curve {
    /// The feature kind's name (`rgb`, `learned`, `b1`, `dsift`, `patch7`).
    pub feature: &'static str,
    /// What the plot and the CSV call the curve: the kind's name, or `name=WEIGHTS` (the weights
    /// file's stem) when `kinds` holds the kind more than once, as `learned=A,learned=B` does.
    pub label: String,
    /// The kind's position among those asked for (tells repeated kinds' colours apart).
    pub kind_index: usize,
    /// Frames in the volume when it was recorded.
    pub frames_added: usize,
    /// The level-0 pixel asked for.
    pub pixel: (usize, usize),
    /// Its pixel on the feature grid.
    pub grid_pixel: (usize, usize),
    /// Mean cost per hypothesis, `None` where no frame saw the cell.
    pub costs: Vec<Option<f32>>,
    /// Ground-truth inverse depth at the grid pixel (1/m), if the keyframe has depth there.
    pub gt_inverse_depth: Option<f64>,
}

/// Colours of the feature kinds (RGB blue, learned orange) and of the ground truth (green).
const RGB_COLOUR: (u8, u8, u8) = (31, 119, 180);
const LEARNED_COLOUR: (u8, u8, u8) = (230, 120, 10);
const B1_COLOUR: (u8, u8, u8) = (148, 103, 189);
const DSIFT_COLOUR: (u8, u8, u8) = (140, 86, 75);
const PATCH7_COLOUR: (u8, u8, u8) = (227, 119, 194);
const GT_COLOUR: (u8, u8, u8) = (20, 160, 40);

/// The live frames of `keyframe` in a sequence of `len` frames, nearest first, alternating future
/// and past: `k+1, k-1, k+2, k-2, ...`, skipping indices that do not exist.
pub fn frame_order(keyframe: usize, len: usize) -> Vec<usize> {
    let mut order = Vec::with_capacity(len.saturating_sub(1));
    for d in 1..len {
        if keyframe + d < len {
            order.push(keyframe + d);
        }
        if d <= keyframe {
            order.push(keyframe - d);
        }
    }
    order
}

/// Level-`level` grid pixel of level-0 pixel `(x, y)`: `round(x / 2^L)` (half away from zero),
/// clamped into a `w x h` grid (the last level-0 column can round past it).
pub fn grid_pixel((x, y): (usize, usize), level: u32, (w, h): (usize, usize)) -> (usize, usize) {
    let s = f64::from(1u32 << level);
    let r = |v: usize, n: usize| ((v as f64 / s).round() as usize).min(n - 1);
    (r(x, w), r(y, h))
}

/// Record the curves (see the module docs). `frame_counts` are clamped to the frames that exist and
/// deduplicated.
///
/// # Errors
/// Reading errors naming the file; [`Error::InvalidArgument`] for a keyframe or pixel outside the
/// sequence, or a sequence of one frame.
pub fn cost_curves(
    seq: &Sequence,
    keyframe: usize,
    pixels: &[(usize, usize)],
    kinds: &[FeatureKind],
    frame_counts: &[usize],
    bins: InverseDepthBins,
    backend: &Arc<dyn Backend>,
) -> Result<Vec<Curve>> {
    if keyframe >= seq.len() {
        return Err(Error::invalid_argument(
            "--keyframe",
            format!("{keyframe}: the sequence has {} frames", seq.len()),
        ));
    }
    let order = frame_order(keyframe, seq.len());
    if order.is_empty() {
        return Err(Error::invalid_argument("--sequence", "one frame: no live frame to match"));
    }
    let seq_camera = seq.the_camera("--sequence")?;
    let (w0, h0) = (seq_camera.width, seq_camera.height);
    if let Some(p) = pixels.iter().find(|(x, y)| *x >= w0 || *y >= h0) {
        return Err(Error::invalid_argument("--pixels", format!("{p:?} is outside the {w0}x{h0} image")));
    }
    let mut counts: Vec<usize> = frame_counts.iter().map(|&n| n.min(order.len())).collect();
    counts.sort_unstable();
    counts.dedup();
    let last = *counts.last().ok_or_else(|| Error::invalid_argument("--frames", "empty"))?;
    let key = seq.load_frame(keyframe)?;
    let rgb_level = FeatureExtractor::network_level()?;
    let mut curves = Vec::new();
    for (kind_index, kind) in kinds.iter().enumerate() {
        let ex = FeatureExtractor::new(kind.clone(), rgb_level, backend.clone())?;
        let label = curve_label(kinds, kind_index, ex.name());
        let camera = ex.camera(&seq_camera);
        let grid: Vec<_> =
            pixels.iter().map(|&p| grid_pixel(p, ex.level(), (camera.width, camera.height))).collect();
        // The default per-frame truncation (SPEC.md §9.13): the curves the mapper sees.
        let truncation = crate::mapping::Truncation::DEFAULT.of(kind);
        let mut builder = ex.volume(ex.extract(&key.rgb)?.data, camera, bins, truncation)?;
        for (i, &n) in order[..last].iter().enumerate() {
            let live = seq.load_frame_rgb(n)?;
            builder
                .add_frame(&ex.upload(ex.extract(&live.rgb)?.data)?, &relative_pose(&key.pose, &live.pose))?;
            if !counts.contains(&(i + 1)) {
                continue;
            }
            // The volume so far, on the host.
            let cv = builder.snapshot()?;
            for (&pixel, &(gx, gy)) in pixels.iter().zip(&grid) {
                let scale = 1usize << ex.level();
                let gt = key.depth.as_ref().and_then(|d| gt_inverse_depth(d, (gx * scale, gy * scale)));
                curves.push(Curve {
                    feature: ex.name(),
                    label: label.clone(),
                    kind_index,
                    frames_added: i + 1,
                    pixel,
                    grid_pixel: (gx, gy),
                    costs: (0..bins.count).map(|k| cv.cost(gy, gx, k)).collect(),
                    gt_inverse_depth: gt,
                });
            }
        }
    }
    Ok(curves)
}

/// The label of `kinds[i]` (named `name`): `name` alone when no other entry of `kinds` has that name,
/// else `name=STEM` with the weights file's stem (`name=shipped` for the built-in weights), and
/// `#i` appended if that still repeats an earlier label.
pub fn curve_label(kinds: &[FeatureKind], i: usize, name: &str) -> String {
    let same = |k: &FeatureKind| std::mem::discriminant(k) == std::mem::discriminant(&kinds[i]);
    if kinds.iter().filter(|k| same(k)).count() < 2 {
        return name.to_string();
    }
    let stem = |k: &FeatureKind| match k {
        FeatureKind::Learned(Some(p)) | FeatureKind::B1(Some(p)) => {
            // `docs/x/weights.safetensors` is named by its folder: `x/weights`.
            let file = p.file_stem().map_or_else(String::new, |s| s.to_string_lossy().into_owned());
            match p.parent().and_then(|d| d.file_name()) {
                Some(dir) => format!("{}/{file}", dir.to_string_lossy()),
                None => file,
            }
        }
        _ => "shipped".to_string(),
    };
    let label = format!("{name}={}", stem(&kinds[i]));
    let earlier = kinds[..i].iter().filter(|k| same(k) && stem(k) == stem(&kinds[i])).count();
    if earlier > 0 {
        format!("{label}#{i}")
    } else {
        label
    }
}

/// The colour of a curve: its kind's ([`colour_of`]), darkened by a third for each earlier entry of
/// the same kind, so that `learned=A,learned=B` are two shades of orange.
pub fn curve_colour(c: &Curve, curves: &[Curve]) -> (u8, u8, u8) {
    let mut earlier: Vec<usize> = curves
        .iter()
        .filter(|o| o.feature == c.feature && o.kind_index < c.kind_index)
        .map(|o| o.kind_index)
        .collect();
    earlier.sort_unstable();
    earlier.dedup();
    let (r, g, b) = colour_of(c.feature);
    let f = 0.6f64.powi(i32::try_from(earlier.len()).unwrap_or(i32::MAX));
    // Invariant: each channel stays in 0..=255 (a value in 0..=255 times a factor in (0, 1]).
    let shade = |v: u8| (f64::from(v) * f).round() as u8;
    (shade(r), shade(g), shade(b))
}

fn gt_inverse_depth(depth: &DepthMap, (x, y): (usize, usize)) -> Option<f64> {
    let (h, w) = depth.dim();
    let z = depth[[y.min(h - 1), x.min(w - 1)]];
    is_valid_depth(z).then(|| 1.0 / f64::from(z))
}

/// `(k*, normalised curve)`: the first argmin over seen cells and the curve min-max scaled to
/// `[0, 1]` (all 0 if flat); NaN where unseen. `None` if nothing was seen.
pub fn normalise(costs: &[Option<f32>]) -> Option<(usize, Vec<f64>)> {
    let seen = costs.iter().enumerate().filter_map(|(k, c)| c.map(|c| (k, f64::from(c))));
    let (kmin, lo, hi) = seen.fold(None, |acc: Option<(usize, f64, f64)>, (k, c)| match acc {
        None => Some((k, c, c)),
        Some((km, lo, hi)) => Some(if c < lo { (k, c, hi.max(c)) } else { (km, lo, hi.max(c)) }),
    })?;
    let span = hi - lo;
    let norm = costs
        .iter()
        .map(|c| c.map_or(f64::NAN, |c| if span > 0.0 { (f64::from(c) - lo) / span } else { 0.0 }))
        .collect();
    Some((kmin, norm))
}

/// One colour per feature kind, so that every kind `--features` accepts is told apart in a panel.
pub fn colour_of(feature: &str) -> (u8, u8, u8) {
    match feature {
        "rgb" => RGB_COLOUR,
        "b1" => B1_COLOUR,
        "dsift" => DSIFT_COLOUR,
        "patch7" => PATCH7_COLOUR,
        _ => LEARNED_COLOUR,
    }
}

/// The plot's panels: one row per frame count, one column per pixel.
pub fn panels(curves: &[Curve], bins: &InverseDepthBins) -> Vec<Vec<Panel>> {
    let mut counts: Vec<usize> = curves.iter().map(|c| c.frames_added).collect();
    counts.sort_unstable();
    counts.dedup();
    let mut pixels: Vec<(usize, usize)> = Vec::new();
    for c in curves {
        if !pixels.contains(&c.pixel) {
            pixels.push(c.pixel);
        }
    }
    let rhos = bins.values();
    counts
        .iter()
        .map(|&n| {
            pixels
                .iter()
                .map(|&p| {
                    let mine: Vec<&Curve> =
                        curves.iter().filter(|c| c.frames_added == n && c.pixel == p).collect();
                    let mut panel = Panel {
                        title: format!("pixel ({}, {}), {n} frames", p.0, p.1),
                        x_label: "inverse depth (1/m)".into(),
                        y_label: "normalised cost".into(),
                        ..Panel::default()
                    };
                    for c in &mine {
                        let Some((kmin, norm)) = normalise(&c.costs) else { continue };
                        let colour = curve_colour(c, curves);
                        panel.series.push(Series {
                            name: c.label.clone(),
                            points: rhos.iter().copied().zip(norm).collect(),
                            colour,
                        });
                        panel.markers.push(Marker {
                            x: rhos[kmin],
                            colour,
                            label: format!("{} min", c.label),
                        });
                    }
                    if let Some(gt) = mine.first().and_then(|c| c.gt_inverse_depth) {
                        panel.markers.push(Marker { x: gt, colour: GT_COLOUR, label: "ground truth".into() });
                    }
                    panel
                })
                .collect()
        })
        .collect()
}

/// The raw curves as CSV: one line per curve and hypothesis; empty cost where unseen.
pub fn curves_csv(curves: &[Curve], bins: &InverseDepthBins) -> String {
    let mut out = String::from(
        "feature,frames_added,pixel_x,pixel_y,grid_x,grid_y,gt_inverse_depth,k,inverse_depth,cost,cost_normalised\n",
    );
    for c in curves {
        let norm = normalise(&c.costs).map(|(_, n)| n);
        let gt = c.gt_inverse_depth.map_or(String::new(), |g| format!("{g}"));
        for (k, cost) in c.costs.iter().enumerate() {
            let cost_text = cost.map_or(String::new(), |v| format!("{v}"));
            let n = norm
                .as_ref()
                .map(|n| n[k])
                .filter(|v| v.is_finite())
                .map_or(String::new(), |v| format!("{v}"));
            // Invariant: writing to a String cannot fail.
            let _ = writeln!(
                out,
                "{},{},{},{},{},{},{gt},{k},{},{cost_text},{n}",
                c.label,
                c.frames_added,
                c.pixel.0,
                c.pixel.1,
                c.grid_pixel.0,
                c.grid_pixel.1,
                bins.rho(k)
            );
        }
    }
    out
}
