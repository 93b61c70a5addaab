//! The surface-normal prior (SPEC.md §10.2; after Weerasekera et al., ICRA 2017, "Dense monocular
//! reconstruction using surface normals", the regulariser of the paper's Table 1): DTAM's
//! `g ‖∇ρ‖_ε` becomes `g ‖∇ρ − ρ q(u)‖_ε`.
//!
//! **Why `q`.** A plane `nᵀX + δ = 0` (camera frame) seen at pixel `u` has depth `z` with
//! `z nᵀK⁻¹ũ = −δ`, so `ρ(u) = −nᵀK⁻¹ũ / δ`: affine in `u`, with
//! `∂ρ/∂u = −n_x / (f_x δ) = ρ · (n_x/f_x) / (nᵀK⁻¹ũ)` and likewise for `v`. Hence
//! `∇ρ = ρ q(u)`, `q(u) = (n_x/f_x, n_y/f_y) / (nᵀK⁻¹ũ)`, independent of the plane's offset and of
//! the normal's orientation (`q` is homogeneous of degree 0 in `n`). `ρ` being affine, its forward
//! differences equal the derivatives, so `K_n ρ = 0` holds exactly on a rendered plane
//! (`normal_prior_annihilates_a_rendered_plane` in tests/dtam_normals.rs).
//!
//! **Operator.** `K_n ρ = ∇ρ − ρ q` with DTAM's forward differences (zero across the last
//! column/row) and `q_x = 0` in the last column, `q_y = 0` in the last row (the Neumann boundary:
//! there the difference is zero, and so is the predicted one). Its adjoint is
//! `K_nᵀ p = −div p − q·p` ([`adjoint`]). `‖K_n‖ ≤ ‖∇‖ + max|q| ≤ √8 + Q`, so the solver steps with
//! `σ = τ = 1/(√8 + Q)` ([`step_size`]): `σ τ ‖diag(g) K_n‖² ≤ 1` for `g ≤ 1`.
//!
//! **Fallback.** Where a pixel has no normal (non-finite or zero), or the view ray grazes the plane
//! (`|nᵀK⁻¹ũ| < GRAZING_COS ‖K⁻¹ũ‖`, i.e. more than ~84° between ray and normal, where `q` blows
//! up), `q = 0`: plain TV there.
//!
//! This file holds the definition: the slope field, `K_n` and `K_nᵀ` in f64, and [`Reference`], a
//! naive f64 primal-dual solver the row-parallel f32 kernels (`super::normal_steps`) are tested
//! against.

use ndarray::{Array2, ArrayView2, ArrayView3};

use crate::error::{Error, Result};
use crate::geometry::PinholeCamera;

/// Below this `|cos|` between the view ray and the normal, `q = 0` (grazing view).
pub const GRAZING_COS: f64 = 0.1;

/// The field `q(u)` of the normal prior at the solver's grid, with its largest norm.
#[derive(Clone, Debug)]
pub struct SlopeField {
    /// `q_x` per pixel (1/pixel), 0 in the last column and where the prior falls back.
    pub qx: Array2<f32>,
    /// `q_y` per pixel (1/pixel), 0 in the last row and where the prior falls back.
    pub qy: Array2<f32>,
    /// `Q = max_u |q(u)|` (from the stored f32 values, in f64).
    pub max_norm: f64,
    /// Pixels that fell back to `q = 0` (no normal, or grazing), last row/column excluded.
    pub fallback: usize,
    /// The normals' edge weights `w(u)` (SPEC.md §10.2, "Normal edges"), which multiply DTAM's `g` in
    /// the prior's solve; `None`: off (`g` alone, the paper's form).
    pub edges: Option<Array2<f32>>,
}

