//! Photometric sub-bin refinement of a keyframe's regularised depth (SPEC.md §10.3).
//!
//! After DTAM, every input-resolution pixel's inverse depth is searched again within
//! `± radius_bins` bin steps of the estimate (bilinearly upsampled from the mapper's level), by the
//! zero-mean normalised cross-correlation of grey `(2r+1)²` windows against a few live frames at
//! their own resolution. Per hypothesis the mean of the best half of the frames' costs is taken (a
//! frame that is occluded there is outvoted), the minimum over the hypotheses is located to a
//! fraction of a sample by a parabola, and a pixel moves only where that minimum is interior and
//! curved enough. The level-`L` estimate then moves by the tent-weighted mean of the moves of the
//! level-0 pixels it was interpolated to (the adjoint of the upsampling).
//!
//! [`refine_level0`] is the fast path (whole-image warps, separable window sums, rows in parallel);
//! [`refine_level0_reference`] the plain-loop reference that it equals bit for bit (the window sums
//! are formed in the same order: a row's sum over `dx`, then the rows' sums over `dy`).

use nalgebra::{Matrix3, Vector3};
use ndarray::{Array2, ArrayView2, Zip};
use rayon::prelude::*;
use serde::Serialize;

use crate::error::{Error, Result};
use crate::geometry::{InverseDepthBins, PinholeCamera, Pose};

/// The refinement's parameters (SPEC.md §10.3; defaults [`REFINE_DEFAULTS`], chosen on the
/// validation scenes by mesh F-score, docs/map/results.md).
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct RefineParams {
    /// Half-width of the search, in steps `Δρ = (ρ_max − ρ_min)/(K₀ − 1)`, `K₀` =
    /// [`REFERENCE_BINS`] whatever the volume's `K` (SPEC.md §10.3).
    pub radius_bins: f64,
    /// Hypotheses over `[−radius, radius]`, evenly spaced, odd (the estimate itself is one).
    pub samples: usize,
    /// The window is `(2 r + 1)²` pixels.
    pub half_window: usize,
    /// At most this many live frames: every `⌈n / frames⌉`-th of the window, from its first.
    pub frames: usize,
    /// Per hypothesis, the mean of the lowest `⌈fraction · n⌉` of the `n` frames' costs.
    pub best_fraction: f64,
    /// A keyframe window whose grey variance (levels², `0..=255`) is at most this is not refined.
    pub min_variance: f64,
    /// The parabola's second difference per squared bin step must exceed this.
    pub min_curvature: f64,
}

/// The defaults of `map` (SPEC.md §10.3, §16.9).
pub const REFINE_DEFAULTS: RefineParams = RefineParams {
    radius_bins: 2.0,
    samples: 17,
    half_window: 3,
    frames: 12,
    best_fraction: 0.5,
    min_variance: 9.0,
    min_curvature: 0.002,
};

/// The refinement's step `Δρ` is the range over this many bins, whatever `--bins` is: its radius and
/// curvature floor were chosen at the default 128 bins, and keep their meaning in inverse depth
/// when the volume is finer or coarser (SPEC.md §10.3).
pub const REFERENCE_BINS: usize = 128;

/// Variance floor inside the correlation's square root (levels²).
const VARIANCE_FLOOR: f64 = 1e-6;

impl RefineParams {
    /// # Errors
    /// [`Error::InvalidArgument`] naming the parameter that is out of range.
    pub fn validate(&self) -> Result<()> {
        let bad = |what: &str, why: String| Err(Error::invalid_argument(what, why));
        if !(self.radius_bins.is_finite() && self.radius_bins > 0.0) {
            return bad("refine radius", format!("{}: must be a positive number of bins", self.radius_bins));
        }
        if self.samples < 3 || self.samples.is_multiple_of(2) {
            return bad("refine samples", format!("{}: must be odd and at least 3", self.samples));
        }
        if self.half_window == 0 {
            return bad("refine window", "the half-width must be at least 1 pixel".into());
        }
        if self.frames == 0 {
            return bad("refine frames", "at least 1 live frame".into());
        }
        if !(self.best_fraction > 0.0 && self.best_fraction <= 1.0) {
            return bad("refine best fraction", format!("{}: must be in (0, 1]", self.best_fraction));
        }
        if !(self.min_variance.is_finite() && self.min_variance >= 0.0) {
            return bad("refine variance", format!("{}: must be >= 0", self.min_variance));
        }
        if !(self.min_curvature.is_finite() && self.min_curvature >= 0.0) {
            return bad("refine curvature", format!("{}: must be >= 0", self.min_curvature));
        }
        Ok(())
    }

