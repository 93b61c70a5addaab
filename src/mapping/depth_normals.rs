//! Normals from a depth map (SPEC.md §10.2, `--normals gt`): a least-squares plane, affine in
//! inverse depth, through a window around each pixel, the pixel's own surface only.

use nalgebra::{Matrix3, Vector3};
use ndarray::Array3;
use rayon::prelude::*;

use crate::geometry::PinholeCamera;
use crate::image::{is_valid_depth, DepthMap};

/// Window half-width per 256 px of focal length (the renders' `f`): the window spans the same angle
/// at any resolution (`fit_radius`).
pub const FIT_RADIUS_PER_256PX: f64 = 3.0;

/// A neighbour joins a pixel's plane only if its depth is within this fraction of the pixel's own
/// (`|z_n − z| ≤ 0.05 z`): the window stops at an occlusion edge.
pub const FIT_DEPTH_GATE: f64 = 0.05;

/// Half-width of the window for a camera: `max(1, round(3 · min(|f_x|, |f_y|) / 256))` pixels
/// (3 at the renders' `f` = 256, 7 at SUN3D's 570).
pub fn fit_radius(camera: &PinholeCamera) -> usize {
    let f = camera.fx.abs().min(camera.fy.abs());
    ((FIT_RADIUS_PER_256PX * f / 256.0).round() as usize).max(1)
}

/// Camera-frame normals from a depth map (metres, `[H, W]`) seen by `camera`.
///
/// A plane `nᵀX + δ = 0` has an inverse depth affine in the pixel, `ρ(u, v) = −nᵀK⁻¹ũ / δ`, so its
/// normal is `n ∝ ±(f_x ∂ρ/∂u, f_y ∂ρ/∂v, ρ(c_x, c_y))`. Each valid pixel `(x, y)` fits
/// `ρ ≈ a + b (u − x) + c (v − y)` by least squares over its support: the pixels of the `(2r+1)²`
/// window around it ([`fit_radius`]), clipped to the image, with valid depth `z_n` and
/// `|z_n − z| ≤` [`FIT_DEPTH_GATE`]` · z` (its own surface). The normal is
/// `(f_x b, f_y c, a + b (c_x − x) + c (c_y − y))` normalised and oriented towards the camera
/// (`nᵀX < 0`). The fit is in the variable a sensor's noise is in (along the ray), so it is unbiased,
/// where a total-least-squares plane through the 3D points tilts towards the rays. NaN where the pixel
/// has no depth, the support has fewer than `max(6, ⌈(2r+1)²/4⌉)` pixels, or their pixel positions
/// are collinear. Sums in f64: per window row, `Σ ρ` and `Σ du ρ` with `du` ascending; then the
/// rows with `dv` ascending (`Σ_dv S_ρ`, `Σ_dv S_uρ`, `Σ_dv dv S_ρ`).
///
/// Fast path: a window wholly inside the image whose depths all pass the gate (its minimum and
/// maximum do) takes its row sums from one horizontal pass shared by every pixel of the row, so it
/// costs `O(r)` instead of `O(r²)`; any other window is summed pixel by pixel. Both give the bits of
/// [`normals_from_depth_reference`]. Every output depends on its own window only, so rows run in
/// parallel and the result is the same for any thread count.
pub fn normals_from_depth(depth: &DepthMap, camera: &PinholeCamera) -> Array3<f32> {
    let (h, w) = depth.dim();
    let r = fit_radius(camera);
    let min_support = min_support(r);
    let ri = r as isize;
    let full = |x: usize, len: usize| x >= r && x + r < len;
    // Horizontal passes over each row's full windows: the lowest and highest depth (an invalid one
    // reads -1 and +inf, so the window fails the gate), and the row sums of ρ and du·ρ.
    let rho = depth.mapv(|z| if is_valid_depth(z) { 1.0 / z as f64 } else { f64::NAN });
    let horizontal: Vec<RowPass> = (0..h)
        .into_par_iter()
        .map(|y| {
            let (mut lo, mut hi) = (vec![f32::NAN; w], vec![f32::NAN; w]);
            let (mut sr, mut sur) = (vec![f64::NAN; w], vec![f64::NAN; w]);
            for x in (0..w).filter(|&x| full(x, w)) {
                let (mut l, mut u, mut a, mut b) = (f32::INFINITY, f32::NEG_INFINITY, 0.0f64, 0.0f64);
                for du in -ri..=ri {
                    let xx = (x as isize + du) as usize;
                    let z = depth[[y, xx]];
                    let (zl, zh) = if is_valid_depth(z) { (z, z) } else { (-1.0, f32::INFINITY) };
                    l = l.min(zl);
                    u = u.max(zh);
                    let p = rho[[y, xx]];
                    a += p;
                    b += du as f64 * p;
                }
                (lo[x], hi[x], sr[x], sur[x]) = (l, u, a, b);
            }
            RowPass { lo, hi, sr, sur }
        })
        .collect();
    let rows: Vec<Vec<[f32; 3]>> = (0..h)
        .into_par_iter()
        .map(|y| {
            let mut row = vec![[f32::NAN; 3]; w];
            for (x, cell) in row.iter_mut().enumerate() {
                let zc = depth[[y, x]];
                if !is_valid_depth(zc) {
                    continue;
                }
                let zc = zc as f64;
                let clean = full(x, w)
                    && full(y, h)
                    && (y - r..=y + r).all(|yy| {
                        let (l, u) = (horizontal[yy].lo[x] as f64, horizontal[yy].hi[x] as f64);
                        (l - zc).abs() <= FIT_DEPTH_GATE * zc && (u - zc).abs() <= FIT_DEPTH_GATE * zc
                    });
                let fit = if clean {
                    let mut fit = AffineFit::full_window(r);
                    for dv in -ri..=ri {
                        let yy = (y as isize + dv) as usize;
                        fit.add_row(dv as f64, horizontal[yy].sr[x], horizontal[yy].sur[x]);
                    }
                    fit
                } else {
                    window_fit(depth, x, y, r)
                };
                if fit.n < min_support as f64 {
                    continue;
                }
                if let Some(n) = fit.normal(camera, x as f64, y as f64) {
                    *cell = n;
                }
            }
            row
        })
        .collect();
    to_array(rows, h, w)
}

