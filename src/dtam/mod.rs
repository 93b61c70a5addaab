//! The DTAM optimiser (Newcombe, Lovegrove and Davison, ICCV 2011) as the paper uses it (eq. 3,
//! data term weighted by `1/λ`): a Huber-TV regularised inverse-depth map `d` from a cost volume.
//!
//! Energy over reference pixels `u`, with an auxiliary inverse-depth map `a` coupled to `d`:
//!
//! ```text
//! E_θ(d, a) = Σ_u  g(u) ‖∇d(u)‖_ε  +  1/(2θ) (d(u) - a(u))²  +  1/λ · C(u, a(u))
//! ```
//!
//! - `‖x‖_ε` is the Huber norm (`|x|²/(2ε)` for `|x| <= ε`, else `|x| - ε/2`), `∇` forward
//!   differences with a zero difference across the last row/column (Neumann boundary);
//! - `g = exp(-α ‖∇I‖^β)` down-weights smoothing across image edges (`I` = grey level / 255);
//! - `C(u, ρ)` the averaged cost volume (`crate::costvolume`), sampled at hypotheses `ρ_k`.
//!
//! Each iteration `n`: `steps_per_search` Chambolle-Pock primal-dual steps on `(d, q)` for fixed
//! `a` ([`huber_tv`]); then, for fixed `d`, a point-wise exhaustive search for `a` over the
//! hypotheses with a sub-bin parabola refinement ([`search`]); `θ` decreases geometrically from
//! `θ_start` to `θ_end` over the schedule's `iterations`, after which the solve stops once the
//! energy has settled and `d` and `a` agree within a tenth of a bin (or at `max_iterations`).
//! SPEC.md §10 gives every formula and default.
//!
//! **Implementation.** An iteration is three row-parallel passes: the dual and the primal halves of
//! the primal-dual step ([`HuberTv::step`]), then one pass over the cost volume that runs the
//! a-search 8 pixels at a time and measures the energy and the `d - a` gap on the way
//! ([`search_with_energy`]). The row kernels have a portable and an AVX-512 build, chosen at run
//! time from the [`CpuFeatureLevel`] the caller passes (a backend its own; [`solve`] the process's). The unfused formulation ([`solve_reference`]: [`HuberTv::step_reference`],
//! [`exhaustive_search_reference`], [`total_energy`], [`rms_gap`]) is kept as the definition;
//! [`solve`] returns its bits for any thread count and either build (tests/dtam.rs).

mod bounds;
mod edge;
mod fused;
pub mod huber_tv;
mod lanes;
pub mod normal_prior;
pub mod search;
pub mod tgv;

use std::time::Instant;

use ndarray::{Array2, ArrayView2, ArrayView3};
use serde::Serialize;

use crate::error::{Error, Result};
use crate::geometry::InverseDepthBins;
use crate::runtime::CpuFeatureLevel;

pub use edge::edge_weights;
pub use fused::{search_with_energy, IterationMeasures};
pub use huber_tv::{HuberTv, HuberTvReport};
pub use normal_prior::SlopeField;
pub use search::{exhaustive_search, exhaustive_search_reference, exhaustive_search_with, CostRange};

/// Parameters of [`solve`]. Every field has a CLI flag (`densefeat reconstruct --help`).
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct DtamParams {
    /// Regularisation strength: the data term is weighted by `1/λ` (paper eq. 3).
    pub lambda: f64,
    /// Huber threshold `ε` on inverse-depth differences between neighbouring pixels, 1/m.
    pub epsilon: f64,
    /// Edge weight `g = exp(-α ‖∇I‖^β)`: `α`.
    pub alpha: f64,
    /// Edge weight exponent `β`.
    pub beta: f64,
    /// First coupling weight `θ` (1/m²-scaled inverse-depth units).
    pub theta_start: f64,
    /// Last coupling weight.
    pub theta_end: f64,
    /// Length of the θ schedule: θ decays geometrically from `theta_start` to `theta_end` over
    /// this many iterations and is then held at `theta_end` until convergence.
    pub iterations: usize,
    /// Primal-dual steps per a-search.
    pub steps_per_search: usize,
    /// Hard cap on iterations (each = `steps_per_search` primal-dual steps and one a-search).
    pub max_iterations: usize,
    /// Convergence: after the schedule, stop once the energy changed by at most this fraction in
    /// the last iteration and the rms `d - a` gap is at most [`GAP_TOLERANCE_BINS`] bins.
    pub tolerance: f64,
}

/// Image width (pixels) at which [`DtamParams`] are stated; [`DtamParams::normalised`] rescales them
/// to another width (SPEC.md §10.1).
pub const REFERENCE_WIDTH: f64 = 640.0;