    /// Spacing of the hypotheses in bin steps.
    fn spacing(&self) -> f64 {
        2.0 * self.radius_bins / (self.samples - 1) as f64
    }

    /// Offset of hypothesis `a`, in bin steps.
    fn offset(&self, a: usize) -> f64 {
        -self.radius_bins + a as f64 * self.spacing()
    }
}

/// One live frame: its grey image at its own resolution (`0..=255`), its camera, and `T_nr`, which
/// takes keyframe-camera points into its camera.
#[derive(Clone, Debug)]
pub struct RefineView<'a> {
    /// `[H, W]` grey levels.
    pub grey: ArrayView2<'a, f64>,
    /// The frame's camera at level 0.
    pub camera: PinholeCamera,
    /// `T_nr`.
    pub pose: Pose,
}

/// What the refinement did to one estimate.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct RefineReport {
    /// Live frames used.
    pub frames: usize,
    /// Level-0 pixels with an estimate and a window inside the image.
    pub candidates: usize,
    /// Of those, the pixels that moved.
    pub refined: usize,
}

/// Bytes the refinement holds at its peak for an `h x w` keyframe and `frames` live frames of that
/// size, a conservative bound: per pixel and frame the grey image and cost plane (f64) and 12 B for
/// the RGB frames decoded beside them, and 112 B of key sums, upsampled and refined estimates, row
/// sums and running minima.
pub fn memory_bytes(h: usize, w: usize, frames: usize) -> u64 {
    (h as u64) * (w as u64) * (112 + 28 * frames as u64)
}

/// The live frames the refinement uses: every `⌈n / frames⌉`-th of `live`, from its first.
pub fn select_frames(live: &[usize], frames: usize) -> Vec<usize> {
    let stride = live.len().div_ceil(frames.max(1)).max(1);
    live.iter().step_by(stride).copied().collect()
}

/// A live view ready to be sampled: `T_nr`'s rotation as a matrix, so that the part of the warp
/// that does not depend on the inverse depth, `R K_r⁻¹ ỹ`, is formed once per pixel (SPEC.md §10.3).
struct Warper<'a, 'v> {
    view: &'a RefineView<'v>,
    rot: Matrix3<f64>,
}

impl<'a, 'v> Warper<'a, 'v> {
    fn new(view: &'a RefineView<'v>) -> Self {
        Warper { view, rot: *view.pose.rotation.to_rotation_matrix().matrix() }
    }

    /// `R K_r⁻¹ ỹ` for the keyframe ray `ray = K_r⁻¹ ỹ`.
    #[inline]
    fn bearing(&self, ray: &Vector3<f64>) -> Vector3<f64> {
        self.rot * ray
    }

    /// The view's grey value at the point of bearing `b` and inverse depth `rho`: the point
    /// `ρ · T_nr(K_r⁻¹ỹ / ρ) = b + ρ t` (the same ray, scaled by `ρ > 0`), projected and sampled
    /// bilinearly. NaN where `rho` is not positive, the point is not in front of the camera or it
    /// projects outside `[0, W−1] × [0, H−1]`.
    #[inline]
    fn sample(&self, b: &Vector3<f64>, rho: f64) -> f64 {
        if rho.is_nan() || rho <= 0.0 {
            return f64::NAN;
        }
        let t = &self.view.pose.translation.vector;
        let p = Vector3::new(b.x + rho * t.x, b.y + rho * t.y, b.z + rho * t.z);
        let Some(q) = self.view.camera.project(&p) else { return f64::NAN };
        if !self.view.camera.contains(q.x, q.y) {
            return f64::NAN;
        }
        bilinear(&self.view.grey, q.x, q.y)
    }
}

