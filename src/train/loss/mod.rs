//! The paper's multi-view cost-volume loss at one scale (§3.2, SPEC.md §13.1).
//!
//! For every reference pixel `u` with valid ground-truth depth `z*` (`ρ* = 1/z*`):
//!
//! ```text
//! E_l  = ‖f_ref(u) − f_live(u'_l)‖²       u'_l = π(T_lr π⁻¹(u, ρ_l)), bilinear; m if u'_l is outside
//! P_l  = exp(−E_l) / Σ_k exp(−E_k)          (softmax over the K hypotheses)
//! CE   = −ln P_{l*} − Σ_{l≠l*} ln max(1 − P_l, ε)     (binary cross-entropy, one-hot target l*)
//! ρ̂    = Σ_l P_l ρ_l,  d̂ = 1 / max(ρ̂, ρ_floor)
//! loss = CE + λ_ρ (ρ̂ − ρ*)² + λ_d (d̂ − z*)²
//! ```
//!
//! `l*` is the bin nearest to `ρ*`. A pixel is masked out (no loss, no gradient) when `z*` is
//! invalid, `ρ*` lies outside `[ρ_min, ρ_max]`, or its true match `u'(ρ*)` is behind the live camera
//! or outside the live image. The scale's loss is the **mean** over unmasked pixels.
//!
//! [`scale_loss_reference`] is the f64 oracle (plain loops); [`scale_loss`] the fast f32 version
//! (samples and costs in f32, the per-pixel softmax and regression in f64, the same
//! [`pixel_terms`]). Both return the gradients with respect to both feature maps.

mod exp;
mod fast;
mod kernel;
mod reference;
mod taps;

pub use fast::{scale_loss, scale_loss_multi, scale_loss_multi_with, scale_loss_with};
pub use kernel::{loss_kernels, uses_avx512, LossKernels};

pub use reference::{scale_loss_multi_reference, scale_loss_reference};

use ndarray::{Array3, ArrayView2, ArrayView3};

use crate::costvolume::evidence_threshold;
use crate::error::{Error, Result};
use crate::geometry::{InverseDepthBins, Warp};
use crate::image::is_valid_depth;
use crate::image::sample::axis;
use crate::runtime::CpuFeatureLevel;

/// Hyper-parameters of the loss (SPEC.md §13.1); `Default` is the paper's.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LossConfig {
    /// Inverse-depth hypotheses (the paper: 256 over `[0, 4]` 1/m).
    pub bins: InverseDepthBins,
    /// Cost `m` of a hypothesis whose sample falls outside the live image (the paper: 10).
    pub outside_cost: f64,
    /// Weight of `(ρ̂ − ρ*)²` (the paper: 5).
    pub lambda_rho: f64,
    /// Weight of `(1/ρ̂ − 1/ρ*)²` (the paper: 1).
    pub lambda_d: f64,
    /// `d̂ = 1 / max(ρ̂, rho_floor)`: bounds the depth term where `ρ̂` nears 0 (0.1 1/m = 10 m).
    pub rho_floor: f64,
    /// `ln(1 − P_l)` is taken of `max(1 − P_l, prob_floor)` (1e-6); no gradient where it clamps.
    pub prob_floor: f64,
    /// Pixel sampling (SPEC.md §13.1a): `1` evaluates every pixel (the paper); `s > 1` evaluates
    /// one pixel per `s x s` block, at an offset drawn from `sample_seed`, and weights it `s²`,
    /// an unbiased estimate of the scale's loss and gradients.
    pub sample_stride: usize,
    /// Seed of the sampled offsets (unused when `sample_stride = 1`).
    pub sample_seed: u64,
    /// How the multi-frame loss treats a hypothesis that leaves some live frames (SPEC.md §13.1d).
    pub multi_cost: MultiCost,
    /// Weight `w_h` of the ranking term (SPEC.md §13.1e): `w_h max(0, μ + E_{l*} − min E_l)`, the
    /// minimum over the bins more than [`HINGE_RADIUS`] from the target. 0 (the default): off, the
    /// paper's loss.
    pub hinge_weight: f64,
    /// The ranking term's margin `μ` (in the cost's units, nats of the softmax).
    pub hinge_margin: f64,
}

/// Bins on either side of the target that the ranking term (SPEC.md §13.1e) leaves out: a winner
/// this near the truth is not a wrong answer.
pub const HINGE_RADIUS: usize = 2;