/// The converged rms `d - a` gap, in bins (`Δρ`): `d` and `a` agree well inside a bin.
pub const GAP_TOLERANCE_BINS: f64 = 0.1;

impl Default for DtamParams {
    fn default() -> Self {
        Self {
            lambda: DEFAULT_LAMBDA,
            epsilon: 1e-3,
            alpha: 10.0,
            beta: 1.0,
            theta_start: 0.05,
            theta_end: 1e-5,
            iterations: 200,
            steps_per_search: 1,
            max_iterations: 1000,
            tolerance: 1e-3,
        }
    }
}

/// Defaults of the normalised parameters the mapping pipeline passes through
/// [`DtamParams::normalised`] (`reconstruct`, `eval`, `demo`; SPEC.md §10.1): chosen on the
/// validation scenes only (SUN3D study room f0935 and synthetic seeds 200000..200099).
pub const MAPPING_DEFAULTS: DtamParams = DtamParams {
    lambda: 100.0,
    epsilon: 1e-3,
    alpha: 10.0,
    beta: 1.0,
    theta_start: 1.0,
    theta_end: 1e-6,
    iterations: 100,
    steps_per_search: 16,
    max_iterations: 500,
    tolerance: 1e-3,
};

/// Default `λ` for RGB cost volumes (mean L1 over 3 channels in grey levels), from a sweep on the
/// hand-built plane scenes of tests/dtam.rs (SPEC.md §10); learned features need their own value.
pub const DEFAULT_LAMBDA: f64 = 300.0;

impl DtamParams {
    /// Check every field.
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] naming the first field out of range.
    pub fn validate(&self) -> Result<()> {
        let pos = |name: &str, v: f64| {
            if v > 0.0 && v.is_finite() {
                Ok(())
            } else {
                Err(Error::invalid_argument(name, format!("{v}: must be positive and finite")))
            }
        };
        pos("lambda", self.lambda)?;
        pos("epsilon", self.epsilon)?;
        pos("theta-start", self.theta_start)?;
        pos("theta-end", self.theta_end)?;
        if !(self.alpha >= 0.0 && self.alpha.is_finite() && self.beta > 0.0 && self.beta.is_finite()) {
            return Err(Error::invalid_argument(
                "alpha/beta",
                format!("α = {}, β = {}: need α >= 0, β > 0", self.alpha, self.beta),
            ));
        }
        if self.theta_end > self.theta_start {
            return Err(Error::invalid_argument(
                "theta",
                format!("theta-end {} > theta-start {}", self.theta_end, self.theta_start),
            ));
        }
        if self.iterations == 0 {
            return Err(Error::invalid_argument("iterations", "need at least 1"));
        }
        if self.steps_per_search == 0 {
            return Err(Error::invalid_argument("steps-per-search", "need at least 1"));
        }
        if self.max_iterations < self.iterations {
            return Err(Error::invalid_argument(
                "max-iterations",
                format!("{} is below --iterations {}", self.max_iterations, self.iterations),
            ));
        }
        if !(self.tolerance >= 0.0 && self.tolerance.is_finite()) {
            return Err(Error::invalid_argument("tolerance", format!("{}: need >= 0", self.tolerance)));
        }
        Ok(())
    }

    /// `θ` at iteration `n`: `θ_start (θ_end/θ_start)^(n/(N-1))` for `n < N = iterations`, then
    /// `θ_end`.
    pub fn theta(&self, n: usize) -> f64 {
        if self.iterations == 1 || n + 1 >= self.iterations {
            return self.theta_end;
        }
        let s = n as f64 / (self.iterations - 1) as f64;
        self.theta_start * (self.theta_end / self.theta_start).powf(s)
    }

    /// The parameters [`solve`] needs for a cost volume, from the normalised parameters the
    /// mapping pipeline states (SPEC.md §10.1): `λ` weights the regulariser against the data term
    /// divided by the volume's cost scale `s`, at [`REFERENCE_WIDTH`]; `θ` is in units of
    /// `R² = (ρ_max - ρ_min)²` of that normalised energy; `ε` is per pixel at [`REFERENCE_WIDTH`].
    /// With `r = width / REFERENCE_WIDTH`:
    /// `λ' = λ s r`, `θ' = θ R² λ r`, `ε' = ε / r`.
    ///
    /// Then the solver's energy is `s` times
    /// `λ r Σ ‖g∇d‖_ε' + Σ (d - a)²/(2 θ R²) + Σ C/s`: the a-search balances the normalised cost
    /// against the coupling independently of `λ`, of the feature kind's cost units and of the image
    /// size, and `λ r` keeps the discrete energy the Riemann sum of one continuous energy at every
    /// resolution (an edge's length in pixels grows as `r`, an area's pixel count as `r²`).
    pub fn normalised(&self, cost_scale: f64, width: usize, rho_range: f64) -> Self {
        let r = width as f64 / REFERENCE_WIDTH;
        let theta = |t: f64| t * rho_range * rho_range * self.lambda * r;
        Self {
            lambda: self.lambda * cost_scale * r,
            theta_start: theta(self.theta_start),
            theta_end: theta(self.theta_end),
            epsilon: self.epsilon / r,
            ..*self
        }
    }
}