impl SlopeField {
    /// The field from camera-frame normals `[H, W, 3]` on `camera`'s grid (non-finite or zero
    /// vectors: no normal). Normals need not be unit length (only their direction counts).
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] if the normals' grid is not `camera`'s `[H, W, 3]`.
    pub fn new(normals: ArrayView3<f32>, camera: &PinholeCamera) -> Result<Self> {
        let (h, w, c) = normals.dim();
        if (h, w, c) != (camera.height, camera.width, 3) {
            return Err(Error::invalid_argument(
                "normals",
                format!(
                    "{:?} do not match the {}x{} grid: need [{}, {}, 3]",
                    normals.dim(),
                    camera.width,
                    camera.height,
                    camera.height,
                    camera.width
                ),
            ));
        }
        let mut qx = Array2::<f32>::zeros((h, w));
        let mut qy = Array2::<f32>::zeros((h, w));
        let mut fallback = 0;
        for y in 0..h {
            for x in 0..w {
                let n = [normals[[y, x, 0]] as f64, normals[[y, x, 1]] as f64, normals[[y, x, 2]] as f64];
                match slope(n, x as f64, y as f64, camera) {
                    Some((sx, sy)) => {
                        qx[[y, x]] = if x + 1 < w { sx as f32 } else { 0.0 };
                        qy[[y, x]] = if y + 1 < h { sy as f32 } else { 0.0 };
                    }
                    None => fallback += 1,
                }
            }
        }
        let max_norm = largest_norm(&qx, &qy);
        Ok(Self { qx, qy, max_norm, fallback, edges: None })
    }

    /// The field with the normals' edge weights of `normals` (the grid [`SlopeField::new`] took) at
    /// scale `σ` degrees (SPEC.md §10.2, "Normal edges"): `w(u) = exp(−(a(u)/σ)²)`, `a(u)` the larger
    /// angle between `u`'s normal and its right and lower neighbours' ([`normal_edge_weights`]).
    /// `σ = 0` turns them off (the field's bits unchanged).
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] (`prior-edges`) if `σ` is negative or not finite, or the normals
    /// are not on the field's grid.
    pub fn with_normal_edges(self, normals: ArrayView3<f32>, sigma_deg: f64) -> Result<Self> {
        check_prior_edges(sigma_deg)?;
        let (h, w) = self.dim();
        if normals.dim() != (h, w, 3) {
            return Err(Error::invalid_argument(
                "prior-edges",
                format!("{:?} normals for a {:?} slope field", normals.dim(), (h, w)),
            ));
        }
        let edges = (sigma_deg > 0.0).then(|| normal_edge_weights(normals, sigma_deg));
        Ok(Self { edges, ..self })
    }

    /// DTAM's edge weights `g` times the normals' edge weights, if on (f32 products; `g` itself
    /// otherwise): the weights of the prior's solve.
    ///
    /// # Panics
    /// If `g` differs in shape from the field (callers validate shapes).
    pub fn solver_weights(&self, g: Array2<f32>) -> Array2<f32> {
        match &self.edges {
            Some(e) => {
                assert_eq!(e.dim(), g.dim(), "edge weights must match the image");
                g * e
            }
            None => g,
        }
    }

    /// An all-zero field (plain TV through the normal-prior solver).
    pub fn zeros(h: usize, w: usize) -> Self {
        Self { qx: Array2::zeros((h, w)), qy: Array2::zeros((h, w)), max_norm: 0.0, fallback: 0, edges: None }
    }

    /// `[H, W]`.
    pub fn dim(&self) -> (usize, usize) {
        self.qx.dim()
    }

    /// The field with each pixel's slope scaled by the data term's confidence (SPEC.md §10.2,
    /// "Confidence weighting"): `q ← w q`, `w = clamp(conf / c₀, 0, 1)` in f64, the product rounded
    /// to f32 once. `c₀ = 0` returns the field unchanged (bit for bit). Where the cost volume cannot
    /// anchor the depth (`conf` low), the prior becomes plain TV, so it does not carry a plane's slope
    /// across a region only its neighbours decide. `w ≤ 1`, so `Q` (and the step size) can only
    /// shrink; `fallback` is kept (it counts the pixels without a usable normal).
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] (`prior-confidence`) if `c₀` is negative or not finite, or
    /// `confidence` is not on the field's `[H, W]` grid.
    pub fn weighted_by_confidence(&self, confidence: ArrayView2<f32>, c0: f64) -> Result<Self> {
        check_prior_confidence(c0)?;
        if confidence.dim() != self.dim() {
            return Err(Error::invalid_argument(
                "prior-confidence",
                format!("a {:?} confidence map for a {:?} slope field", confidence.dim(), self.dim()),
            ));
        }
        if c0 == 0.0 {
            return Ok(self.clone());
        }
        let weight = |c: f32| (f64::from(c) / c0).clamp(0.0, 1.0);
        let scale = |q: &Array2<f32>| {
            ndarray::Zip::from(q).and(&confidence).map_collect(|&q, &c| (f64::from(q) * weight(c)) as f32)
        };
        let (qx, qy) = (scale(&self.qx), scale(&self.qy));
        let max_norm = largest_norm(&qx, &qy);
        Ok(Self { qx, qy, max_norm, fallback: self.fallback, edges: self.edges.clone() })
    }
}