/// [`normals_from_depth`] by its definition: every pixel's window summed pixel by pixel (the
/// oracle of the fast path, `tests/depth_normals.rs`).
pub fn normals_from_depth_reference(depth: &DepthMap, camera: &PinholeCamera) -> Array3<f32> {
    let (h, w) = depth.dim();
    let r = fit_radius(camera);
    let min_support = min_support(r);
    let mut rows = Vec::with_capacity(h);
    for y in 0..h {
        let mut row = vec![[f32::NAN; 3]; w];
        for (x, cell) in row.iter_mut().enumerate() {
            if !is_valid_depth(depth[[y, x]]) {
                continue;
            }
            let fit = window_fit(depth, x, y, r);
            if fit.n >= min_support as f64 {
                if let Some(n) = fit.normal(camera, x as f64, y as f64) {
                    *cell = n;
                }
            }
        }
        rows.push(row);
    }
    to_array(rows, h, w)
}

/// One row's horizontal pass over its full windows (NaN where the window leaves the image).
struct RowPass {
    /// The lowest depth of the window (-1 if one is invalid).
    lo: Vec<f32>,
    /// The highest depth of the window (+inf if one is invalid).
    hi: Vec<f32>,
    /// `Σ ρ` over the window, `du` ascending.
    sr: Vec<f64>,
    /// `Σ du·ρ` over the window, `du` ascending.
    sur: Vec<f64>,
}

/// The smallest support that gets a normal: `max(6, ⌈(2r+1)²/4⌉)`.
fn min_support(r: usize) -> usize {
    6usize.max(((2 * r + 1) * (2 * r + 1)).div_ceil(4))
}