/// What a [`solve`] did: solver outcomes are data, not errors.
#[derive(Clone, Debug, Serialize)]
pub struct DtamReport {
    /// Iterations run.
    pub iterations: usize,
    /// Full energy `E_θ(d, a)` after each iteration (with that iteration's `θ`).
    pub energy: Vec<f64>,
    /// Root mean square of `d - a` after each iteration, 1/m.
    pub gap: Vec<f64>,
    /// Whether the convergence test stopped it (else `max_iterations` did).
    pub converged: bool,
    /// Wall time of the whole solve, seconds.
    pub seconds: f64,
}

/// The regularised result.
#[derive(Clone, Debug)]
pub struct DtamResult {
    /// Inverse depth `d`, 1/m, `[H, W]`.
    pub inverse_depth: Array2<f32>,
    /// The auxiliary `a` of the last iteration (the data-term solution near `d`).
    pub auxiliary: Array2<f32>,
}

/// One DTAM solve's inputs (SPEC.md §10), the value every solver and every backend takes: the
/// finalised cost volume and its hypotheses, the keyframe's grey levels (for the edge weights), the
/// initial inverse depth, the parameters, and the regulariser (Huber-TV, or the surface-normal prior
/// of SPEC.md §10.2 with its slope field).
///
/// `C` is where the costs are: a host view (the default), or [`Resident`] for a problem on the
/// costs a backend keeps on its device (`backend::ResidentVolume::dtam_solve`, SPEC.md §15.6).
#[derive(Clone, Copy, Debug)]
pub struct DtamProblem<'a, C = ArrayView3<'a, f32>> {
    /// `[H, W, K]` mean costs; cells `>= crate::costvolume::UNSEEN_COST` are unseen and skipped.
    pub costs: C,
    /// The `K` inverse-depth hypotheses of `costs`.
    pub bins: &'a InverseDepthBins,
    /// The reference image's grey levels, `[H, W]`, 0-255.
    pub grey: ArrayView2<'a, f32>,
    /// The initial inverse depth `d = a`, `[H, W]`, 1/m (typically winner-take-all).
    pub init: ArrayView2<'a, f32>,
    /// The solver's parameters.
    pub params: &'a DtamParams,
    /// `None`: Huber-TV (`g ‖∇d‖_ε`); `Some(q)`: the normal prior (`g ‖∇d − d q‖_ε`).
    pub slope: Option<&'a SlopeField>,
    /// `Some(β)`: TGV² (`g ‖∇d − v/β‖_ε + ‖∇v‖`, SPEC.md §10.4), `β` in pixels of this grid
    /// ([`tgv::normalised_beta`]); not with a slope field.
    pub second_order: Option<f64>,
}

/// The costs of a [`DtamProblem`] that a backend keeps where it computes (a resident volume,
/// SPEC.md §15.6): the problem names no array; the volume that solves it supplies its own.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Resident;

impl<'a> DtamProblem<'a> {
    /// A Huber-TV problem.
    pub fn new(
        costs: ArrayView3<'a, f32>,
        bins: &'a InverseDepthBins,
        grey: ArrayView2<'a, f32>,
        init: ArrayView2<'a, f32>,
        params: &'a DtamParams,
    ) -> Self {
        Self { costs, bins, grey, init, params, slope: None, second_order: None }
    }

    /// Valid parameters, and sizes that agree: costs `[H, W, K]` with `K` hypotheses, image,
    /// initial depth and slope field `[H, W]`.
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] naming what is wrong.
    pub fn check(&self) -> Result<()> {
        self.check_costs(self.costs.dim())
    }
}

impl<'a> DtamProblem<'a, Resident> {
    /// A Huber-TV problem on a resident volume's costs.
    pub fn resident(
        bins: &'a InverseDepthBins,
        grey: ArrayView2<'a, f32>,
        init: ArrayView2<'a, f32>,
        params: &'a DtamParams,
    ) -> Self {
        Self { costs: Resident, bins, grey, init, params, slope: None, second_order: None }
    }
}