/// `Q = max_u |q(u)|` from the stored f32 values, in f64.
fn largest_norm(qx: &Array2<f32>, qy: &Array2<f32>) -> f64 {
    qx.iter().zip(qy.iter()).map(|(&a, &b)| (a as f64).hypot(b as f64)).fold(0.0, f64::max)
}

/// Checks `--prior-confidence`'s `c₀` (SPEC.md §10.2): finite and `>= 0` (0: off).
///
/// # Errors
/// [`Error::InvalidArgument`] (`prior-confidence`) otherwise.
pub fn check_prior_confidence(c0: f64) -> Result<()> {
    check_off_or_positive("prior-confidence", c0, "number")
}

/// Checks `--prior-edges`'s `σ` (SPEC.md §10.2): finite and `>= 0` degrees (0: off).
///
/// # Errors
/// [`Error::InvalidArgument`] (`prior-edges`) otherwise.
pub fn check_prior_edges(sigma_deg: f64) -> Result<()> {
    check_off_or_positive("prior-edges", sigma_deg, "angle in degrees")
}

/// A prior option's value: finite and `>= 0`, 0 meaning off; the error names `flag` and `what` it is.
fn check_off_or_positive(flag: &str, value: f64, what: &str) -> Result<()> {
    if value >= 0.0 && value.is_finite() {
        Ok(())
    } else {
        Err(Error::invalid_argument(flag, format!("{value}: must be a finite {what} >= 0 (0: off)")))
    }
}

/// The normals' edge weights `[H, W]` at scale `σ > 0` degrees (SPEC.md §10.2, "Normal edges"), in
/// f64 rounded to f32 once: `w(u) = exp(−(a(u)/σ)²)` with `a(u) = max(∠(n(u), n(u + x̂)),
/// ∠(n(u), n(u + ŷ)))`, the angle `acos(clamp(n̂·n̂', −1, 1))` in degrees between unit normals; a
/// neighbour outside the grid, or a pixel or neighbour without a normal (non-finite or zero), adds
/// angle 0. Where the normal turns (a crease, or one surface in front of another) the prior's
/// coupling across that pixel's forward differences falls, as DTAM's `g` does at an image edge.
/// The normals' signs count (unlike in `q`): they must be oriented alike, e.g. towards the camera.
pub fn normal_edge_weights(normals: ArrayView3<f32>, sigma_deg: f64) -> Array2<f32> {
    let (h, w, _) = normals.dim();
    let unit = |y: usize, x: usize| {
        let n = [normals[[y, x, 0]] as f64, normals[[y, x, 1]] as f64, normals[[y, x, 2]] as f64];
        let m = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
        (m.is_finite() && m > 0.0).then(|| [n[0] / m, n[1] / m, n[2] / m])
    };
    let angle = |a: Option<[f64; 3]>, b: Option<[f64; 3]>| match (a, b) {
        (Some(a), Some(b)) => (a[0] * b[0] + a[1] * b[1] + a[2] * b[2]).clamp(-1.0, 1.0).acos().to_degrees(),
        _ => 0.0,
    };
    Array2::from_shape_fn((h, w), |(y, x)| {
        let n = unit(y, x);
        let ax = if x + 1 < w { angle(n, unit(y, x + 1)) } else { 0.0 };
        let ay = if y + 1 < h { angle(n, unit(y + 1, x)) } else { 0.0 };
        (-(ax.max(ay) / sigma_deg).powi(2)).exp() as f32
    })
}

