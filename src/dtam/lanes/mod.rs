//! The lane kernels of DTAM's a-search and of its energy terms (SPEC.md §10.1): [`LANES`]
//! consecutive pixels of a row, one per lane, searched and measured together.
//!
//! Layout (issue 33 item 3, as `ops/conv2d/direct/`): this file holds the types shared by the builds
//! and the dispatch; `portable.rs` the plain-Rust lane loops (which the compiler may vectorise);
//! `avx512.rs` the same IEEE operations, lane for lane and in the same order, on `__m512d` registers,
//! with the costs gathered from the pixels' curves; `avx2.rs` the lane scan on two `__m256d`
//! registers. The ISA files import only from here. Which build runs is the `ISA` constant of the
//! caller's row loop (`search::for_each_group`, `fused::fused_row_any`): [`AVX512`] only inside
//! functions built with AVX-512F, [`AVX2`] only inside functions built with AVX2 and FMA, each run
//! where the [`crate::runtime::CpuFeatureLevel`] passed to the solver reported it; every build gives
//! the same bits (tests/dtam.rs checks each against the scalar definition).

#[cfg(target_arch = "x86_64")]
mod avx2;
#[cfg(target_arch = "x86_64")]
mod avx512;
mod portable;

// What the ISA files use from outside this op (they import only from here).
use super::bounds::{applies, bounded_search as bounded_search_portable, BLOCK_BINS};
use super::search::{energy_scaled, SearchParams, UNSEEN};
use crate::costvolume::{parabola_offset, MAX_PARABOLA_OFFSET};

/// Which build of the lane kernels a row loop runs: its `ISA` const parameter. `AVX512` only inside
/// functions built with AVX-512F, `AVX2` only inside functions built with AVX2 and FMA, each run
/// only where the CPU reported it; `PORTABLE` anywhere.
pub(crate) const PORTABLE: u8 = 0;
/// See [`PORTABLE`]: the AVX2 lane scan (`avx2.rs`), the other kernels portable.
pub(crate) const AVX2: u8 = 1;
/// See [`PORTABLE`]: every kernel's AVX-512 build (`avx512.rs`).
pub(crate) const AVX512: u8 = 2;

/// Pixels searched together, one per lane (one AVX-512 register of `f64`).
pub(crate) const LANES: usize = 8;

/// [`LANES`] consecutive pixels of a row, one per lane, ready to search: the offset of each curve
/// in the row's costs, `d`, whether the lane is flat (nothing seen, or past the row's end) and its
/// range `lo..=hi`: the planned pruned range, or the full curve where the hypothesis nearest `d` is
/// unseen (`full`), as in `search::search_pixel`. `span`: the longest live range.
pub(crate) struct Lanes {
    pub off: [usize; LANES],
    pub d: [f64; LANES],
    pub flat: [bool; LANES],
    pub full: [bool; LANES],
    pub lo: [usize; LANES],
    pub hi: [usize; LANES],
    pub span: usize,
}

/// The result of each lane's scan: the least energy, its hypothesis and whether any was seen.
pub(crate) struct Scan {
    pub best: [f64; LANES],
    pub arg: [usize; LANES],
    pub found: [bool; LANES],
}

/// The scan of each live lane over its `lo..=hi` ([`portable::scan_lanes`] or its AVX-512 or AVX2
/// build): the first seen hypothesis, then any with a strictly lower energy.
#[inline(always)]
pub(crate) fn scan<const ISA: u8>(costs: &[f32], p: &SearchParams, lanes: &Lanes) -> Scan {
    #[cfg(target_arch = "x86_64")]
    if ISA == AVX512 {
        // SAFETY: `ISA` is `AVX512` only inside functions built with AVX-512F, which run only where
        // the CPU reported it (`CpuFeatureLevel::avx512f`); every curve offset plus hypothesis is in
        // `costs`.
        return unsafe { avx512::scan_lanes(costs, p, lanes) };
    }
    #[cfg(target_arch = "x86_64")]
    if ISA == AVX2 {
        // SAFETY: `ISA` is `AVX2` only inside functions built with AVX2 and FMA, which run only where
        // the CPU reported them (`CpuFeatureLevel::avx2_fma`); offsets as above.
        return unsafe { avx2::scan_lanes(costs, p, lanes) };
    }
    portable::scan_lanes(costs, p, lanes)
}

/// The parabola refinement of the lanes' scan results ([`portable::refine_lanes`] or its AVX-512
/// build).
#[inline(always)]
pub(crate) fn refine<const ISA: u8>(
    costs: &[f32],
    p: &SearchParams,
    lanes: &Lanes,
    s: &Scan,
) -> [f64; LANES] {
    #[cfg(target_arch = "x86_64")]
    if ISA == AVX512 {
        // SAFETY: as in `scan`.
        return unsafe { avx512::refine_lanes(costs, p, lanes, s) };
    }
    portable::refine_lanes(costs, p, lanes, s)
}

/// Per lane `a as f32`, the coupling term, the data term and whether it counts
/// ([`portable::terms_lanes`] or its AVX-512 build).
#[inline(always)]
pub(crate) fn terms<const ISA: u8>(
    costs: &[f32],
    p: &SearchParams,
    off: &[usize; LANES],
    d: &[f64; LANES],
    a: &[f64; LANES],
) -> ([f32; LANES], [f64; LANES], [f64; LANES], [bool; LANES]) {
    #[cfg(target_arch = "x86_64")]
    if ISA == AVX512 {
        // SAFETY: as in `scan`; every `off[j]` plus hypothesis lies in `costs`.
        return unsafe { avx512::terms_lanes(costs, p, off, d, a) };
    }
    portable::terms_lanes(costs, p, off, d, a)
}

/// One pixel's bounded search of `lo..=hi` ([`super::bounds::bounded_search`] or its AVX-512
/// build): the least `(E(k), k)` over the seen cells, the definition's first strict minimum.
#[inline(always)]
pub(crate) fn bounded<const ISA: u8>(
    curve: &[f32],
    minima: &[f32],
    p: &SearchParams,
    d: f64,
    lo: usize,
    hi: usize,
) -> Option<(usize, f64)> {
    #[cfg(target_arch = "x86_64")]
    if ISA == AVX512 {
        // SAFETY: as in `scan`; `curve` and `minima` are the pixel's whole slices, `lo <= hi < K`.
        return unsafe { avx512::bounded_search(curve, minima, p, d, lo, hi) };
    }
    bounded_search_portable(curve, minima, p, d, lo, hi)
}

/// The index of a least block minimum (a prefetch hint only: any index below the length is safe).
#[inline(always)]
pub(crate) fn least_block<const ISA: u8>(minima: &[f32]) -> usize {
    #[cfg(target_arch = "x86_64")]
    if ISA == AVX512 && minima.len() <= 16 {
        // SAFETY: as in `scan`; the masked load reads `minima.len()` floats.
        return unsafe { avx512::least_block(minima) };
    }
    portable::least_block(minima)
}