/// How the multi-frame loss (SPEC.md §13.1b) combines live frames that do not all see a hypothesis
/// (`--multi-cost`; SPEC.md §13.1d).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum MultiCost {
    /// §13.1b: every live frame counts, `m` where a hypothesis falls outside it, and a pixel is
    /// used only when its true match lies inside every live frame.
    #[default]
    All,
    /// The mapper's rule (SPEC.md §9.10): per hypothesis the mean over the live frames that see
    /// it; a hypothesis seen by fewer than `max(1, ⌈0.25 · c_max⌉)` frames (`c_max` the pixel's
    /// best-seen hypothesis's count) costs `m`; a pixel is used when its true bin passes that
    /// minimum, whether or not every frame sees it.
    Seen,
}

impl std::str::FromStr for MultiCost {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        match s {
            "all" => Ok(MultiCost::All),
            "seen" => Ok(MultiCost::Seen),
            _ => Err(Error::invalid_argument("--multi-cost", format!("{s:?}: expected all or seen"))),
        }
    }
}

/// The evidence fraction of [`MultiCost::Seen`]: the mapper's default `--min-evidence` (§9.10).
pub const SEEN_MIN_EVIDENCE: f64 = 0.25;

/// Under [`MultiCost::Seen`], the least number of live frames a hypothesis must be seen by to
/// compete, given the most any hypothesis of the pixel is seen by: the mapper's
/// [`evidence_threshold`] (`max(1, ⌈0.25 c_max⌉)`, §9.10).
pub fn seen_threshold(c_max: usize) -> usize {
    usize::from(evidence_threshold(u16::try_from(c_max).unwrap_or(u16::MAX), SEEN_MIN_EVIDENCE))
}

impl Default for LossConfig {
    fn default() -> Self {
        LossConfig {
            bins: InverseDepthBins::paper(),
            outside_cost: 10.0,
            lambda_rho: 5.0,
            lambda_d: 1.0,
            rho_floor: 0.1,
            prob_floor: 1e-6,
            sample_stride: 1,
            sample_seed: 0,
            multi_cost: MultiCost::All,
            hinge_weight: 0.0,
            hinge_margin: 1.0,
        }
    }
}

impl LossConfig {
    /// This configuration with the regression term (SPEC.md §13.1 step 5) scaled by `w` against the
    /// paper's weights: `λ_ρ = 5 w`, `λ_d = w` (`--regression-weight`). `w = 1` is the paper's loss
    /// (the same fields, so the same fingerprint); `w = 0` trains with the cross-entropy alone.
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] naming `--regression-weight` unless `w` is finite and `>= 0`.
    pub fn with_regression_weight(self, w: f64) -> Result<Self> {
        if !(w.is_finite() && w >= 0.0) {
            return Err(Error::invalid_argument(
                "--regression-weight",
                format!("{w}: must be a finite number >= 0 (1: the paper's loss, 0: cross-entropy alone)"),
            ));
        }
        let paper = LossConfig::default();
        Ok(LossConfig { lambda_rho: paper.lambda_rho * w, lambda_d: paper.lambda_d * w, ..self })
    }

    /// This configuration with the ranking term of SPEC.md §13.1e at weight `w` and margin `margin`
    /// (`--hinge-weight`, `--hinge-margin`); `w = 0` is the paper's loss (the same fields as the
    /// default when the margin is the default's, so the same fingerprint).
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] naming `--hinge-weight` unless `w` is finite and `>= 0`, or
    /// `--hinge-margin` unless `margin` is finite and `>= 0`.
    pub fn with_hinge(self, w: f64, margin: f64) -> Result<Self> {
        if !(w.is_finite() && w >= 0.0) {
            return Err(Error::invalid_argument(
                "--hinge-weight",
                format!("{w}: must be a finite number >= 0 (0: off, the paper's loss)"),
            ));
        }
        if !(margin.is_finite() && margin >= 0.0) {
            return Err(Error::invalid_argument(
                "--hinge-margin",
                format!("{margin}: must be a finite number >= 0"),
            ));
        }
        Ok(LossConfig { hinge_weight: w, hinge_margin: margin, ..self })
    }

    /// Checks that every field is finite and in range.
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] naming the field.
    pub fn validate(&self) -> Result<()> {
        let bad = |name: &str, v: f64| Error::invalid_argument(name, format!("{v} is out of range"));
        if !(self.outside_cost.is_finite() && self.outside_cost >= 0.0) {
            return Err(bad("outside_cost", self.outside_cost));
        }
        if !(self.lambda_rho.is_finite() && self.lambda_rho >= 0.0) {
            return Err(bad("lambda_rho", self.lambda_rho));
        }
        if !(self.lambda_d.is_finite() && self.lambda_d >= 0.0) {
            return Err(bad("lambda_d", self.lambda_d));
        }
        if !(self.rho_floor.is_finite() && self.rho_floor > 0.0) {
            return Err(bad("rho_floor", self.rho_floor));
        }
        if !(self.prob_floor > 0.0 && self.prob_floor < 1.0) {
            return Err(bad("prob_floor", self.prob_floor));
        }
        if !(1..=64).contains(&self.sample_stride) {
            return Err(bad("sample_stride", self.sample_stride as f64));
        }
        if !(self.hinge_weight.is_finite() && self.hinge_weight >= 0.0) {
            return Err(bad("hinge_weight", self.hinge_weight));
        }
        if !(self.hinge_margin.is_finite() && self.hinge_margin >= 0.0) {
            return Err(bad("hinge_margin", self.hinge_margin));
        }
        Ok(())
    }
}

