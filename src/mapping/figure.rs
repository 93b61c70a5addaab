//! The feature figure (issue 32 item 2; the paper's Fig. 4 and its supplementary figures): for one
//! keyframe, its image, the ground-truth depth and every method's depth on one colour scale, each
//! captioned with the method's rms, δ<1.1 and δ<1.25 (SPEC.md §11.4a). `densefeat eval --figure`
//! writes one per keyframe; `demo` writes its keyframe's.

use std::path::Path;

use crate::error::Result;
use crate::eval::DepthMetrics;
use crate::image::is_valid_depth;
use crate::mapping::evaluate::Method;
use crate::mapping::keyframe::KeyframeResult;
use crate::mapping::output::{colour_range, depth_colour};
use crate::plot::{image_grid_png, Tile};

/// Pictures per row of the figure.
pub const FIGURE_COLUMNS: usize = 4;

/// One method's picture of a keyframe.
#[derive(Clone, Debug)]
pub struct FigureEntry {
    /// The method.
    pub method: Method,
    /// Its depth on the keyframe's level-`L` grid, metres (0: invalid).
    pub depth: ndarray::Array2<f32>,
    /// Its metrics against the ground truth.
    pub metrics: DepthMetrics,
}

impl FigureEntry {
    /// `method`'s entry of `result` (a reconstruction of its feature kind), or `None` when that
    /// estimate was not made or cannot be measured (no ground truth, no valid pixel).
    pub fn of(method: Method, result: &KeyframeResult) -> Option<Self> {
        let estimate = method.estimate(result)?;
        let metrics = result.metrics(estimate).ok()?;
        Some(FigureEntry { method, depth: estimate.depth.clone(), metrics })
    }
}

/// `depth` as RGB bytes on the colour scale `[near, far]` (turbo of inverse depth, near red, far
/// blue, as `depth_*_color.png`), invalid pixels black.
fn coloured(depth: &ndarray::Array2<f32>, near: f64, far: f64) -> Vec<u8> {
    depth
        .iter()
        .flat_map(|&z| if is_valid_depth(z) { depth_colour(f64::from(z), near, far) } else { [0.0; 3] })
        .map(|v| v.round().clamp(0.0, 255.0) as u8)
        .collect()
}

/// Writes `path`: `result`'s keyframe image and ground truth (when it has one), then `entries` in
/// order, [`FIGURE_COLUMNS`] to a row, every depth on `result`'s colour range
/// ([`colour_range`]: the 2nd-98th percentile of the ground truth).
///
/// # Errors
/// No entry; writing `path`.
pub fn write_feature_figure(
    path: &Path,
    title: &str,
    result: &KeyframeResult,
    entries: &[FigureEntry],
) -> Result<()> {
    if entries.is_empty() {
        return Err(crate::error::Error::invalid_argument("feature figure", "no method to show"));
    }
    let (h, w, _) = result.colour.dim();
    let (near, far) = colour_range(result);
    let mut tiles = vec![Tile {
        width: w,
        height: h,
        rgb: result.colour.iter().map(|&v| v.round().clamp(0.0, 255.0) as u8).collect(),
        caption: format!("keyframe {}", result.keyframe),
    }];
    if let Some(gt) = &result.gt_depth {
        tiles.push(Tile {
            width: w,
            height: h,
            rgb: coloured(gt, near, far),
            caption: format!("ground truth ({near:.1}-{far:.1} m)"),
        });
    }
    for e in entries {
        let m = &e.metrics;
        tiles.push(Tile {
            width: e.depth.ncols(),
            height: e.depth.nrows(),
            rgb: coloured(&e.depth, near, far),
            caption: format!(
                "{}: rms {:.2} m, δ<1.1 {:.2}, δ<1.25 {:.2}",
                e.method, m.rms, m.delta_1_1, m.delta_1_25
            ),
        });
    }
    image_grid_png(path, title, &tiles, FIGURE_COLUMNS)
}