/// The sums of pixel `(x, y)`'s support, pixel by pixel in the order of [`normals_from_depth`].
fn window_fit(depth: &DepthMap, x: usize, y: usize, r: usize) -> AffineFit {
    let (h, w) = depth.dim();
    let zc = depth[[y, x]] as f64;
    let mut fit = AffineFit::default();
    for yy in y.saturating_sub(r)..(y + r + 1).min(h) {
        let (mut sr, mut sur) = (0.0f64, 0.0f64);
        for xx in x.saturating_sub(r)..(x + r + 1).min(w) {
            let z = depth[[yy, xx]];
            if is_valid_depth(z) && (z as f64 - zc).abs() <= FIT_DEPTH_GATE * zc {
                let (du, dv) = (xx as f64 - x as f64, yy as f64 - y as f64);
                fit.add_moments(du, dv);
                let p = 1.0 / z as f64;
                sr += p;
                sur += du * p;
            }
        }
        fit.add_row(yy as f64 - y as f64, sr, sur);
    }
    fit
}

fn to_array(rows: Vec<Vec<[f32; 3]>>, h: usize, w: usize) -> Array3<f32> {
    let flat: Vec<f32> = rows.into_iter().flatten().flatten().collect();
    Array3::from_shape_vec((h, w, 3), flat).expect("h rows of w normals")
}

/// The sums of a least-squares fit `ρ ≈ a + b du + c dv` (offsets from the pixel): the offsets'
/// moments, and `Σ ρ`, `Σ du ρ`, `Σ dv ρ` built row by row.
#[derive(Default)]
struct AffineFit {
    n: f64,
    u: f64,
    v: f64,
    uu: f64,
    uv: f64,
    vv: f64,
    r: f64,
    ur: f64,
    vr: f64,
}

impl AffineFit {
    /// One support pixel's offsets (integers: exact in any order).
    fn add_moments(&mut self, du: f64, dv: f64) {
        self.n += 1.0;
        self.u += du;
        self.v += dv;
        self.uu += du * du;
        self.uv += du * dv;
        self.vv += dv * dv;
    }

    /// One window row's sums `Σ ρ` and `Σ du ρ`, at offset `dv`.
    fn add_row(&mut self, dv: f64, sr: f64, sur: f64) {
        self.r += sr;
        self.ur += sur;
        self.vr += dv * sr;
    }

    /// The offsets' moments of a full `(2r+1)²` window.
    fn full_window(r: usize) -> Self {
        let side = (2 * r + 1) as f64;
        let squares: f64 = (-(r as isize)..=r as isize).map(|d| (d * d) as f64).sum();
        Self { n: side * side, uu: side * squares, vv: side * squares, ..Self::default() }
    }

    /// The oriented unit normal of the fitted plane at pixel `(x, y)`; `None` when the offsets are
    /// collinear (the normal equations' determinant, an integer, is 0).
    fn normal(&self, camera: &PinholeCamera, x: f64, y: f64) -> Option<[f32; 3]> {
        let m = Matrix3::new(self.n, self.u, self.v, self.u, self.uu, self.uv, self.v, self.uv, self.vv);
        if m.determinant() < 0.5 {
            return None;
        }
        let p = m.cholesky()?.solve(&Vector3::new(self.r, self.ur, self.vr));
        let (a, b, c) = (p[0], p[1], p[2]);
        let mut n = [camera.fx * b, camera.fy * c, a + b * (camera.cx - x) + c * (camera.cy - y)];
        let norm = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
        if !(norm > 0.0 && norm.is_finite()) {
            return None;
        }
        // Towards the camera: nᵀK⁻¹ũ < 0 at the pixel itself (the sign of nᵀX, z > 0).
        let ray = [(x - camera.cx) / camera.fx, (y - camera.cy) / camera.fy, 1.0];
        let s = if n[0] * ray[0] + n[1] * ray[1] + n[2] * ray[2] > 0.0 { -1.0 } else { 1.0 };
        for v in &mut n {
            *v *= s / norm;
        }
        Some([n[0] as f32, n[1] as f32, n[2] as f32])
    }
}
