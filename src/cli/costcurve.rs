//! `densefeat costcurve`: the cost curves `E(u, ρ)` of a few keyframe pixels, for RGB and learned
//! features, as the volume fills up (the paper's cost-volume figures). SPEC.md §12.1 defines it.
//!
//! For each feature kind a [`CostVolume`] is built on the features' grid (level `L`, the network's
//! output level for both kinds so they are compared on one grid), and live frames are added one at
//! a time in the order of [`frame_order`]. After 2, 15 and 30 frames (or `--frames`) the curve of
//! every pixel is recorded. The plot is a grid (rows: frames added, columns: pixels) of cost against
//! inverse depth, every curve min-max normalised to `[0, 1]` over its seen hypotheses, with a
//! vertical line at each curve's minimum (its colour) and a green one at the ground-truth inverse
//! depth. The raw curves go to a CSV beside the PNG.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use clap::Args;

use crate::costvolume::CostVolume;
use crate::error::{Error, Result};
use crate::geometry::{relative_pose, InverseDepthBins};
use crate::image::{is_valid_depth, DepthMap};
use crate::io::{write_atomic, Staging};
use crate::mapping::features::{FeatureExtractor, FeatureKind};
use crate::memory;
use crate::plot::{grid_of_plots_png, Marker, Panel, Series};
use crate::sequence::{open, Sequence};

use super::validate::{feature_channels, flag, frames_big_enough, MemoryLimit};

/// Arguments of `densefeat costcurve`.
#[derive(Debug, Clone, Args)]
pub struct CostcurveArgs {
    /// The sequence folder (any format `densefeat inspect` reads).
    #[arg(long)]
    pub sequence: PathBuf,
    /// Index of the keyframe (the reference frame of the volume).
    #[arg(long)]
    pub keyframe: usize,
    /// Level-0 keyframe pixels "x,y;x,y;..." (column, row).
    #[arg(long)]
    pub pixels: String,
    /// Feature kinds, comma-separated: rgb, learned, learned=WEIGHTS.
    #[arg(long, default_value = "rgb,learned")]
    pub features: String,
    /// Numbers of added frames at which curves are recorded (clamped to the frames that exist).
    #[arg(long, default_value = "2,15,30")]
    pub frames: String,
    /// Depth range NEAR,FAR in metres (hypotheses uniform in inverse depth).
    #[arg(long, default_value = "0.4,10")]
    pub depth_range: String,
    /// Number of inverse-depth hypotheses K.
    #[arg(long, default_value_t = 64)]
    pub bins: usize,
    /// Output PNG; the raw curves go to the same path with extension `.csv`.
    #[arg(long)]
    pub out: PathBuf,
    /// Memory limit.
    #[command(flatten)]
    pub memory: MemoryLimit,
}