impl<'a, C> DtamProblem<'a, C> {
    /// The same problem with the surface-normal prior for the slope field `slope` (SPEC.md §10.2).
    pub fn with_slope(self, slope: &'a SlopeField) -> Self {
        Self { slope: Some(slope), ..self }
    }

    /// The same problem with TGV² of weight `beta` (pixels of this grid; SPEC.md §10.4).
    pub fn with_second_order(self, beta: f64) -> Self {
        Self { second_order: Some(beta), ..self }
    }

    /// The same problem on other costs (a resident volume hands its host copy to the CPU solver so).
    pub fn with_costs<'b, D>(self, costs: D) -> DtamProblem<'b, D>
    where
        'a: 'b,
    {
        let Self { bins, grey, init, params, slope, second_order, .. } = self;
        DtamProblem { costs, bins, grey, init, params, slope, second_order }
    }

    /// [`DtamProblem::check`] for costs of shape `(h, w, k)`.
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] naming what is wrong.
    pub fn check_costs(&self, (h, w, k): (usize, usize, usize)) -> Result<()> {
        self.params.validate()?;
        if k != self.bins.count || self.grey.dim() != (h, w) || self.init.dim() != (h, w) {
            return Err(Error::invalid_argument(
                "DTAM inputs",
                format!(
                    "cost volume {:?} with {} bins, image {:?}, initial depth {:?}: sizes must agree",
                    (h, w, k),
                    self.bins.count,
                    self.grey.dim(),
                    self.init.dim()
                ),
            ));
        }
        if let Some(beta) = self.second_order {
            tgv::check_beta(beta)?;
            if self.slope.is_some() {
                return Err(Error::invalid_argument(
                    "--regularizer",
                    "TGV and the surface-normal prior are two regularisers: choose one",
                ));
            }
        }
        if let Some(q) = self.slope {
            if q.dim() != (h, w) {
                return Err(Error::invalid_argument(
                    "normals",
                    format!("slope field {:?} does not match the image {:?}", q.dim(), (h, w)),
                ));
            }
        }
        Ok(())
    }
}

/// Run DTAM on `problem` to convergence: Huber-TV, or the normal prior where the problem has a
/// slope field, with the process's CPU-feature level.
///
/// # Errors
/// [`Error::InvalidArgument`] for bad parameters or mismatched shapes.
pub fn solve(problem: &DtamProblem) -> Result<(DtamResult, DtamReport)> {
    solve_with(problem, CpuFeatureLevel::get())
}

/// [`solve`] with the row kernels of `level` (a backend passes its own; the same bits for every
/// level).
///
/// # Errors
/// As [`solve`].
pub fn solve_with(problem: &DtamProblem, level: CpuFeatureLevel) -> Result<(DtamResult, DtamReport)> {
    problem.check()?;
    let (bins, params) = (problem.bins, problem.params);
    let start = Instant::now();
    let costs = problem.costs.as_standard_layout();
    let costs = costs.view();
    let range = CostRange::new(costs);
    Ok(iterate(start, problem, |n, tv, a| {
        let theta = params.theta(n);
        tv.steps_with(a.view(), theta, params.steps_per_search, level);
        let m = search_with_energy(costs, &range, bins, tv, theta, params.lambda, a, level);
        (m.energy, m.gap)
    }))
}

/// The same solve in the unfused formulation of the module docs (one primal-dual step at a time
/// with [`HuberTv::step_reference`], [`exhaustive_search_reference`], [`total_energy`],
/// [`rms_gap`]): the definition [`solve`] is tested against.
///
/// # Errors
/// As [`solve`].
pub fn solve_reference(problem: &DtamProblem) -> Result<(DtamResult, DtamReport)> {
    problem.check()?;
    let (costs, bins, params) = (problem.costs, problem.bins, problem.params);
    let start = Instant::now();
    let range = CostRange::new(costs);
    Ok(iterate(start, problem, |n, tv, a| {
        let theta = params.theta(n);
        for _ in 0..params.steps_per_search {
            tv.step_reference(a.view(), theta);
        }
        *a = exhaustive_search_reference(costs, &range, bins, tv.primal(), theta, params.lambda);
        let e = total_energy(tv, costs, bins, a.view(), theta, params.lambda);
        (e, rms_gap(tv.primal(), a.view()))
    }))
}