/// Bilinear sample at `(u, v)` inside `[0, W−1] × [0, H−1]` (integer pixel centres; there the
/// truncation `as usize` is the floor).
#[inline]
fn bilinear(img: &ArrayView2<f64>, u: f64, v: f64) -> f64 {
    let (h, w) = img.dim();
    let (x0, y0) = (u as usize, v as usize);
    let (x1, y1) = ((x0 + 1).min(w - 1), (y0 + 1).min(h - 1));
    let (fx, fy) = (u - x0 as f64, v - y0 as f64);
    let top = (1.0 - fx) * img[[y0, x0]] + fx * img[[y0, x1]];
    let bottom = (1.0 - fx) * img[[y1, x0]] + fx * img[[y1, x1]];
    (1.0 - fy) * top + fy * bottom
}

/// One frame's cost from the window sums: `1 − ZNCC`, or `+∞` when the keyframe window is too flat
/// or any warped sample is missing (a NaN sum).
#[inline]
fn zncc_cost(n: f64, sw: f64, sww: f64, swi: f64, si: f64, sii: f64, min_variance: f64) -> f64 {
    let (mw, mi) = (sw / n, si / n);
    let vi = sii / n - mi * mi;
    if vi.is_nan() || vi <= min_variance {
        return f64::INFINITY;
    }
    let vw = sww / n - mw * mw;
    let cov = swi / n - mw * mi;
    let c = 1.0 - cov / (vw.max(VARIANCE_FLOOR) * vi.max(VARIANCE_FLOOR)).sqrt();
    if c.is_finite() {
        c
    } else {
        f64::INFINITY
    }
}

/// The mean of the lowest `⌈fraction · n⌉` finite costs, or `+∞` with fewer than
/// `max(2, ⌊frames / 2⌋)` finite ones. `costs` is reordered: the finite ones first, ascending.
#[inline]
fn best_mean(costs: &mut [f64], frames: usize, fraction: f64) -> f64 {
    // An insertion sort of the finite costs (a handful): the same order as sorting them by
    // `f64::total_cmp`, as the sum's bits need, without the general sort's overhead.
    let mut n = 0;
    for i in 0..costs.len() {
        let c = costs[i];
        if !c.is_finite() {
            continue;
        }
        costs[i] = costs[n];
        let mut j = n;
        while j > 0 && costs[j - 1].total_cmp(&c).is_gt() {
            costs[j] = costs[j - 1];
            j -= 1;
        }
        costs[j] = c;
        n += 1;
    }
    if n < (frames / 2).max(2) {
        return f64::INFINITY;
    }
    let k = ((fraction * n as f64).ceil() as usize).clamp(1, n);
    let mut s = 0.0;
    for &c in &costs[..k] {
        s += c;
    }
    s / k as f64
}

/// The running minimum over the hypotheses of one pixel, with its neighbours' costs.
#[derive(Clone, Copy, Debug)]
struct Track {
    best: usize,
    cost: f64,
    before: f64,
    after: f64,
    last: f64,
}

impl Track {
    const START: Track =
        Track { best: usize::MAX, cost: f64::INFINITY, before: f64::NAN, after: f64::NAN, last: f64::NAN };

    #[inline]
    fn push(&mut self, a: usize, c: f64) {
        if a > 0 && self.best == a - 1 {
            self.after = c;
        }
        if c < self.cost {
            *self = Track { best: a, cost: c, before: self.last, after: f64::NAN, last: c };
        }
        self.last = c;
    }

    /// The refined inverse depth, or NaN where the minimum is at an end, a neighbour is unseen, or
    /// the parabola is too flat.
    #[inline]
    fn finish(&self, rho0: f64, step: f64, p: &RefineParams) -> f64 {
        if self.best == 0
            || self.best >= p.samples - 1
            || !(self.before.is_finite() && self.after.is_finite())
        {
            return f64::NAN;
        }
        let h = p.spacing();
        let den = self.before - 2.0 * self.cost + self.after;
        if den.is_nan() || den <= p.min_curvature * h * h {
            return f64::NAN;
        }
        let sub = (0.5 * (self.before - self.after) / den).clamp(-0.5, 0.5);
        rho0 + (p.offset(self.best) + sub * h) * step
    }
}

