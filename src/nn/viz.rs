//! A deterministic RGB picture of a feature map (SPEC.md §8.8): the projection of every pixel's
//! feature vector onto the top three principal components of the map's own features.

use nalgebra::{DMatrix, SymmetricEigen};
use ndarray::{Array3, ArrayView3};

use crate::error::{Error, Result};

/// Lower and upper percentiles mapped to 0 and 255.
const PERCENTILES: (f64, f64) = (0.01, 0.99);

/// The `q`-quantile (nearest rank) of sorted values.
fn quantile(sorted: &[f64], q: f64) -> f64 {
    let i = ((sorted.len() - 1) as f64 * q).round() as usize;
    sorted[i]
}

/// Maps `[H, W, C]` features to an `[H, W, 3]` image in `0..=255`: centre the features (f64 mean),
/// form the `C x C` covariance in f64, take the eigenvectors of its three largest eigenvalues
/// (nalgebra `SymmetricEigen`; each vector's sign fixed so that its largest-magnitude component is
/// positive; fewer than three channels leave the rest 0), project, and scale each component
/// linearly so its 1st and 99th percentiles map to 0 and 255 (clamped). Sequential, hence
/// deterministic.
///
/// # Errors
/// [`Error::InvalidArgument`] for an empty map.
pub fn pca_rgb(features: ArrayView3<f32>) -> Result<Array3<f32>> {
    let (h, w, c) = features.dim();
    if h * w * c == 0 {
        return Err(Error::invalid_argument("features", format!("empty map {:?}", features.shape())));
    }
    let n = h * w;
    let x = DMatrix::from_fn(n, c, |p, ch| f64::from(features[[p / w, p % w, ch]]));
    let mean = x.row_mean();
    let centred = DMatrix::from_fn(n, c, |p, ch| x[(p, ch)] - mean[ch]);
    let cov = centred.transpose() * &centred / n as f64;
    let eig = SymmetricEigen::new(cov);
    let mut order: Vec<usize> = (0..c).collect();
    order.sort_by(|&a, &b| eig.eigenvalues[b].total_cmp(&eig.eigenvalues[a]).then(a.cmp(&b)));
    let mut out = Array3::zeros((h, w, 3));
    for (rgb, &idx) in order.iter().take(3).enumerate() {
        let mut v = eig.eigenvectors.column(idx).into_owned();
        let largest = v.iter().copied().fold(0.0f64, |m, x| if x.abs() > m.abs() { x } else { m });
        if largest < 0.0 {
            v = -v;
        }
        let proj = &centred * &v;
        let mut sorted: Vec<f64> = proj.iter().copied().collect();
        sorted.sort_by(f64::total_cmp);
        let (lo, hi) = (quantile(&sorted, PERCENTILES.0), quantile(&sorted, PERCENTILES.1));
        let scale = if hi > lo { 255.0 / (hi - lo) } else { 0.0 };
        for p in 0..n {
            out[[p / w, p % w, rgb]] = ((proj[p] - lo) * scale).clamp(0.0, 255.0) as f32;
        }
    }
    Ok(out)
}