/// One recorded cost curve.
#[derive(Clone, Debug)]
pub struct Curve {
    /// `rgb` or `learned`.
    pub feature: &'static str,
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

/// Parse `"x,y;x,y"`.
///
/// # Errors
/// [`Error::InvalidArgument`] naming `--pixels`.
pub fn parse_pixels(text: &str) -> Result<Vec<(usize, usize)>> {
    let bad = |what: String| Error::invalid_argument("--pixels", format!("{text:?}: {what}"));
    let pixels = text
        .split(';')
        .filter(|p| !p.trim().is_empty())
        .map(|p| {
            let (x, y) = p.split_once(',').ok_or_else(|| bad(format!("{p:?} is not x,y")))?;
            let num =
                |v: &str| v.trim().parse::<usize>().map_err(|_| bad(format!("{v:?} is not a pixel index")));
            Ok((num(x)?, num(y)?))
        })
        .collect::<Result<Vec<_>>>()?;
    if pixels.is_empty() {
        return Err(bad("no pixel".into()));
    }
    Ok(pixels)
}

fn parse_list(name: &str, text: &str) -> Result<Vec<usize>> {
    let list = text
        .split(',')
        .map(|v| v.trim().parse::<usize>())
        .collect::<std::result::Result<Vec<_>, _>>()
        .map_err(|_| Error::invalid_argument(name, format!("{text:?}: expected N,N,...")))?;
    if list.is_empty() || list.contains(&0) {
        return Err(Error::invalid_argument(name, format!("{text:?}: need counts >= 1")));
    }
    Ok(list)
}

fn parse_range(text: &str) -> Result<(f64, f64)> {
    let bad = || Error::invalid_argument("--depth-range", format!("{text:?}: expected NEAR,FAR in metres"));
    let (a, b) = text.split_once(',').ok_or_else(bad)?;
    Ok((a.trim().parse().map_err(|_| bad())?, b.trim().parse().map_err(|_| bad())?))
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
    let (w0, h0) = (seq.camera.width, seq.camera.height);
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
    for kind in kinds {
        let ex = FeatureExtractor::new(kind.clone(), rgb_level, crate::backend::default_backend())?;
        let camera = ex.camera(&seq.camera);
        let grid: Vec<_> =
            pixels.iter().map(|&p| grid_pixel(p, ex.level(), (camera.width, camera.height))).collect();
        let mut cv = CostVolume::new(ex.extract(&key.rgb)?.data, camera, bins)?;
        for (i, &n) in order[..last].iter().enumerate() {
            let live = seq.load_frame(n)?;
            cv.add_frame(ex.extract(&live.rgb)?.data.view(), &relative_pose(&key.pose, &live.pose))?;
            if !counts.contains(&(i + 1)) {
                continue;
            }
            for (&pixel, &(gx, gy)) in pixels.iter().zip(&grid) {
                let scale = 1usize << ex.level();
                let gt = key.depth.as_ref().and_then(|d| gt_inverse_depth(d, (gx * scale, gy * scale)));
                curves.push(Curve {
                    feature: ex.name(),
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

fn colour_of(feature: &str) -> (u8, u8, u8) {
    if feature == "rgb" {
        RGB_COLOUR
    } else {
        LEARNED_COLOUR
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
                        let colour = colour_of(c.feature);
                        panel.series.push(Series {
                            name: c.feature.to_string(),
                            points: rhos.iter().copied().zip(norm).collect(),
                            colour,
                        });
                        panel.markers.push(Marker {
                            x: rhos[kmin],
                            colour,
                            label: format!("{} min", c.feature),
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
                c.feature,
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

/// The CSV path for a PNG path.
pub fn csv_path(png: &Path) -> PathBuf {
    png.with_extension("csv")
}

/// The checks that run before any curve is computed (SPEC.md §14.1): frame size, keyframe, pixels,
/// weights files and the memory of the largest volume.
fn preflight(
    args: &CostcurveArgs,
    seq: &Sequence,
    kinds: &[FeatureKind],
    pixels: &[(usize, usize)],
) -> Result<()> {
    frames_big_enough(seq, "costcurve")?;
    if args.keyframe >= seq.len() {
        return Err(flag("keyframe", format!("{}: the sequence has {} frames", args.keyframe, seq.len())));
    }
    let (w0, h0) = (seq.camera.width, seq.camera.height);
    if let Some(p) = pixels.iter().find(|(x, y)| *x >= w0 || *y >= h0) {
        return Err(flag("pixels", format!("{p:?} is outside the {w0}x{h0} image")));
    }
    if csv_path(&args.out) == args.out {
        return Err(flag(
            "out",
            format!("{}: give the PNG a .png name (the CSV goes beside it)", args.out.display()),
        ));
    }
    let level = FeatureExtractor::network_level()?;
    for kind in kinds {
        let (channels, stride) = feature_channels(kind)?;
        let grid = seq.camera.at_level(level);
        let mut bytes = memory::cost_volume_bytes(grid.height, grid.width, args.bins, channels);
        if !matches!(kind, FeatureKind::Rgb) {
            bytes = bytes.saturating_add(memory::network_forward_bytes(h0, w0, channels, stride));
        }
        let what =
            format!("the {}x{}x{} cost volume with {channels} channels", grid.height, grid.width, args.bins);
        args.memory.check(&what, bytes, "use fewer --bins")?;
    }
    Ok(())
}

/// Runs the command.
///
/// # Errors
/// Argument errors naming the flag; reading and writing errors naming the file.
pub fn run(args: CostcurveArgs) -> Result<()> {
    let pixels = parse_pixels(&args.pixels)?;
    let kinds = args.features.split(',').map(|k| k.trim().parse()).collect::<Result<Vec<FeatureKind>>>()?;
    let counts = parse_list("--frames", &args.frames)?;
    let (near, far) = parse_range(&args.depth_range)?;
    let bins = InverseDepthBins::from_depth_range(near, far, args.bins)
        .map_err(|e| flag(if args.bins < 2 { "bins" } else { "depth-range" }, e.to_string()))?;
    let seq = open(&args.sequence)?;
    preflight(&args, &seq, &kinds, &pixels)?;
    let mut staging = Staging::new();
    let png = staging.file(&args.out)?;
    let csv_staged = staging.file(&csv_path(&args.out))?;
    let start = std::time::Instant::now();
    let curves = cost_curves(&seq, args.keyframe, &pixels, &kinds, &counts, bins)?;
    let title = format!(
        "Keyframe {}: cost vs inverse depth, each curve normalised to [0, 1]; lines: minima, green: ground truth",
        args.keyframe
    );
    grid_of_plots_png(&png, &title, &panels(&curves, &bins))?;
    write_atomic(&csv_staged, curves_csv(&curves, &bins).as_bytes())?;
    staging.commit()?;
    let csv = csv_path(&args.out);
    eprintln!(
        "costcurve: {} curves -> {} and {} in {:.2} s",
        curves.len(),
        args.out.display(),
        csv.display(),
        start.elapsed().as_secs_f64()
    );
    Ok(())
}
