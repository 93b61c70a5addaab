//! The depth range of a frame estimated from the data (`--depth-range auto`, SPEC.md §4a): the
//! format's sparse points seen in the frame (COLMAP `points3D`), else its ground-truth depth.

use super::Sequence;
use crate::error::Result;
use crate::image::is_valid_depth;

/// Fewest depths a range is estimated from.
pub const MIN_RANGE_SAMPLES: usize = 8;
/// Lower and upper percentiles of the depths.
pub const RANGE_PERCENTILES: (f64, f64) = (0.02, 0.98);
/// The percentile depths are widened by this factor: `near = p02 / 1.25`, `far = p98 * 1.25`.
pub const RANGE_MARGIN: f64 = 1.25;

/// `(p02 / 1.25, p98 * 1.25)` of the finite positive `depths` (nearest-rank percentiles,
/// rank `round((n - 1) q)`), `None` with fewer than [`MIN_RANGE_SAMPLES`].
pub fn depth_range_of(mut depths: Vec<f64>) -> Option<(f64, f64)> {
    depths.retain(|z| z.is_finite() && *z > 0.0);
    if depths.len() < MIN_RANGE_SAMPLES {
        return None;
    }
    depths.sort_by(f64::total_cmp);
    let at = |q: f64| depths[((depths.len() - 1) as f64 * q).round() as usize];
    Some((at(RANGE_PERCENTILES.0) / RANGE_MARGIN, at(RANGE_PERCENTILES.1) * RANGE_MARGIN))
}

impl Sequence {
    /// Frame `index`'s estimated depth range: its sparse range if the format has one, else
    /// [`depth_range_of`] its valid ground-truth depths; `None` when it has neither.
    ///
    /// # Errors
    /// As [`Sequence::load_frame`].
    pub fn estimate_depth_range(&self, index: usize) -> Result<Option<(f64, f64)>> {
        if let Some(r) = self.frames.get(index).and_then(|f| f.sparse_depth_range) {
            return Ok(Some(r));
        }
        if self.frames.get(index).is_none_or(|f| f.depth.is_none()) {
            return Ok(None);
        }
        let depth = self.load_frame(index)?.depth;
        Ok(depth.and_then(|d| {
            depth_range_of(d.iter().copied().filter(|z| is_valid_depth(*z)).map(f64::from).collect())
        }))
    }
}