/// Sums over the unmasked pixels of one scale (divide by `pixels` for means).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct LossSums {
    /// Unmasked pixels.
    pub pixels: usize,
    /// Σ cross-entropy.
    pub ce: f64,
    /// Σ `λ_ρ (ρ̂ − ρ*)²`.
    pub rho: f64,
    /// Σ `λ_d (d̂ − z*)²`.
    pub depth: f64,
    /// Σ ranking term (SPEC.md §13.1e; 0 when it is off).
    pub hinge: f64,
    /// Pixels whose expected depth `d̂` is within a factor 1.25 of `z*`.
    pub delta125_expected: usize,
    /// Pixels whose winner-take-all depth (`1/ρ` of the lowest-cost bin) is within 1.25 of `z*`.
    pub delta125_wta: usize,
}

impl LossSums {
    /// The scale's loss: `(ce + rho + depth + hinge) / pixels` (0 with no pixels; the hinge sum
    /// is added only when it is not 0, so the paper's loss keeps its bits).
    pub fn mean(&self) -> f64 {
        if self.pixels == 0 {
            0.0
        } else if self.hinge == 0.0 {
            (self.ce + self.rho + self.depth) / self.pixels as f64
        } else {
            (self.ce + self.rho + self.depth + self.hinge) / self.pixels as f64
        }
    }

    /// Adds one evaluated pixel's terms (`ρ*` its ground truth) with weight `m` (`s²` under
    /// sampling, else 1): sums and δ counts grow by `m` times the pixel's, `pixels` by `m` (the
    /// caller sets `pixels` to the exact unmasked count afterwards).
    pub(crate) fn add_pixel(&mut self, cfg: &LossConfig, terms: &PixelTerms, rho_star: f64, m: usize) {
        let z_star = 1.0 / rho_star;
        let mf = m as f64;
        self.pixels += m;
        self.ce += mf * terms.ce;
        self.rho += mf * terms.rho;
        self.depth += mf * terms.depth;
        self.hinge += mf * terms.hinge;
        self.delta125_expected += m * usize::from(within_125(1.0 / terms.rho_hat.max(cfg.rho_floor), z_star));
        self.delta125_wta += m * usize::from(within_125(1.0 / cfg.bins.rho(terms.wta), z_star));
    }

    /// Adds another scale's or pair's sums.
    pub fn accumulate(&mut self, o: &LossSums) {
        self.pixels += o.pixels;
        self.ce += o.ce;
        self.rho += o.rho;
        self.depth += o.depth;
        self.hinge += o.hinge;
        self.delta125_expected += o.delta125_expected;
        self.delta125_wta += o.delta125_wta;
    }
}

/// The loss of one scale and its gradients (already divided by the pixel count).
#[derive(Clone, Debug)]
pub struct ScaleLoss<T> {
    /// Sums over unmasked pixels.
    pub sums: LossSums,
    /// `d mean / d f_ref`, `[H, W, C]`.
    pub d_ref: Array3<T>,
    /// `d mean / d f_live`, `[H', W', C]`.
    pub d_live: Array3<T>,
}