/// `q(u)` for the normal `n` at pixel `(u, v)`, `None` where the prior falls back (module docs).
pub fn slope(n: [f64; 3], u: f64, v: f64, camera: &PinholeCamera) -> Option<(f64, f64)> {
    let norm = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
    if !(norm.is_finite() && norm > 0.0) {
        return None;
    }
    let ray = [(u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy, 1.0];
    let den = n[0] * ray[0] + n[1] * ray[1] + n[2] * ray[2];
    let ray_norm = (ray[0] * ray[0] + ray[1] * ray[1] + 1.0).sqrt();
    if den.abs() < GRAZING_COS * norm * ray_norm {
        return None;
    }
    Some((n[0] / camera.fx / den, n[1] / camera.fy / den))
}

/// Primal and dual step `σ = τ = 1/(√8 + Q)` for a field of largest norm `Q`.
pub fn step_size(max_norm: f64) -> f64 {
    1.0 / (8f64.sqrt() + max_norm)
}

/// `K_n d = ∇d − d q` in f64 (the definition): `(x, y)` components per pixel.
pub fn apply(d: ArrayView2<f64>, q: &SlopeField) -> (Array2<f64>, Array2<f64>) {
    let (h, w) = d.dim();
    let kx = Array2::from_shape_fn((h, w), |(y, x)| {
        let diff = if x + 1 < w { d[[y, x + 1]] - d[[y, x]] } else { 0.0 };
        diff - d[[y, x]] * q.qx[[y, x]] as f64
    });
    let ky = Array2::from_shape_fn((h, w), |(y, x)| {
        let diff = if y + 1 < h { d[[y + 1, x]] - d[[y, x]] } else { 0.0 };
        diff - d[[y, x]] * q.qy[[y, x]] as f64
    });
    (kx, ky)
}

/// `K_nᵀ p = −div p − q·p` in f64 (the definition; `−div` the exact adjoint of the forward
/// differences).
pub fn adjoint(px: ArrayView2<f64>, py: ArrayView2<f64>, q: &SlopeField) -> Array2<f64> {
    Array2::from_shape_fn(px.dim(), |(y, x)| {
        super::tgv::neg_div(&px, &py, y, x)
            - (q.qx[[y, x]] as f64 * px[[y, x]] + q.qy[[y, x]] as f64 * py[[y, x]])
    })
}

/// The naive f64 Chambolle-Pock solver of `min_d Σ ‖g K_n d‖_ε + 1/(2θ) ‖d − a‖²`: whole-array
/// passes through [`apply`] and [`adjoint`], every value in f64. The oracle of the row-parallel
/// f32 steps.
#[derive(Clone, Debug)]
pub struct Reference {
    /// Primal `d`.
    pub d: Array2<f64>,
    d_bar: Array2<f64>,
    /// Dual `p = (px, py)`.
    pub px: Array2<f64>,
    /// Dual, `y` component.
    pub py: Array2<f64>,
    g: Array2<f64>,
    q: SlopeField,
    eps: f64,
    step: f64,
}

impl Reference {
    /// Start from `d0`, zero dual.
    pub fn new(d0: ArrayView2<f32>, g: ArrayView2<f32>, eps: f64, q: SlopeField) -> Self {
        let d = d0.mapv(f64::from);
        let zeros = Array2::zeros(d.dim());
        let step = step_size(q.max_norm);
        let g = q.solver_weights(g.to_owned()).mapv(f64::from);
        Self { d_bar: d.clone(), d, px: zeros.clone(), py: zeros, g, q, eps, step }
    }

    /// One step: `p ← Π((p + σ g K_n d̄)/(1 + σε))`, `d' ← (d − τ K_nᵀ(g p) + τ a/θ)/(1 + τ/θ)`,
    /// `d̄ ← 2d' − d`.
    pub fn step(&mut self, a: ArrayView2<f32>, theta: f64) {
        let s = self.step;
        let (kx, ky) = apply(self.d_bar.view(), &self.q);
        for ((y, x), px) in self.px.indexed_iter_mut() {
            let g = self.g[[y, x]];
            let nx = (*px + s * g * kx[[y, x]]) / (1.0 + s * self.eps);
            let ny = (self.py[[y, x]] + s * g * ky[[y, x]]) / (1.0 + s * self.eps);
            let m = (nx * nx + ny * ny).sqrt().max(1.0);
            *px = nx / m;
            self.py[[y, x]] = ny / m;
        }
        let gpx = &self.px * &self.g;
        let gpy = &self.py * &self.g;
        let kt = adjoint(gpx.view(), gpy.view(), &self.q);
        let old = self.d.clone();
        for ((y, x), d) in self.d.indexed_iter_mut() {
            *d = (*d - s * kt[[y, x]] + s * a[[y, x]] as f64 / theta) / (1.0 + s / theta);
        }
        self.d_bar = &self.d * 2.0 - &old;
    }

    /// `Σ ‖g K_n d‖_ε` in f64.
    pub fn regulariser_energy(&self) -> f64 {
        let (kx, ky) = apply(self.d.view(), &self.q);
        let mut e = 0.0;
        for ((y, x), g) in self.g.indexed_iter() {
            e += super::huber_tv::huber(g * kx[[y, x]], g * ky[[y, x]], self.eps);
        }
        e
    }
}
