//! The portable builds of the lane kernels (see `mod.rs`): each lane runs the scalar definition's
//! operations on plain arrays, in the same order as `avx512.rs`.

use super::{energy_scaled, parabola_offset, Lanes, Scan, SearchParams, LANES, UNSEEN};

/// The portable lane scan: each lane runs the scalar definition's scan over its own `lo..=hi`,
/// skipping unseen cells: the first seen hypothesis is taken, then any with a strictly lower
/// energy, so ties, infinities and NaNs resolve exactly as in `search::search_range`. The lanes step
/// through their ranges together for `span` steps (a lane past its `hi` idles).
/// `avx512.rs`'s build performs the same operations on whole registers.
#[inline(always)]
pub(super) fn scan_lanes(costs: &[f32], p: &SearchParams, l: &Lanes) -> Scan {
    let k = p.k;
    let cell = |i: usize| costs[i.min(costs.len() - 1)]; // in bounds by construction
    let rho = |i: usize| p.rho[i.min(k - 1)];
    let (mut best, mut arg, mut found) = ([f64::INFINITY; LANES], [0usize; LANES], [false; LANES]);
    for t in 0..l.span {
        for j in 0..LANES {
            let kk = l.lo[j] + t;
            let active = !l.flat[j] && kk <= l.hi[j];
            let kk = if active { kk } else { l.lo[j] };
            let c = cell(l.off[j] + kk);
            let e = energy_scaled(l.d[j], rho(kk), c, p.inv_two_theta, p.inv_lambda);
            // `!(c >= UNSEEN)`: the scan skips only cells at or above UNSEEN (a NaN is scanned).
            let scanned = c < UNSEEN || c.is_nan();
            let take = active && scanned && (!found[j] || e < best[j]);
            best[j] = if take { e } else { best[j] };
            arg[j] = if take { kk } else { arg[j] };
            found[j] |= take;
        }
    }
    Scan { best, arg, found }
}

/// The portable refinement: per lane the parabola through the energies at `k* - 1, k*, k* + 1`
/// (none at the ends or next to an unseen cell), `a = d` where the lane is flat or found nothing.
/// `avx512.rs`'s build performs the same operations on whole registers.
#[inline(always)]
pub(super) fn refine_lanes(costs: &[f32], p: &SearchParams, l: &Lanes, s: &Scan) -> [f64; LANES] {
    let k = p.k;
    let cell = |i: usize| costs[i.min(costs.len() - 1)]; // in bounds by construction
    let rho = |i: usize| p.rho[i.min(k - 1)];
    let mut a = [0.0; LANES];
    for (j, a) in a.iter_mut().enumerate() {
        let kk = s.arg[j];
        let inner = kk > 0 && kk + 1 < k;
        let (km, kp) = if inner { (kk - 1, kk + 1) } else { (kk, kk) };
        let (cm, cp) = (cell(l.off[j] + km), cell(l.off[j] + kp));
        let em = energy_scaled(l.d[j], rho(km), cm, p.inv_two_theta, p.inv_lambda);
        let ep = energy_scaled(l.d[j], rho(kp), cp, p.inv_two_theta, p.inv_lambda);
        let delta =
            if inner && cm < UNSEEN && cp < UNSEEN { parabola_offset(em, s.best[j], ep) } else { 0.0 };
        let refined = if delta == 0.0 { rho(kk) } else { p.rho_min + (kk as f64 + delta) * p.step };
        *a = if l.flat[j] || !s.found[j] { l.d[j] } else { refined };
    }
    a
}

/// Per lane: `a as f32`, then `total_energy`'s coupling term `(d - a)² / (2θ)` and data term
/// (`C` interpolated linearly at `a`'s bin, over `λ`), and whether the data term counts (both
/// interpolated cells seen). The reference's expressions, term by term.
#[inline(always)]
pub(super) fn terms_lanes(
    costs: &[f32],
    p: &SearchParams,
    off: &[usize; LANES],
    d: &[f64; LANES],
    a: &[f64; LANES],
) -> ([f32; LANES], [f64; LANES], [f64; LANES], [bool; LANES]) {
    let k = p.k;
    let last = (k - 1) as f64;
    let cell = |i: usize| costs[i.min(costs.len() - 1)]; // in bounds by construction
    let (mut a32, mut coupling, mut data, mut seen) =
        ([0.0f32; LANES], [0.0; LANES], [0.0; LANES], [false; LANES]);
    for j in 0..LANES {
        let a = a[j] as f32;
        a32[j] = a;
        let diff = d[j] - a as f64;
        coupling[j] = diff * diff / (2.0 * p.theta);
        let b = ((a as f64 - p.rho_min) / p.step).clamp(0.0, last);
        let k0 = (b.floor() as usize).min(k.saturating_sub(2));
        let t = b - k0 as f64;
        let c0 = cell(off[j] + k0);
        let c1 = cell(off[j] + (k0 + 1).min(k - 1));
        seen[j] = c0 < UNSEEN && c1 < UNSEEN;
        data[j] = ((1.0 - t) * c0 as f64 + t * c1 as f64) / p.lambda;
    }
    (a32, coupling, data, seen)
}

/// The index of the first least block minimum.
#[inline(always)]
pub(super) fn least_block(minima: &[f32]) -> usize {
    let mut best = 0;
    for (j, &m) in minima.iter().enumerate() {
        if m < minima[best] {
            best = j;
        }
    }
    best
}
