//! Mesh-to-mesh metrics of the 3D-reconstruction literature (SPEC.md §16.5), with the vertices of
//! each mesh as its point samples (surface nets put about one vertex per surface voxel, so the
//! samples are near uniform over the surface at the voxel spacing).
//!
//! For predicted points `P` and ground-truth points `G`, `d(x, S) = min_{y ∈ S} ‖x - y‖`:
//! accuracy `mean_{p ∈ P} d(p, G)`, completeness `mean_{g ∈ G} d(g, P)`, precision
//! `|{p : d(p, G) < τ}| / |P|`, recall `|{g : d(g, P) < τ}| / |G|`, F-score `2 P R / (P + R)`.
//! Nearest neighbours are exact (a k-d tree), distances summed in point order: deterministic.

use rayon::prelude::*;
use serde::Serialize;

use super::mesh::Mesh;

/// Metrics between a predicted and a ground-truth mesh.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct MeshMetrics {
    /// Mean distance from predicted points to the ground truth, metres.
    pub accuracy: f64,
    /// Mean distance from ground-truth points to the prediction, metres.
    pub completeness: f64,
    /// Fraction of predicted points within `threshold` of the ground truth.
    pub precision: f64,
    /// Fraction of ground-truth points within `threshold` of the prediction.
    pub recall: f64,
    /// `2 precision recall / (precision + recall)` (0 when both are 0).
    pub fscore: f64,
    /// The threshold `τ`, metres.
    pub threshold: f64,
    /// Predicted points.
    pub predicted_points: usize,
    /// Ground-truth points.
    pub gt_points: usize,
    /// Precision, recall and F-score at the thresholds the field reports, [`STANDARD_THRESHOLDS`]
    /// (2, 5 and 10 cm), whatever `threshold` is.
    pub standard: [ThresholdScores; 3],
}

/// The thresholds of [`MeshMetrics::standard`], metres (the 2 / 5 / 10 cm of the MVS and
/// TSDF-fusion evaluations: Tanks and Temples, ScanNet's Atlas / NeuralRecon tables).
pub const STANDARD_THRESHOLDS: [f64; 3] = [0.02, 0.05, 0.10];

/// Precision, recall and F-score at one threshold.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct ThresholdScores {
    /// The threshold, metres.
    pub threshold: f64,
    /// Fraction of predicted points within `threshold` of the ground truth.
    pub precision: f64,
    /// Fraction of ground-truth points within `threshold` of the prediction.
    pub recall: f64,
    /// `2 precision recall / (precision + recall)` (0 when both are 0).
    pub fscore: f64,
}

impl ThresholdScores {
    /// The scores of the nearest distances `dp` (predicted to ground truth) and `dg` (ground
    /// truth to predicted): fractions strictly below `threshold`, 0 for an empty side.
    fn of(dp: &[f64], dg: &[f64], threshold: f64) -> Self {
        let frac = |d: &[f64]| {
            if d.is_empty() {
                0.0
            } else {
                d.iter().filter(|&&x| x < threshold).count() as f64 / d.len() as f64
            }
        };
        let (precision, recall) = (frac(dp), frac(dg));
        let fscore =
            if precision + recall > 0.0 { 2.0 * precision * recall / (precision + recall) } else { 0.0 };
        ThresholdScores { threshold, precision, recall, fscore }
    }
}

/// A static 3-d tree over points for exact nearest-neighbour distances.
pub struct KdTree {
    points: Vec<[f64; 3]>,
    /// Split axis of the node whose median sits at this position.
    axes: Vec<u8>,
}

impl KdTree {
    /// Build over `points` (median splits on the axis of largest spread, deterministic).
    pub fn new(points: &[[f64; 3]]) -> Self {
        let mut points = points.to_vec();
        let mut axes = vec![0u8; points.len()];
        build(&mut points, &mut axes);
        Self { points, axes }
    }

    /// Distance from `q` to the nearest point (`inf` for an empty tree).
    pub fn nearest_distance(&self, q: [f64; 3]) -> f64 {
        let mut best = f64::INFINITY;
        search(&self.points, &self.axes, q, &mut best);
        best.sqrt()
    }
}

/// Leaves hold at most this many points (scanned linearly).
const LEAF: usize = 8;

fn spread_axis(p: &[[f64; 3]]) -> usize {
    let mut best = (0, f64::NEG_INFINITY);
    for a in 0..3 {
        let (lo, hi) =
            p.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), v| (l.min(v[a]), h.max(v[a])));
        if hi - lo > best.1 {
            best = (a, hi - lo);
        }
    }
    best.0
}

/// Node layout: the median at `len / 2`, left half before it, right half after.
fn build(p: &mut [[f64; 3]], axes: &mut [u8]) {
    if p.len() <= LEAF {
        return;
    }
    let axis = spread_axis(p);
    let mid = p.len() / 2;
    p.select_nth_unstable_by(mid, |a, b| a[axis].total_cmp(&b[axis]));
    axes[mid] = axis as u8;
    let (left, right) = p.split_at_mut(mid);
    let (al, ar) = axes.split_at_mut(mid);
    build(left, al);
    build(&mut right[1..], &mut ar[1..]);
}

fn search(p: &[[f64; 3]], axes: &[u8], q: [f64; 3], best: &mut f64) {
    if p.len() <= LEAF {
        for v in p {
            *best = best.min(dist2(v, &q));
        }
        return;
    }
    let mid = p.len() / 2;
    let axis = axes[mid] as usize;
    *best = best.min(dist2(&p[mid], &q));
    let diff = q[axis] - p[mid][axis];
    let (lo, hi) = ((&p[..mid], &axes[..mid]), (&p[mid + 1..], &axes[mid + 1..]));
    let (near, far) = if diff < 0.0 { (lo, hi) } else { (hi, lo) };
    search(near.0, near.1, q, best);
    if diff * diff < *best {
        search(far.0, far.1, q, best);
    }
}

fn dist2(a: &[f64; 3], b: &[f64; 3]) -> f64 {
    (a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)
}

/// Distance from each of `queries` to the nearest of `reference`, in query order.
pub fn nearest_distances(queries: &[[f64; 3]], reference: &[[f64; 3]]) -> Vec<f64> {
    let tree = KdTree::new(reference);
    queries.par_iter().map(|&q| tree.nearest_distance(q)).collect()
}

fn points(m: &Mesh) -> Vec<[f64; 3]> {
    m.vertices.iter().map(|v| v.map(f64::from)).collect()
}

/// [`MeshMetrics`] of `predicted` against `gt` at threshold `threshold` metres. With an empty
/// mesh on either side the distances are infinite and the fractions 0.
pub fn mesh_metrics(predicted: &Mesh, gt: &Mesh, threshold: f64) -> MeshMetrics {
    let (p, g) = (points(predicted), points(gt));
    let dp = nearest_distances(&p, &g);
    let dg = nearest_distances(&g, &p);
    let mean = |d: &[f64]| if d.is_empty() { f64::INFINITY } else { d.iter().sum::<f64>() / d.len() as f64 };
    let ThresholdScores { precision, recall, fscore, .. } = ThresholdScores::of(&dp, &dg, threshold);
    MeshMetrics {
        accuracy: mean(&dp),
        completeness: mean(&dg),
        precision,
        recall,
        fscore,
        threshold,
        predicted_points: p.len(),
        gt_points: g.len(),
        standard: STANDARD_THRESHOLDS.map(|t| ThresholdScores::of(&dp, &dg, t)),
    }
}