/// The level-0 problem: the keyframe's grey image and camera, the estimate at that resolution
/// (NaN: none), the live views and the bin step `Δρ`.
#[derive(Clone, Copy, Debug)]
pub struct Level0<'a, 'v> {
    /// `[H, W]` grey levels of the keyframe.
    pub key: ArrayView2<'a, f64>,
    /// The keyframe's camera at level 0.
    pub camera: &'a PinholeCamera,
    /// `[H, W]` inverse depth to refine, NaN where there is none.
    pub rho0: ArrayView2<'a, f64>,
    /// The live frames.
    pub views: &'a [RefineView<'v>],
    /// `Δρ`, 1/m.
    pub step: f64,
}

impl<'a, 'v> Level0<'a, 'v> {
    /// The problem itself once the parameters and the sizes are checked.
    fn checked(&self, p: &RefineParams) -> Result<Level0<'a, 'v>> {
        p.validate()?;
        let (key, camera, rho0) = (&self.key, self.camera, &self.rho0);
        if key.dim() != (camera.height, camera.width) || rho0.dim() != key.dim() {
            return Err(Error::invalid_argument(
                "refine",
                format!(
                    "keyframe image {:?}, inverse depth {:?} and camera {}x{} disagree",
                    key.dim(),
                    rho0.dim(),
                    camera.width,
                    camera.height
                ),
            ));
        }
        for (i, v) in self.views.iter().enumerate() {
            if v.grey.dim() != (v.camera.height, v.camera.width) {
                return Err(Error::invalid_argument(
                    "refine",
                    format!(
                        "live view {i}: image {:?} but camera {}x{}",
                        v.grey.dim(),
                        v.camera.width,
                        v.camera.height
                    ),
                ));
            }
        }
        Ok(*self)
    }
}

/// Fast path: the refined inverse depth of every level-0 pixel, NaN where it did not move
/// (SPEC.md §10.3). `rho0` is the estimate at the keyframe image's resolution (NaN: none); `step`
/// the bin step `Δρ`. Bit-identical to [`refine_level0_reference`] and for any thread count.
///
/// # Errors
/// [`Error::InvalidArgument`] for bad parameters or images whose sizes disagree with their cameras.
pub fn refine_level0(problem: &Level0, p: &RefineParams) -> Result<Array2<f64>> {
    let Level0 { key, camera, rho0, views, step } = problem.checked(p)?;
    let (h, w) = key.dim();
    let r = p.half_window;
    let n = ((2 * r + 1) * (2 * r + 1)) as f64;
    let mut out = Array2::from_elem((h, w), f64::NAN);
    if h <= 2 * r || w <= 2 * r || views.is_empty() {
        return Ok(out);
    }
    let key_sq = key.mapv(|v| v * v);
    let (si, sii) = (window_sums(key.view(), r), window_sums(key_sq.view(), r));
    // The keyframe rays K_r⁻¹ỹ by column and row, formed as `PinholeCamera::ray` forms them.
    let rays_x: Vec<f64> = (0..w).map(|x| camera.ray(x as f64, 0.0).x).collect();
    let rays_y: Vec<f64> = (0..h).map(|y| camera.ray(0.0, y as f64).y).collect();
    let warpers: Vec<Warper> = views.iter().map(Warper::new).collect();
    let frames = views.len();
    let mut tracks = Array2::from_elem((h, w), Track::START);
    // Per pixel the frames' costs of the current hypothesis, side by side.
    let mut costs = vec![0.0f64; h * w * frames];
    // Per row the horizontal window sums of g, g² and g·I (g the frame's warped grey value), one
    // after the other.
    let mut rows = Array2::<f64>::zeros((h, 3 * w));
    let span = r..w - r;
    for a in 0..p.samples {
        let offset = p.offset(a) * step;
        for (v, warper) in warpers.iter().enumerate() {
            // The frame's grey value at every pixel's own hypothesis, summed along the row...
            let scratch = || (vec![0.0; w], vec![0.0; w], vec![0.0; w]);
            par_rows_with(&mut rows, scratch, |(g, gg, gi), y, row| {
                for x in 0..w {
                    let r0 = rho0[[y, x]];
                    let value = if r0.is_finite() {
                        let ray = Vector3::new(rays_x[x], rays_y[y], 1.0);
                        warper.sample(&warper.bearing(&ray), r0 + offset)
                    } else {
                        f64::NAN
                    };
                    g[x] = value;
                    gg[x] = value * value;
                    gi[x] = value * key[[y, x]];
                }
                for (sums, terms) in row.chunks_exact_mut(w).zip([&*g, &*gg, &*gi]) {
                    window_sum_into(&mut sums[span.clone()], |d| &terms[d..], 2 * r + 1);
                }
            });
            // ... then over the window's rows, and the correlation.
            let all = rows.as_slice().expect("a freshly allocated array is contiguous");
            par_chunks_with(
                &mut costs,
                w * frames,
                || vec![0.0; 3 * w],
                |acc, y, out| {
                    let interior_row = y >= r && y + r < h;
                    if interior_row {
                        let first = (y - r) * 3 * w;
                        window_sum_into(acc, |d| &all[first + d * 3 * w..], 2 * r + 1);
                    }
                    for x in 0..w {
                        out[x * frames + v] = if interior_row && span.contains(&x) {
                            zncc_cost(
                                n,
                                acc[x],
                                acc[w + x],
                                acc[2 * w + x],
                                si[[y, x]],
                                sii[[y, x]],
                                p.min_variance,
                            )
                        } else {
                            f64::INFINITY
                        };
                    }
                },
            );
        }
        let costs = &costs;
        par_rows_with(
            &mut tracks,
            || vec![0.0; frames],
            |buf, y, row| {
                for (x, t) in row.iter_mut().enumerate() {
                    let at = (y * w + x) * frames;
                    buf.copy_from_slice(&costs[at..at + frames]);
                    t.push(a, best_mean(buf, frames, p.best_fraction));
                }
            },
        );
    }
    Zip::from(&mut out).and(&tracks).and(&rho0).for_each(|o, t, &r0| *o = t.finish(r0, step, p));
    Ok(out)
}