fn iterate(
    start: Instant,
    problem: &DtamProblem,
    mut iteration: impl FnMut(usize, &mut HuberTv, &mut Array2<f32>) -> (f64, f64),
) -> (DtamResult, DtamReport) {
    let params = problem.params;
    let g = edge_weights(problem.grey, params.alpha, params.beta);
    let init = problem.init;
    let mut tv = match (problem.slope, problem.second_order) {
        (Some(q), _) => HuberTv::with_slope(init.to_owned(), g, params.epsilon, q),
        (None, Some(beta)) => HuberTv::with_second_order(init.to_owned(), g, params.epsilon, beta),
        (None, None) => HuberTv::new(init.to_owned(), g, params.epsilon),
    };
    let mut a = init.to_owned();
    let mut history = History::new(params);
    for n in 0..params.max_iterations {
        let (e, gap) = iteration(n, &mut tv, &mut a);
        if history.push(n, e, gap, params, problem.bins) {
            break;
        }
    }
    let report = history.report(start);
    (DtamResult { inverse_depth: tv.primal().to_owned(), auxiliary: a }, report)
}

pub(crate) struct History {
    energy: Vec<f64>,
    gap: Vec<f64>,
    converged: bool,
}

impl History {
    pub(crate) fn new(params: &DtamParams) -> Self {
        Self {
            energy: Vec::with_capacity(params.iterations),
            gap: Vec::with_capacity(params.iterations),
            converged: false,
        }
    }

    /// Record iteration `n`; `true` when the convergence test stops the solve there.
    pub(crate) fn push(
        &mut self,
        n: usize,
        e: f64,
        g: f64,
        params: &DtamParams,
        bins: &InverseDepthBins,
    ) -> bool {
        let settled =
            self.energy.last().is_some_and(|&p| (e - p).abs() <= params.tolerance * e.abs().max(p.abs()));
        let done = n + 1 >= params.iterations && settled && g <= GAP_TOLERANCE_BINS * bins.step();
        self.energy.push(e);
        self.gap.push(g);
        self.converged = done;
        done
    }

    pub(crate) fn report(self, start: Instant) -> DtamReport {
        DtamReport {
            iterations: self.energy.len(),
            energy: self.energy,
            gap: self.gap,
            converged: self.converged,
            seconds: start.elapsed().as_secs_f64(),
        }
    }
}

/// `sqrt(mean (d - a)²)`, summed per row in f64, rows in order. The definition of the report's gap;
/// [`solve`] gets the same bits from [`search_with_energy`].
pub fn rms_gap(d: ArrayView2<f32>, a: ArrayView2<f32>) -> f64 {
    use rayon::prelude::*;
    let (h, w) = d.dim();
    let rows: Vec<f64> = (0..h)
        .into_par_iter()
        .map(|y| (0..w).map(|x| (f64::from(d[[y, x]]) - f64::from(a[[y, x]])).powi(2)).sum())
        .collect();
    (rows.iter().sum::<f64>() / (h * w).max(1) as f64).sqrt()
}

/// `E_θ(d, a)`, with `C(u, a)` linearly interpolated between hypotheses (unseen: 0). Summed per row
/// in f64, rows in order: the same bits for any thread count. The definition of the report's
/// energy; [`solve`] gets the same bits from [`search_with_energy`], fused with the a-search.
pub fn total_energy(
    tv: &HuberTv,
    costs: ArrayView3<f32>,
    bins: &InverseDepthBins,
    a: ArrayView2<f32>,
    theta: f64,
    lambda: f64,
) -> f64 {
    use rayon::prelude::*;
    let d = tv.primal();
    let (h, w, k) = costs.dim();
    // Per-row sums in parallel, then summed over rows in order: the same bits for any thread count.
    let rows: Vec<(f64, f64)> = (0..h)
        .into_par_iter()
        .map(|y| {
            let (mut coupling, mut data) = (0.0, 0.0);
            for x in 0..w {
                let diff = d[[y, x]] as f64 - a[[y, x]] as f64;
                coupling += diff * diff / (2.0 * theta);
                let b = bins.bin_of(a[[y, x]] as f64).clamp(0.0, (k - 1) as f64);
                let k0 = (b.floor() as usize).min(k.saturating_sub(2));
                let t = b - k0 as f64;
                let c0 = costs[[y, x, k0]];
                let c1 = costs[[y, x, (k0 + 1).min(k - 1)]];
                if c0 < search::UNSEEN && c1 < search::UNSEEN {
                    data += ((1.0 - t) * c0 as f64 + t * c1 as f64) / lambda;
                }
            }
            (coupling, data)
        })
        .collect();
    let (mut coupling, mut data) = (0.0, 0.0);
    for (c, dt) in rows {
        coupling += c;
        data += dt;
    }
    tv.regulariser_energy() + coupling + data
}
