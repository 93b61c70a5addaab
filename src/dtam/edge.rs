//! Edge weights `g(u) = exp(-α ‖∇I(u)‖^β)` from the reference image, `I` = grey level / 255, `∇`
//! forward differences (zero across the last row/column), as in DTAM.

use ndarray::{Array2, ArrayView2};

/// `[H, W]` weights in `(0, 1]`; 1 where the image is flat.
pub fn edge_weights(grey: ArrayView2<f32>, alpha: f64, beta: f64) -> Array2<f32> {
    let (h, w) = grey.dim();
    Array2::from_shape_fn((h, w), |(y, x)| {
        let i = grey[[y, x]] as f64 / 255.0;
        let gx = if x + 1 < w { grey[[y, x + 1]] as f64 / 255.0 - i } else { 0.0 };
        let gy = if y + 1 < h { grey[[y + 1, x]] as f64 / 255.0 - i } else { 0.0 };
        let n = (gx * gx + gy * gy).sqrt();
        (-alpha * n.powf(beta)).exp() as f32
    })
}