/// `out[i] = Σ_{d < taps} terms(d)[i]`, summed from `0.0` with `d` ascending, as the plain loop
/// does (so the same bits), eight outputs at a time in registers (which the compiler vectorises).
#[inline]
fn window_sum_into<'t>(out: &mut [f64], terms: impl Fn(usize) -> &'t [f64], taps: usize) {
    const LANES: usize = 8;
    let len = out.len();
    let full = len - len % LANES;
    for i in (0..full).step_by(LANES) {
        let mut acc = [0.0f64; LANES];
        for d in 0..taps {
            let t = &terms(d)[i..i + LANES];
            for (a, v) in acc.iter_mut().zip(t) {
                *a += v;
            }
        }
        out[i..i + LANES].copy_from_slice(&acc);
    }
    for (i, o) in out.iter_mut().enumerate().skip(full) {
        let mut acc = 0.0;
        for d in 0..taps {
            acc += terms(d)[i];
        }
        *o = acc;
    }
}

/// `f(scratch, i, chunk)` for the consecutive `len`-element chunks of `a`, in parallel, with a
/// scratch buffer from `init` per worker task rather than per chunk (each chunk's values depend on
/// that chunk's work alone and `f` overwrites what it reads of the scratch, so the result is the
/// same for any thread count).
fn par_chunks_with<T: Send, S>(
    a: &mut [T],
    len: usize,
    init: impl Fn() -> S + Sync + Send,
    f: impl Fn(&mut S, usize, &mut [T]) + Sync + Send,
) {
    a.par_chunks_mut(len.max(1)).enumerate().for_each_init(init, |s, (i, chunk)| f(s, i, chunk));
}

/// [`par_chunks_with`] over the rows of a standard-layout array.
fn par_rows_with<T: Send, S>(
    a: &mut Array2<T>,
    init: impl Fn() -> S + Sync + Send,
    f: impl Fn(&mut S, usize, &mut [T]) + Sync + Send,
) {
    let w = a.ncols();
    par_chunks_with(a.as_slice_mut().expect("a freshly allocated array is contiguous"), w, init, f);
}

/// `f(y, row)` for every row of a standard-layout array, rows in parallel.
fn par_rows<T: Send>(a: &mut Array2<T>, f: impl Fn(usize, &mut [T]) + Sync + Send) {
    par_rows_with(a, || (), |_, y, row| f(y, row));
}

/// Whether the window of `(y, x)` lies inside an `h x w` image.
#[inline]
fn interior(y: usize, x: usize, h: usize, w: usize, r: usize) -> bool {
    y >= r && x >= r && y + r < h && x + r < w
}

