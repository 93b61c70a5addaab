//! The dense-SIFT oracle (SPEC.md §9a.2): for every pixel, every sample of its window, every cell,
//! in f64, one thread. Slow (about 400 samples x 16 cells per pixel); for tests on small images.

use ndarray::{Array3, ArrayView3};

use super::{orientation_split, DsiftParams, CELLS, CHANNELS, CLIP, ORIENTATIONS};

/// Grey value `(R + G + B) / 3` in f64 at a pixel clamped into the image (edge replication).
fn grey(rgb: &ArrayView3<f32>, x: i64, y: i64) -> f64 {
    let (h, w, _) = rgb.dim();
    let (x, y) = (x.clamp(0, w as i64 - 1) as usize, y.clamp(0, h as i64 - 1) as usize);
    (f64::from(rgb[[y, x, 0]]) + f64::from(rgb[[y, x, 1]]) + f64::from(rgb[[y, x, 2]])) / 3.0
}

/// Central differences `((I(x+1) - I(x-1)) / 2, (I(y+1) - I(y-1)) / 2)` at a pixel inside the image,
/// the missing neighbour at an edge replaced by the edge pixel.
fn gradient(rgb: &ArrayView3<f32>, x: i64, y: i64) -> (f64, f64) {
    let gx = (grey(rgb, x + 1, y) - grey(rgb, x - 1, y)) / 2.0;
    let gy = (grey(rgb, x, y + 1) - grey(rgb, x, y - 1)) / 2.0;
    (gx, gy)
}

/// The histogram `h` of pixel `(x, y)` before normalisation (SPEC.md §9a.2), f64.
pub fn histogram_reference(
    rgb: &ArrayView3<f32>,
    params: &DsiftParams,
    x: usize,
    y: usize,
) -> [f64; CHANNELS] {
    let (h, w, _) = rgb.dim();
    let r = params.radius() as i64;
    let sigma = params.sigma();
    let mut hist = [0.0f64; CHANNELS];
    for dy in -r..=r {
        for dx in -r..=r {
            let (sx, sy) = (x as i64 + dx, y as i64 + dy);
            // Outside the image: zero gradient, no contribution.
            if sx < 0 || sy < 0 || sx >= w as i64 || sy >= h as i64 {
                continue;
            }
            let (gx, gy) = gradient(rgb, sx, sy);
            let m = (gx * gx + gy * gy).sqrt();
            if m == 0.0 {
                continue;
            }
            let mut theta = gy.atan2(gx);
            if theta < 0.0 {
                theta += std::f64::consts::TAU;
            }
            let (o0, o1, f) = orientation_split(theta * ORIENTATIONS as f64 / std::f64::consts::TAU);
            let (dxf, dyf) = (dx as f64, dy as f64);
            let g = (-(dxf * dxf + dyf * dyf) / (2.0 * sigma * sigma)).exp();
            for i in 0..CELLS {
                let wy = params.tri(dyf - params.cell_centre(i));
                for j in 0..CELLS {
                    let wx = params.tri(dxf - params.cell_centre(j));
                    let wt = g * wx * wy * m;
                    let base = (i * CELLS + j) * ORIENTATIONS;
                    hist[base + o0] += wt * (1.0 - f);
                    hist[base + o1] += wt * f;
                }
            }
        }
    }
    hist
}

/// Lowe's normalisation with the contrast fade and the scale (SPEC.md §9a.2), f64:
/// `scale · min(1, ‖h‖₁ / (W₁ τ)) · v / ‖v‖₂`, `v = min(h / ‖h‖₂, 0.2)`; zero for `h = 0`.
pub fn normalise_reference(hist: &[f64; CHANNELS], params: &DsiftParams) -> [f64; CHANNELS] {
    let n1: f64 = hist.iter().sum();
    let n2 = hist.iter().map(|v| v * v).sum::<f64>().sqrt();
    if n2 == 0.0 {
        return [0.0; CHANNELS];
    }
    let fade = (n1 / (params.unit_field_weight() * params.min_contrast)).min(1.0);
    let v = hist.map(|h| (h / n2).min(CLIP));
    let nv = v.iter().map(|v| v * v).sum::<f64>().sqrt();
    v.map(|v| params.scale * fade * v / nv)
}

/// The weighted mean gradient magnitude `‖h‖₁ / W₁` of pixel `(x, y)`'s window, grey levels per
/// pixel (the contrast the fade compares with `τ`).
pub fn contrast_reference(rgb: &ArrayView3<f32>, params: &DsiftParams, x: usize, y: usize) -> f64 {
    histogram_reference(rgb, params, x, y).iter().sum::<f64>() / params.unit_field_weight()
}

/// Dense SIFT per its definition: [`histogram_reference`] then [`normalise_reference`] at every
/// pixel, rounded once to f32. `rgb` must be `[H >= 1, W >= 1, 3]` (checked by
/// [`super::dense_sift`]).
pub fn dense_sift_reference(rgb: ArrayView3<f32>, params: &DsiftParams) -> Array3<f32> {
    let (h, w, _) = rgb.dim();
    let mut out = Array3::<f32>::zeros((h, w, CHANNELS));
    for y in 0..h {
        for x in 0..w {
            let d = normalise_reference(&histogram_reference(&rgb, params, x, y), params);
            for (c, v) in d.iter().enumerate() {
                out[[y, x, c]] = *v as f32;
            }
        }
    }
    out
}
