//! Bilinear and nearest sampling with pixel centres at integer coordinates.
//!
//! ```text
//!   x0 = floor(x), a = x - x0          valid iff 0 <= x <= W-1 and 0 <= y <= H-1
//!   (x0,y0) ---- (x0+1,y0)             value = (1-a)(1-b) I00 + a(1-b) I10
//!      |    *(x,y)   |                          + (1-a) b I01 + a b I11
//!   (x0,y0+1) -- (x0+1,y0+1)           at x = W-1 exactly, x0 = W-2 and a = 1 (so no read past
//!                                       the edge); a 1-pixel-wide image needs x = 0
//! ```
//! This is PyTorch's `grid_sample(align_corners=True)` with `x_n = 2x/(W-1) - 1`, restricted to the
//! in-bounds region (SPEC.md §2.1).

use ndarray::{ArrayView2, ArrayView3};

/// Corner index and weight along one axis; `None` outside `[0, n-1]` (also used by the training
/// loss, which needs the corners themselves for its backward pass).
#[inline]
pub(crate) fn axis(x: f64, n: usize) -> Option<(usize, usize, f64)> {
    if !(x >= 0.0 && x <= (n - 1) as f64) {
        return None;
    }
    if n == 1 {
        return Some((0, 0, 0.0));
    }
    // x >= 0 here, so truncation is the floor (and needs no libm call).
    let x0 = (x as usize).min(n - 2);
    Some((x0, x0 + 1, x - x0 as f64))
}

/// Bilinearly sample every channel of `img` (`[H, W, C]`) at `(x, y)` into `out` (length `C`).
/// Returns `false`, leaving `out` untouched, when `(x, y)` is outside the image.
///
/// # Panics
/// If `out.len()` differs from the channel count.
pub fn sample_bilinear(img: &ArrayView3<f32>, x: f64, y: f64, out: &mut [f32]) -> bool {
    let (h, w, c) = img.dim();
    assert_eq!(out.len(), c, "output length must equal the channel count");
    let (Some((x0, x1, a)), Some((y0, y1, b))) = (axis(x, w), axis(y, h)) else {
        return false;
    };
    let (w00, w10, w01, w11) = ((1.0 - a) * (1.0 - b), a * (1.0 - b), (1.0 - a) * b, a * b);
    for (ch, o) in out.iter_mut().enumerate() {
        let v = w00 * img[[y0, x0, ch]] as f64
            + w10 * img[[y0, x1, ch]] as f64
            + w01 * img[[y1, x0, ch]] as f64
            + w11 * img[[y1, x1, ch]] as f64;
        *o = v as f32;
    }
    true
}

/// Nearest-neighbour sample of a single-channel map at `(x, y)` (rounding half away from zero);
/// `None` outside `[-0.5, W-0.5) x [-0.5, H-0.5)`.
pub fn sample_nearest(img: &ArrayView2<f32>, x: f64, y: f64) -> Option<f32> {
    let (h, w) = img.dim();
    let (xi, yi) = (x.round(), y.round());
    if xi < 0.0 || yi < 0.0 || xi > (w - 1) as f64 || yi > (h - 1) as f64 || x.is_nan() || y.is_nan() {
        return None;
    }
    Some(img[[yi as usize, xi as usize]])
}