/// Window sums `Σ_dy (Σ_dx v[y+dy, x+dx])` for interior pixels (0 elsewhere), in that order.
fn window_sums(v: ArrayView2<f64>, r: usize) -> Array2<f64> {
    let (h, w) = v.dim();
    let v = v.as_standard_layout();
    let v = v.as_slice().expect("standard layout");
    let taps = 2 * r + 1;
    let mut rows = Array2::<f64>::zeros((h, w));
    par_rows(&mut rows, |y, row| {
        if w > 2 * r {
            let line = &v[y * w..(y + 1) * w];
            window_sum_into(&mut row[r..w - r], |d| &line[d..], taps);
        }
    });
    let mut out = Array2::<f64>::zeros((h, w));
    let all = rows.as_slice().expect("a freshly allocated array is contiguous");
    par_rows(&mut out, |y, row| {
        if y >= r && y + r < h && w > 2 * r {
            window_sum_into(&mut row[r..w - r], |d| &all[(y - r + d) * w + r..], taps);
        }
    });
    out
}

/// Plain-loop reference of [`refine_level0`] (SPEC.md §10.3): per pixel, per hypothesis, per frame,
/// the window's warps and sums directly.
///
/// # Errors
/// As [`refine_level0`].
pub fn refine_level0_reference(problem: &Level0, p: &RefineParams) -> Result<Array2<f64>> {
    let Level0 { key, camera, rho0, views, step } = problem.checked(p)?;
    let (h, w) = key.dim();
    let r = p.half_window as isize;
    let n = ((2 * r + 1) * (2 * r + 1)) as f64;
    let mut out = Array2::from_elem((h, w), f64::NAN);
    if views.is_empty() {
        return Ok(out);
    }
    let warpers: Vec<Warper> = views.iter().map(Warper::new).collect();
    for y in 0..h {
        for x in 0..w {
            if !interior(y, x, h, w, p.half_window) {
                continue;
            }
            let mut track = Track::START;
            for a in 0..p.samples {
                let offset = p.offset(a) * step;
                let mut per_frame = Vec::with_capacity(views.len());
                for warper in &warpers {
                    let (mut sw, mut sww, mut swi, mut si, mut sii) = (0.0, 0.0, 0.0, 0.0, 0.0);
                    for dy in -r..=r {
                        let (mut rw, mut rww, mut rwi, mut ri, mut rii) = (0.0, 0.0, 0.0, 0.0, 0.0);
                        for dx in -r..=r {
                            let (yy, xx) = ((y as isize + dy) as usize, (x as isize + dx) as usize);
                            let r0 = rho0[[yy, xx]];
                            let g = if r0.is_finite() {
                                let ray = camera.ray(xx as f64, yy as f64);
                                warper.sample(&warper.bearing(&ray), r0 + offset)
                            } else {
                                f64::NAN
                            };
                            let k = key[[yy, xx]];
                            rw += g;
                            rww += g * g;
                            rwi += g * k;
                            ri += k;
                            rii += k * k;
                        }
                        sw += rw;
                        sww += rww;
                        swi += rwi;
                        si += ri;
                        sii += rii;
                    }
                    per_frame.push(zncc_cost(n, sw, sww, swi, si, sii, p.min_variance));
                }
                track.push(a, best_mean(&mut per_frame, views.len(), p.best_fraction));
            }
            out[[y, x]] = track.finish(rho0[[y, x]], step, p);
        }
    }
    Ok(out)
}