/// One live frame of a multi-frame scale loss (SPEC.md §13.1b): its features `[H', W', C]` and
/// the warp from the reference camera to its camera.
#[derive(Clone, Copy, Debug)]
pub struct LiveView<'a, T> {
    /// Live features.
    pub features: ArrayView3<'a, T>,
    /// Reference camera to this live camera.
    pub warp: &'a Warp,
}

/// The multi-frame loss of one scale and its gradients (already divided by the pixel count).
#[derive(Clone, Debug)]
pub struct MultiScaleLoss<T> {
    /// Sums over unmasked pixels.
    pub sums: LossSums,
    /// `d mean / d f_ref`, `[H, W, C]`.
    pub d_ref: Array3<T>,
    /// `d mean / d f_live_n`, one per live frame, in order.
    pub d_lives: Vec<Array3<T>>,
}

/// At least one live frame.
pub(crate) fn check_lives(n: usize) -> Result<()> {
    if n == 0 {
        return Err(Error::invalid_argument("loss inputs", "no live frame"));
    }
    Ok(())
}

/// The target of reference pixel `(x, y)` over several live frames: [`pixel_target`] of the
/// first, and `None` unless the true match is inside every live frame (SPEC.md §13.1b).
pub(crate) fn multi_target<T>(
    cfg: &LossConfig,
    lives: &[LiveView<'_, T>],
    x: usize,
    y: usize,
    z: f32,
) -> Option<(f64, usize)> {
    let first = pixel_target(cfg, lives.first()?.warp, x, y, z)?;
    lives[1..].iter().all(|l| pixel_target(cfg, l.warp, x, y, z).is_some()).then_some(first)
}

/// Under [`MultiCost::Seen`]: `(ρ*, l*)` of reference pixel `(x, y)` when [`pixel_target`] holds
/// in some live frame (the true match inside at least one; `(ρ*, l*)` does not depend on the
/// frame). The caller then requires the true bin to compete (SPEC.md §13.1d).
pub(crate) fn any_target<T>(
    cfg: &LossConfig,
    lives: &[LiveView<'_, T>],
    x: usize,
    y: usize,
    z: f32,
) -> Option<(f64, usize)> {
    lives.iter().find_map(|l| pixel_target(cfg, l.warp, x, y, z))
}

/// Under [`MultiCost::Seen`], turns per-bin sums of the seeing frames' costs and their counts into
/// the pixel's costs: `sum / count` where the bin competes (at least [`seen_threshold`] of the
/// largest count), else `m`. Returns that least count.
pub(crate) fn seen_energies(cfg: &LossConfig, energies: &mut [f64], counts: &[u32]) -> u32 {
    let need = seen_need(counts);
    for (e, &n) in energies.iter_mut().zip(counts) {
        *e = if n >= need { *e / f64::from(n) } else { cfg.outside_cost };
    }
    need
}

/// [`seen_threshold`] of the largest of `counts`.
pub(crate) fn seen_need(counts: &[u32]) -> u32 {
    seen_threshold(counts.iter().copied().max().unwrap_or(0) as usize) as u32
}

/// What one unmasked pixel contributes, given its costs.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PixelTerms {
    /// Cross-entropy.
    pub ce: f64,
    /// `λ_ρ (ρ̂ − ρ*)²`.
    pub rho: f64,
    /// `λ_d (d̂ − z*)²`.
    pub depth: f64,
    /// The ranking term `w_h max(0, μ + E_{l*} − min_{|l − l*| > r} E_l)` (SPEC.md §13.1e).
    pub hinge: f64,
    /// `ρ̂`.
    pub rho_hat: f64,
    /// The lowest-cost bin (the first on ties).
    pub wta: usize,
}

/// The per-pixel part of the loss, in f64 (shared by both implementations): from the costs
/// `energies[l]` (already `m` outside the image), the target bin and `ρ*`, the terms and
/// `grad[l] = d(CE + λ_ρ(ρ̂−ρ*)² + λ_d(d̂−z*)²) / dE_l` (SPEC.md §13.1). Allocates its scratch;
/// [`pixel_terms_with`] takes it from the caller.
pub fn pixel_terms(
    cfg: &LossConfig,
    energies: &[f64],
    target: usize,
    rho_star: f64,
    grad: &mut [f64],
) -> PixelTerms {
    let mut scratch = PixelScratch::default();
    pixel_terms_with(cfg, energies, target, rho_star, grad, &mut scratch, CpuFeatureLevel::get())
}

/// Per-bin buffers of [`pixel_terms_with`], reused across pixels.
#[derive(Clone, Debug, Default)]
pub struct PixelScratch {
    /// `ρ_l`.
    rho: Vec<f64>,
    /// `1 / (1 − P_l)` where the term is unclamped and `l ≠ l*`, else 0.
    inv_q: Vec<f64>,
}

/// [`pixel_terms`] with caller-provided scratch. The passes over the bins are elementwise (the
/// shifted exponentials, their normalisation, `1 / (1 − P_l)`, the final gradient) or sums taken
/// in 8 lanes (`lane = l mod 8`, bins in order within a lane, then a fixed tree), so every pass
/// vectorises; compiled for AVX-512 where the CPU has it, with the same bits either way (IEEE
/// operations only, no fused multiply-add), at the CPU-feature level `level`. Both loss
/// implementations call this one function.
pub fn pixel_terms_with(
    cfg: &LossConfig,
    energies: &[f64],
    target: usize,
    rho_star: f64,
    grad: &mut [f64],
    scratch: &mut PixelScratch,
    level: CpuFeatureLevel,
) -> PixelTerms {
    let k = energies.len();
    let bins = &cfg.bins;
    if scratch.rho.len() != k || scratch.rho.last() != Some(&bins.rho(k - 1)) || scratch.rho[0] != bins.rho(0)
    {
        scratch.rho = (0..k).map(|l| bins.rho(l)).collect();
    }
    scratch.inv_q.resize(k, 0.0);
    let (rho, inv_q) = (&scratch.rho[..k], &mut scratch.inv_q[..k]);
    let grad = &mut grad[..k];
    #[cfg(target_arch = "x86_64")]
    if level.avx512f() {
        // SAFETY: the CPU has AVX-512F (`CpuFeatureLevel::avx512f` checks it).
        return unsafe { pixel_terms_avx512(cfg, energies, target, rho_star, grad, rho, inv_q, level) };
    }
    #[cfg(target_arch = "x86_64")]
    if level.avx2_fma() {
        // SAFETY: the CPU has AVX2 and FMA (`CpuFeatureLevel::avx2_fma` checks it).
        return unsafe { pixel_terms_avx2(cfg, energies, target, rho_star, grad, rho, inv_q, level) };
    }
    pixel_terms_body(cfg, energies, target, rho_star, grad, rho, inv_q, level)
}

/// Lanes of the per-pixel sums.
const SUM_LANES: usize = 8;

/// `Σ_l f(x_l, y_l)` in [`SUM_LANES`] lanes (bins in order within a lane), then
/// [`kernel::lane_tree`].
#[inline(always)]
fn lane_sum(x: &[f64], y: &[f64], f: impl Fn(f64, f64) -> f64) -> f64 {
    let mut acc = [0.0f64; SUM_LANES];
    let (xc, yc) = (x.chunks_exact(SUM_LANES), y.chunks_exact(SUM_LANES));
    let (xr, yr) = (xc.remainder(), yc.remainder());
    for (a, b) in xc.zip(yc) {
        for i in 0..SUM_LANES {
            acc[i] += f(a[i], b[i]);
        }
    }
    for i in 0..xr.len() {
        acc[i] += f(xr[i], yr[i]);
    }
    kernel::lane_tree(acc)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
#[allow(clippy::too_many_arguments)]
unsafe fn pixel_terms_avx512(
    cfg: &LossConfig,
    energies: &[f64],
    target: usize,
    rho_star: f64,
    grad: &mut [f64],
    rho: &[f64],
    inv_q: &mut [f64],
    level: CpuFeatureLevel,
) -> PixelTerms {
    pixel_terms_body(cfg, energies, target, rho_star, grad, rho, inv_q, level)
}

/// [`pixel_terms_body`] compiled for AVX2 (the compiler's vectorisation; Rust never fuses a
/// product and a sum unless asked, so the bits are the portable build's).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
#[allow(clippy::too_many_arguments)]
unsafe fn pixel_terms_avx2(
    cfg: &LossConfig,
    energies: &[f64],
    target: usize,
    rho_star: f64,
    grad: &mut [f64],
    rho: &[f64],
    inv_q: &mut [f64],
    level: CpuFeatureLevel,
) -> PixelTerms {
    pixel_terms_body(cfg, energies, target, rho_star, grad, rho, inv_q, level)
}

#[inline(always)]
#[allow(clippy::needless_range_loop)] // bins index several parallel arrays
#[allow(clippy::too_many_arguments)]
fn pixel_terms_body(
    cfg: &LossConfig,
    energies: &[f64],
    target: usize,
    rho_star: f64,
    grad: &mut [f64],
    rho: &[f64],
    inv_q: &mut [f64],
    level: CpuFeatureLevel,
) -> PixelTerms {
    let k = energies.len();
    // Softmax of s = −E, shifted by the smallest cost (a minimum is exact in any order; NaNs are
    // passed over); the winner is the first bin holding it.
    let mut mins = [f64::INFINITY; SUM_LANES];
    for ch in energies.chunks(SUM_LANES) {
        for (m, &e) in mins.iter_mut().zip(ch) {
            if e < *m {
                *m = e;
            }
        }
    }
    let e_min = mins.iter().fold(f64::INFINITY, |a, &b| if b < a { b } else { a });
    let wta = energies.iter().position(|&e| e == e_min).unwrap_or(0);
    // exp(E_min − E_l), elementwise (exp.rs), then their sum.
    exp::exp_shifted(energies, e_min, grad, level);
    let sum = lane_sum(grad, grad, |g, _| g);
    // grad holds P for now.
    for g in grad.iter_mut() {
        *g /= sum;
    }
    let log_p_target = (e_min - energies[target]) - sum.ln();
    let mut ce = -log_p_target;
    // dCE/dP_l for l != l*: 1/q_l where q_l = 1 - P_l is above the floor, else 0.
    for l in 0..k {
        let q = 1.0 - grad[l];
        inv_q[l] = if l != target && q > cfg.prob_floor { 1.0 / q } else { 0.0 };
    }
    // Σ ln q_l over the unclamped bins: per block of 8 · ln_run bins, the product of each lane's
    // factors (at most ln_run, each > prob_floor, so a product stays above e^-700, far from f64's
    // smallest normal), then one ln per lane in lane order.
    let ln_run = (-700.0 / cfg.prob_floor.ln()).floor().clamp(1.0, 32.0) as usize;
    let mut unclamped = 0usize;
    for (gb, qb) in grad.chunks(SUM_LANES * ln_run).zip(inv_q.chunks(SUM_LANES * ln_run)) {
        let mut prod = [1.0f64; SUM_LANES];
        for (gc, qc) in gb.chunks(SUM_LANES).zip(qb.chunks(SUM_LANES)) {
            for i in 0..gc.len() {
                let used = qc[i] != 0.0;
                prod[i] *= if used { 1.0 - gc[i] } else { 1.0 };
                unclamped += usize::from(used);
            }
        }
        for p in prod {
            ce -= p.ln();
        }
    }
    let clamped = k - 1 - unclamped;
    ce -= clamped as f64 * cfg.prob_floor.ln();
    // dCE/ds_j = P_j (g_j − Σ_l g_l P_l), with g_{l*} P_{l*} = −1.
    let gp_sum = -1.0 + lane_sum(grad, inv_q, |p, iq| p * iq);
    let rho_hat = lane_sum(grad, rho, |p, r| p * r);
    let z_star = 1.0 / rho_star;
    let d_hat = 1.0 / rho_hat.max(cfg.rho_floor);
    let rho_term = cfg.lambda_rho * (rho_hat - rho_star) * (rho_hat - rho_star);
    let depth_term = cfg.lambda_d * (d_hat - z_star) * (d_hat - z_star);
    // dLoss/dρ̂.
    let mut dl_drho = 2.0 * cfg.lambda_rho * (rho_hat - rho_star);
    if rho_hat > cfg.rho_floor {
        dl_drho += 2.0 * cfg.lambda_d * (d_hat - z_star) * (-1.0 / (rho_hat * rho_hat));
    }
    // g_l P_l: P_l / q_l (0 where clamped), and exactly −1 at the target even when P underflows.
    let p_target = grad[target];
    for l in 0..k {
        let p = grad[l];
        let gp = p * inv_q[l];
        let ds_ce = gp - p * gp_sum;
        let ds_rho = p * (rho[l] - rho_hat) * dl_drho;
        // E = −s.
        grad[l] = -(ds_ce + ds_rho);
    }
    grad[target] = -((-1.0 - p_target * gp_sum) + p_target * (rho[target] - rho_hat) * dl_drho);
    let hinge = if cfg.hinge_weight > 0.0 { hinge_term(cfg, energies, target, grad) } else { 0.0 };
    PixelTerms { ce, rho: rho_term, depth: depth_term, hinge, rho_hat, wta }
}

/// The ranking term of SPEC.md §13.1e: with `j` the first bin of lowest cost among those more
/// than [`HINGE_RADIUS`] from `target` (none: no term), `h = μ + E_{l*} − E_j`; where `h > 0`
/// the term is `w_h h` and `grad` gains `w_h` at the target and `−w_h` at `j`.
fn hinge_term(cfg: &LossConfig, energies: &[f64], target: usize, grad: &mut [f64]) -> f64 {
    let far = |l: &usize| l.abs_diff(target) > HINGE_RADIUS;
    let mut best: Option<usize> = None;
    for l in (0..energies.len()).filter(far) {
        if best.is_none_or(|b| energies[l] < energies[b]) {
            best = Some(l);
        }
    }
    let Some(j) = best else { return 0.0 };
    let h = cfg.hinge_margin + energies[target] - energies[j];
    if h > 0.0 {
        grad[target] += cfg.hinge_weight;
        grad[j] -= cfg.hinge_weight;
        cfg.hinge_weight * h
    } else {
        0.0
    }
}

/// Whether pixel `(x, y)` is evaluated under `cfg`'s sampling (SPEC.md §13.1a): always for
/// `sample_stride = 1`; else exactly one pixel of each `s x s` block (blocks at multiples of `s`),
/// at offset `hash64(sample_seed, bx, by, 0) mod s²` (row-major inside the block). Every pixel
/// is evaluated with probability exactly `1/s²` over the seed, including those of partial blocks
/// at the right and bottom edges (their missing offsets evaluate nothing).
pub fn pixel_sampled(cfg: &LossConfig, x: usize, y: usize) -> bool {
    let s = cfg.sample_stride;
    if s <= 1 {
        return true;
    }
    let offset =
        crate::util::rng::hash64(cfg.sample_seed, (x / s) as u64, (y / s) as u64, 0) % (s * s) as u64;
    offset == ((y % s) * s + x % s) as u64
}

/// The target of reference pixel `(x, y)` at ground-truth depth `z`: `(ρ*, l*)`, or `None` when
/// the pixel is masked (SPEC.md §13.1).
pub fn pixel_target(cfg: &LossConfig, warp: &Warp, x: usize, y: usize, z: f32) -> Option<(f64, usize)> {
    if !is_valid_depth(z) {
        return None;
    }
    let rho_star = 1.0 / f64::from(z);
    let bins = &cfg.bins;
    if !(rho_star >= bins.rho_min && rho_star <= bins.rho_max) {
        return None;
    }
    let m = warp.apply(x as f64, y as f64, rho_star)?;
    if !warp.target().contains(m.uv.x, m.uv.y) {
        return None;
    }
    let target = ((rho_star - bins.rho_min) / bins.step()).round() as usize;
    Some((rho_star, target.min(bins.count - 1)))
}

/// Validates the shapes of one scale's inputs against the warp's cameras.
pub(crate) fn check_inputs(
    warp: &Warp,
    ref_shape: &[usize],
    live_shape: &[usize],
    depth: &ArrayView2<f32>,
) -> Result<()> {
    let (r, l) = (warp.reference(), warp.target());
    let want_ref = [r.height, r.width];
    if ref_shape[..2] != want_ref || depth.shape() != want_ref {
        return Err(Error::invalid_argument(
            "loss inputs",
            format!(
                "reference features {:?} and depth {:?} must be {want_ref:?} (the reference camera)",
                ref_shape,
                depth.shape()
            ),
        ));
    }
    if live_shape[..2] != [l.height, l.width] || live_shape[2] != ref_shape[2] {
        return Err(Error::invalid_argument(
            "loss inputs",
            format!("live features {live_shape:?} must be [{}, {}, {}]", l.height, l.width, ref_shape[2]),
        ));
    }
    Ok(())
}

/// Corner indices and weights of a bilinear sample at `(x, y)` in a `w x h` map (SPEC.md §2.1):
/// `[(y0, x0), (y0, x1), (y1, x0), (y1, x1)]` and their f64 weights; `None` outside.
#[inline]
pub(crate) fn bilinear_taps(x: f64, y: f64, w: usize, h: usize) -> Option<([usize; 4], [f64; 4])> {
    let (x0, x1, a) = axis(x, w)?;
    let (y0, y1, b) = axis(y, h)?;
    Some((
        [y0 * w + x0, y0 * w + x1, y1 * w + x0, y1 * w + x1],
        [(1.0 - a) * (1.0 - b), a * (1.0 - b), (1.0 - a) * b, a * b],
    ))
}

/// The sample position of hypothesis `rho` for the warp's point `p0 = R K⁻¹ u̇` (hoisted): `None`
/// behind the live camera. The same arithmetic as [`Warp::apply`].
#[inline]
pub(crate) fn hypothesis_position(warp: &Warp, p0: &[f64; 3], rho: f64) -> Option<(f64, f64)> {
    let t = warp.translation();
    let warp_t = [t.x, t.y, t.z];
    let c = warp.target();
    let (fx, fy, cx, cy) = (c.fx, c.fy, c.cx, c.cy);
    let px = p0[0] + rho * warp_t[0];
    let py = p0[1] + rho * warp_t[1];
    let pz = p0[2] + rho * warp_t[2];
    if !(pz > 0.0 && pz.is_finite()) {
        return None;
    }
    Some((fx * px / pz + cx, fy * py / pz + cy))
}

/// Whether `d̂` is within a factor 1.25 of `z*`.
pub(crate) fn within_125(d_hat: f64, z_star: f64) -> bool {
    d_hat > 0.0 && (d_hat / z_star).max(z_star / d_hat) < 1.25
}

/// `R K⁻¹ u̇` of reference pixel `(x, y)`.
#[inline]
pub(crate) fn ray_point(warp: &Warp, x: usize, y: usize) -> [f64; 3] {
    let p = warp.rotation_k_inv() * nalgebra::Vector3::new(x as f64, y as f64, 1.0);
    [p.x, p.y, p.z]
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::util::rng::SplitMix64;

    /// The AVX-512 and AVX2 builds of the per-pixel terms give the portable build's bits (each
    /// level the CPU has).
    #[test]
    fn pixel_terms_avx512_and_portable_give_the_same_bits() {
        let cfg = LossConfig::default();
        let k = cfg.bins.count;
        let rho: Vec<f64> = (0..k).map(|l| cfg.bins.rho(l)).collect();
        let mut rng = SplitMix64::new(3);
        for case in 0..200 {
            // From flat to sharply peaked costs, with out-of-image runs of m.
            let spread = [0.01, 1.0, 30.0, 300.0][case % 4];
            let energies: Vec<f64> = (0..k)
                .map(|l| if (l + case) % 37 < 5 { cfg.outside_cost } else { rng.range(0.0, spread) })
                .collect();
            let target = rng.below(k);
            let rho_star = rho[target].max(0.05);
            let mut g1 = vec![0.0; k];
            let mut g2 = vec![0.0; k];
            let mut q1 = vec![0.0; k];
            let a = pixel_terms_body(
                &cfg,
                &energies,
                target,
                rho_star,
                &mut g1,
                &rho,
                &mut q1,
                CpuFeatureLevel::Portable,
            );
            for level in [CpuFeatureLevel::Avx2, CpuFeatureLevel::Avx512] {
                let mut scratch = PixelScratch::default();
                let b = pixel_terms_with(&cfg, &energies, target, rho_star, &mut g2, &mut scratch, level);
                assert_eq!(
                    [a.ce, a.rho, a.depth, a.rho_hat].map(f64::to_bits),
                    [b.ce, b.rho, b.depth, b.rho_hat].map(f64::to_bits),
                    "case {case}, {level:?}"
                );
                assert_eq!(a.wta, b.wta);
                assert!(
                    g1.iter().zip(&g2).all(|(x, y)| x.to_bits() == y.to_bits()),
                    "case {case}, {level:?}"
                );
            }
        }
    }
}