/// The level-0 inverse depth of a level-`level` estimate: level-0 pixel `x` sits at level-`L`
/// coordinate `x / 2^L` (SPEC.md §2.6); bilinear between the four neighbours, clamped to the grid,
/// NaN unless all four have an estimate (`valid`).
pub fn upsample(
    rho: ArrayView2<f32>,
    valid: ArrayView2<bool>,
    level: u32,
    h0: usize,
    w0: usize,
) -> Array2<f64> {
    let (h, w) = rho.dim();
    let s = f64::from(1u32 << level);
    Array2::from_shape_fn((h0, w0), |(y, x)| {
        let (u, v) = ((x as f64 / s).min((w - 1) as f64), (y as f64 / s).min((h - 1) as f64));
        let (x0, y0) = (u.floor() as usize, v.floor() as usize);
        let (x1, y1) = ((x0 + 1).min(w - 1), (y0 + 1).min(h - 1));
        if !(valid[[y0, x0]] && valid[[y0, x1]] && valid[[y1, x0]] && valid[[y1, x1]]) {
            return f64::NAN;
        }
        let (fx, fy) = (u - x0 as f64, v - y0 as f64);
        let g = |yy: usize, xx: usize| f64::from(rho[[yy, xx]]);
        (1.0 - fy) * ((1.0 - fx) * g(y0, x0) + fx * g(y0, x1))
            + fy * ((1.0 - fx) * g(y1, x0) + fx * g(y1, x1))
    })
}

/// A refined level-`level` estimate: `(inverse depth, depth, report)`. Each level-`L` pixel with an
/// estimate moves by `Σ w δ / Σ w` over the level-0 pixels of its tent `w = (1 − |x/2^L − i|)⁺
/// (1 − |y/2^L − j|)⁺` (the adjoint of [`upsample`]), `δ` the level-0 move (0 where a pixel did not
/// move); it keeps its value when none moved or the result is not positive.
///
/// # Errors
/// As [`refine_level0`]; [`Error::InvalidArgument`] when the maps do not match the keyframe camera at
/// `level`.
#[allow(clippy::too_many_arguments)]
pub fn refine_estimate(
    inverse_depth: ArrayView2<f32>,
    depth: ArrayView2<f32>,
    level: u32,
    key: ArrayView2<f64>,
    camera: &PinholeCamera,
    views: &[RefineView],
    bins: &InverseDepthBins,
    p: &RefineParams,
) -> Result<(Array2<f32>, Array2<f32>, RefineReport)> {
    let at = camera.at_level(level);
    if inverse_depth.dim() != (at.height, at.width) || depth.dim() != inverse_depth.dim() {
        return Err(Error::invalid_argument(
            "refine",
            format!(
                "the estimate is {:?}, the keyframe camera at level {level} {}x{}",
                inverse_depth.dim(),
                at.width,
                at.height
            ),
        ));
    }
    let valid = Zip::from(&inverse_depth)
        .and(&depth)
        .map_collect(|&r, &d| r.is_finite() && r > 0.0 && d.is_finite() && d > 0.0);
    let (h0, w0) = (camera.height, camera.width);
    let rho0 = upsample(inverse_depth, valid.view(), level, h0, w0);
    let step = (bins.rho_max - bins.rho_min) / (REFERENCE_BINS - 1) as f64;
    let refined = refine_level0(&Level0 { key, camera, rho0: rho0.view(), views, step }, p)?;
    let r = p.half_window;
    let report = RefineReport {
        frames: views.len(),
        candidates: Zip::indexed(&rho0)
            .fold(0, |n, (y, x), v| n + usize::from(v.is_finite() && interior(y, x, h0, w0, r))),
        refined: refined.iter().filter(|v| v.is_finite()).count(),
    };
    let s = 1usize << level;
    let mut inv = inverse_depth.to_owned();
    let mut dep = depth.to_owned();
    Zip::indexed(&mut inv).and(&mut dep).for_each(|(j, i), rho, d| {
        if !valid[[j, i]] {
            return;
        }
        let (mut num, mut den, mut moved) = (0.0, 0.0, false);
        for y in (j * s).saturating_sub(s - 1)..(j * s + s).min(h0) {
            let wy = 1.0 - (y as f64 / s as f64 - j as f64).abs();
            for x in (i * s).saturating_sub(s - 1)..(i * s + s).min(w0) {
                let wt = wy * (1.0 - (x as f64 / s as f64 - i as f64).abs());
                if wt <= 0.0 {
                    continue;
                }
                den += wt;
                let v = refined[[y, x]];
                if v.is_finite() {
                    num += wt * (v - rho0[[y, x]]);
                    moved = true;
                }
            }
        }
        if !moved {
            return;
        }
        let new = f64::from(*rho) + num / den;
        if new > 0.0 && new.is_finite() {
            *rho = new as f32;
            *d = 1.0 / *rho;
        }
    });
    Ok((inv, dep, report))
}
