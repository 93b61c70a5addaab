//! The AVX-512 row kernel of [`super::CostVolumeImpl::Fast`]: the bits of the portable kernel
//! (`fast.rs`), computed 16 hypotheses at a time.
//!
//! Per reference pixel and block of 16 hypotheses, the geometry runs in two 8-lane `f64` halves with
//! exactly the portable kernel's expressions (`p = a + t·ρ` as a multiply then an add, `u = (f_x p_x)
//! / p_z + c_x`, the same comparisons, `floor`, `min` with the clamp, weights rounded to `f32`), so
//! validity, corner offsets and weights are the same values. Then:
//! - three channels: the twelve corner values of the 16 hypotheses come from masked gathers (only
//!   valid lanes load) and each lane computes `s = ((w0 a + w1 b) + w2 c) + w3 d` and
//!   `(|r0 - s0| + |r2 - s2|) + |r1 - s1|`, the portable kernel's per-hypothesis order (from a
//!   byte-valued map's packed words: one 16-byte load of the four corners per lane, [`corner_quads`],
//!   or for a map one pixel wide or high one 4-byte gather per corner);
//! - any other channel count: per valid hypothesis, the channel loop with 16-lane partial sums
//!   (channel `c` in lane `c mod 16`) and the same pairwise fold as `l1_distance`.
//!
//! Sums and counts of the block are updated with one masked vector add each (a valid cell gets
//! `sum + l1` and `count + 1`, exactly the scalar update). Corner offsets are `i32`, so the caller
//! runs this kernel only when every flat offset fits ([`fits_i32`]).

#![cfg(target_arch = "x86_64")]

use std::arch::x86_64::*;

use super::{row_any, Geometry, Scratch, Slices};

/// Hypotheses per block (one `zmm` of `f32`).
const BLOCK: usize = 16;

/// Whether this CPU runs the kernel (AVX-512F, BW for the `u16` count update, VL, DQ), at the
/// process's level (the tests' probe; `add_frame` asks the level it is handed).
#[cfg(test)]
fn available() -> bool {
    crate::runtime::has_avx512_bw_vl_dq()
}

/// Whether every flat corner offset `(y·W + x)·C + ch` of a `W x H x C` map fits an `i32` index.
pub(super) fn fits_i32(w: usize, h: usize, c: usize) -> bool {
    w.checked_mul(h).and_then(|n| n.checked_mul(c)).is_some_and(|n| n <= i32::MAX as usize)
}

/// A copy of a feature map starting on a 64-byte boundary.
pub(super) struct AlignedCopy {
    chunks: Vec<Chunk>,
    len: usize,
}

/// 16 `f32`, aligned as one cache line.
#[derive(Clone, Copy)]
#[repr(C, align(64))]
struct Chunk([f32; 16]);

impl AlignedCopy {
    pub(super) fn new(data: &[f32]) -> Self {
        let mut chunks = vec![Chunk([0.0; 16]); data.len().div_ceil(16)];
        for (dst, src) in chunks.iter_mut().zip(data.chunks(16)) {
            dst.0[..src.len()].copy_from_slice(src);
        }
        Self { chunks, len: data.len() }
    }

    pub(super) fn as_slice(&self) -> &[f32] {
        // SAFETY: `Chunk` is `repr(C)` of 16 `f32` with no padding (64 bytes), so the vector is
        // `16·chunks` contiguous, initialised `f32`s; `len` of them are the data.
        unsafe { std::slice::from_raw_parts(self.chunks.as_ptr().cast::<f32>(), self.len) }
    }
}

/// A byte-valued RGB map packed one pixel per word, `r | g << 8 | b << 16`: the three values a
/// pixel's channels hold, exactly (each is an integer in `0..=255`, so the conversion back to `f32`
/// is exact and every sample gets the same bits as from the float map).
///
/// For a map at least 2x2 it also holds the **quads**: per pixel `i` with a row below, the words of
/// the bilinear stencil `[i, i + 1, i + W, i + W + 1]` in 16 bytes, so that one plain load per
/// hypothesis fetches its four corners ([`corner_quads`]; the entry of the last column, whose right
/// neighbour does not exist, repeats its own words and is never read: corners stop at `x0 = W - 2`).
pub(super) struct PackedRgb {
    words: Vec<u32>,
    quads: Vec<[u32; 4]>,
}

impl PackedRgb {
    /// The packed map of a `width`-pixel-wide map, or `None` unless `channels == 3` and every value is
    /// an integer `0..=255` (bit for bit: `-0.0` and NaN are not).
    pub(super) fn new(data: &[f32], channels: usize, width: usize) -> Option<Self> {
        if channels != 3 {
            return None;
        }
        let byte = |v: f32| {
            let b = v as u8; // saturating; exact for the values accepted below
            (f32::from(b).to_bits() == v.to_bits()).then_some(u32::from(b))
        };
        let words = data
            .chunks_exact(3)
            .map(|p| Some(byte(p[0])? | byte(p[1])? << 8 | byte(p[2])? << 16))
            .collect::<Option<Vec<u32>>>()?;
        let mut quads = Vec::new();
        if width > 1 && words.len() >= 2 * width {
            quads.reserve_exact(words.len() - width);
            // Row `y` and row `y + 1`, for every row with one below.
            for (top, bottom) in words.chunks_exact(width).zip(words[width..].chunks_exact(width)) {
                quads.extend((0..width).map(|x| {
                    let right = (x + 1).min(width - 1);
                    [top[x], top[right], bottom[x], bottom[right]]
                }));
            }
        }
        Some(Self { words, quads })
    }

    fn as_slice(&self) -> &[u32] {
        &self.words
    }
}

/// Validity, corner offsets (`i32`, the top-left corner's first channel) and the four `f32`
/// bilinear weights of 16 hypotheses.
struct Block {
    ok: __mmask16,
    offset: __m512i,
    w: [__m512; 4],
}

/// Per-row constants of the geometry.
struct RowGeo {
    a: [f64; 3],
    t: [f64; 3],
    f: [f64; 2],
    centre: [f64; 2],
    max: [f64; 2],
    cap: [f64; 2],
    w: i32,
    c: i32,
}

/// The geometry of 8 hypotheses (`rho`, lanes under `live`): validity mask, `x0`, `y0` as `i32`, and
/// the four weights rounded to `f32`. The expressions are the portable kernel's, term for term.
#[inline]
#[target_feature(enable = "avx512f,avx512bw,avx512vl,avx512dq")]
fn geometry8(g: &RowGeo, rho: __m512d, live: __mmask8) -> (__mmask8, __m256i, [__m256; 4]) {
    let set = _mm512_set1_pd;
    let px = _mm512_add_pd(set(g.a[0]), _mm512_mul_pd(set(g.t[0]), rho));
    let py = _mm512_add_pd(set(g.a[1]), _mm512_mul_pd(set(g.t[1]), rho));
    let pz = _mm512_add_pd(set(g.a[2]), _mm512_mul_pd(set(g.t[2]), rho));
    let inv = _mm512_div_pd(set(1.0), pz);
    let u = _mm512_add_pd(_mm512_mul_pd(_mm512_mul_pd(set(g.f[0]), px), inv), set(g.centre[0]));
    let v = _mm512_add_pd(_mm512_mul_pd(_mm512_mul_pd(set(g.f[1]), py), inv), set(g.centre[1]));
    // `pz > 0 && pz.is_finite() && u >= 0 && u <= x_max && v >= 0 && v <= y_max`; ordered
    // comparisons are false on NaN, as Rust's.
    let zero = _mm512_setzero_pd();
    let mut ok = _mm512_mask_cmp_pd_mask::<_CMP_GT_OQ>(live, pz, zero);
    ok = _mm512_mask_cmp_pd_mask::<_CMP_LT_OQ>(ok, _mm512_abs_pd(pz), set(f64::INFINITY));
    ok = _mm512_mask_cmp_pd_mask::<_CMP_GE_OQ>(ok, u, zero);
    ok = _mm512_mask_cmp_pd_mask::<_CMP_LE_OQ>(ok, u, set(g.max[0]));
    ok = _mm512_mask_cmp_pd_mask::<_CMP_GE_OQ>(ok, v, zero);
    ok = _mm512_mask_cmp_pd_mask::<_CMP_LE_OQ>(ok, v, set(g.max[1]));
    // `u.floor().min(x_cap)`: on a valid lane u is finite and non-negative, so `vminpd` (second
    // operand on a NaN or a tie) gives Rust's `min`; other lanes are never read.
    const FLOOR: i32 = _MM_FROUND_TO_NEG_INF | _MM_FROUND_NO_EXC;
    let x0 = _mm512_min_pd(_mm512_roundscale_pd::<FLOOR>(u), set(g.cap[0]));
    let y0 = _mm512_min_pd(_mm512_roundscale_pd::<FLOOR>(v), set(g.cap[1]));
    let (fa, fb) = (_mm512_sub_pd(u, x0), _mm512_sub_pd(v, y0));
    let one = set(1.0);
    let (ga, gb) = (_mm512_sub_pd(one, fa), _mm512_sub_pd(one, fb));
    let w = [
        _mm512_cvtpd_ps(_mm512_mul_pd(ga, gb)),
        _mm512_cvtpd_ps(_mm512_mul_pd(fa, gb)),
        _mm512_cvtpd_ps(_mm512_mul_pd(ga, fb)),
        _mm512_cvtpd_ps(_mm512_mul_pd(fa, fb)),
    ];
    // Truncation of the (integral, in-range on valid lanes) corner; garbage elsewhere, never read.
    let (xi, yi) = (_mm512_cvttpd_epi32(x0), _mm512_cvttpd_epi32(y0));
    (ok, _mm256_add_epi32(_mm256_mullo_epi32(yi, _mm256_set1_epi32(g.w)), xi), w)
}

/// Join two 8-lane halves into 16 lanes.
#[inline]
#[target_feature(enable = "avx512f,avx512bw,avx512vl,avx512dq")]
fn join_ps(lo: __m256, hi: __m256) -> __m512 {
    _mm512_insertf32x8::<1>(_mm512_castps256_ps512(lo), hi)
}

/// The geometry of hypotheses `k..k+16` (lanes past `K` are invalid).
#[inline]
#[target_feature(enable = "avx512f,avx512bw,avx512vl,avx512dq")]
fn block(g: &RowGeo, rhos: &[f64], k: usize) -> Block {
    let n = (rhos.len() - k).min(BLOCK);
    let live = if n == BLOCK { u16::MAX } else { (1u16 << n) - 1 };
    let (m_lo, m_hi) = (live as u8, (live >> 8) as u8);
    // SAFETY: masked loads touch only lanes below `n`, inside `rhos[k..]`.
    let (r_lo, r_hi) = unsafe {
        let p = rhos.as_ptr().add(k);
        (_mm512_maskz_loadu_pd(m_lo, p), _mm512_maskz_loadu_pd(m_hi, p.add(8)))
    };
    let (ok_lo, xy_lo, w_lo) = geometry8(g, r_lo, m_lo);
    let (ok_hi, xy_hi, w_hi) = geometry8(g, r_hi, m_hi);
    let ok = u16::from(ok_lo) | (u16::from(ok_hi) << 8);
    let cell = _mm512_inserti64x4::<1>(_mm512_castsi256_si512(xy_lo), xy_hi);
    let offset = _mm512_mullo_epi32(cell, _mm512_set1_epi32(g.c));
    let w = std::array::from_fn(|i| join_ps(w_lo[i], w_hi[i]));
    Block { ok, offset, w }
}

/// The portable row kernel ([`super::portable`]'s body) compiled with AVX-512F: the same bits.
///
/// # Safety
/// The CPU has AVX-512F.
#[target_feature(enable = "avx512f")]
pub(super) unsafe fn row_generic(
    geo: &Geometry,
    feats: &Slices,
    rhos: &[f64],
    y: usize,
    sum_row: &mut [f32],
    count_row: &mut [u16],
    scratch: &mut Scratch,
) {
    row_any(geo, feats, rhos, y, sum_row, count_row, scratch);
}

/// One reference row of `add_frame` (see `portable::row`, whose bits this reproduces).
///
/// # Safety
/// The CPU must have the features `CpuFeatureLevel::avx512_bw_vl_dq` checks, and [`fits_i32`] must hold for the map.
#[target_feature(enable = "avx512f,avx512bw,avx512vl,avx512dq")]
pub(super) unsafe fn row(
    geo: &Geometry,
    feats: &Slices,
    packed: Option<&PackedRgb>,
    rhos: &[f64],
    y: usize,
    sum_row: &mut [f32],
    count_row: &mut [u16],
) {
    // The reference row is walked in the reference camera; warped positions, bounds and offsets
    // are in the live camera (its own size and intrinsics, SPEC.md §9.1).
    let cam = geo.live;
    let c = feats.channels;
    let (w, k_count) = (geo.camera.width, rhos.len());
    let (lw, lh) = (cam.width, cam.height);
    let t = geo.t;
    let mut g = RowGeo {
        a: [0.0; 3],
        t: [t.x, t.y, t.z],
        f: [cam.fx, cam.fy],
        centre: [cam.cx, cam.cy],
        max: [(lw - 1) as f64, (lh - 1) as f64],
        cap: [lw.saturating_sub(2) as f64, lh.saturating_sub(2) as f64],
        w: lw as i32,
        // Offsets count pixels in the packed map, floats otherwise.
        c: if packed.is_some() { 1 } else { c as i32 },
    };
    // Corner steps in the units of the offsets (pixels in the packed map, floats otherwise).
    let unit = g.c as usize;
    let (dx, dy) = (if lw > 1 { unit } else { 0 }, if lh > 1 { lw * unit } else { 0 });
    // How many pixels ahead the sums and counts are prefetched: about one memory latency's worth of
    // work (a pixel of the 3-channel kernel is quicker than one of the 16·N-channel kernels).
    let ahead = if c <= 3 { 4 } else { 2 };
    for x in 0..w {
        let a = geo.warp.point(x as f64, y as f64, 0.0);
        g.a = [a.x, a.y, a.z];
        let r = &feats.reference[(y * w + x) * c..(y * w + x + 1) * c];
        let base = x * k_count;
        if x + ahead < w {
            prefetch_cells(sum_row, count_row, (x + ahead) * k_count, k_count);
        }
        for k in (0..k_count).step_by(BLOCK) {
            let b = block(&g, rhos, k);
            if b.ok == 0 {
                continue;
            }
            // SAFETY (all three): valid lanes' corners lie inside `live` (x0 <= W-2 or W = 1,
            // likewise y0).
            let l1 = if let Some(packed) = packed {
                unsafe { l1_rgb16_packed(packed, &b, dx as i32, dy as i32, r) }
            } else if c == 3 {
                unsafe { l1_rgb16(feats.live, &b, dx as i32, dy as i32, r) }
            } else if c == 32 {
                unsafe { l1_chunks16::<2>(feats.live, &b, dx, dy, r) }
            } else if c == 16 {
                unsafe { l1_chunks16::<1>(feats.live, &b, dx, dy, r) }
            } else if c == 64 {
                unsafe { l1_chunks16::<4>(feats.live, &b, dx, dy, r) }
            } else {
                // SAFETY: as above.
                unsafe { l1_any16(feats.live, &b, dx, dy, r) }
            };
            let l1 = _mm512_min_ps(l1, _mm512_set1_ps(feats.truncation));
            let n = (k_count - k).min(BLOCK);
            let store = if n == BLOCK { u16::MAX } else { (1u16 << n) - 1 };
            // SAFETY: lanes below `n` are cells `base + k .. base + k + n` of this row.
            unsafe {
                let ps = sum_row.as_mut_ptr().add(base + k);
                let old = _mm512_maskz_loadu_ps(store, ps);
                _mm512_mask_storeu_ps(ps, store, _mm512_mask_add_ps(old, b.ok, old, l1));
                let pc = count_row.as_mut_ptr().add(base + k).cast::<__m256i>();
                let old = _mm256_maskz_loadu_epi16(store, pc.cast());
                let new = _mm256_mask_add_epi16(old, b.ok, old, _mm256_set1_epi16(1));
                _mm256_mask_storeu_epi16(pc.cast(), store, new);
            }
        }
    }
}

/// Ask for the cache lines of cells `at..at + k` of the row's sums and counts. The
/// row is read and written once per frame in order, but the hardware prefetchers do not run ahead of
/// it across 4 KB pages: without this, the masked add of the sums waited on their load for about a
/// third of the kernel's time (SPEC.md §9.4).
#[inline]
#[target_feature(enable = "avx512f,avx512bw,avx512vl,avx512dq")]
fn prefetch_cells(sum_row: &[f32], count_row: &[u16], at: usize, k: usize) {
    let (sums, counts) = (&sum_row[at..at + k], &count_row[at..at + k]);
    for i in (0..k).step_by(16) {
        // A hint that never faults; the address is inside `sums`.
        _mm_prefetch::<_MM_HINT_T0>(sums[i..].as_ptr().cast());
    }
    for i in (0..k).step_by(32) {
        _mm_prefetch::<_MM_HINT_T0>(counts[i..].as_ptr().cast());
    }
}

/// Three channels, 16 hypotheses: per lane `((w0 a + w1 b) + w2 c) + w3 d` per channel, then
/// `(|d0| + |d2|) + |d1|`.
///
/// # Safety
/// Every valid lane's corners `o + {0, dx, dy, dy + dx} + {0, 1, 2}` must lie inside `live`.
#[inline]
#[target_feature(enable = "avx512f,avx512bw,avx512vl,avx512dq")]
unsafe fn l1_rgb16(live: &[f32], b: &Block, dx: i32, dy: i32, r: &[f32]) -> __m512 {
    let p = live.as_ptr();
    let zero = _mm512_setzero_ps();
    let corners = [
        b.offset,
        _mm512_add_epi32(b.offset, _mm512_set1_epi32(dx)),
        _mm512_add_epi32(b.offset, _mm512_set1_epi32(dy)),
        _mm512_add_epi32(b.offset, _mm512_set1_epi32(dy + dx)),
    ];
    let mut d = [zero; 3];
    for (ch, d) in d.iter_mut().enumerate() {
        let at: [__m512; 4] =
            std::array::from_fn(|i| _mm512_add_epi32(corners[i], _mm512_set1_epi32(ch as i32)))
                // SAFETY: only valid lanes load, inside `live` (the caller's contract).
                .map(|o| unsafe { gather(b.ok, o, p) });
        *d = channel_l1(&b.w, at, r[ch]);
    }
    _mm512_add_ps(_mm512_add_ps(d[0], d[2]), d[1])
}

/// One channel of 16 hypotheses: `|r - (((w0 a + w1 b) + w2 c) + w3 d)|` from the four corners'
/// values, the generic loop's expression.
#[inline]
#[target_feature(enable = "avx512f,avx512bw,avx512vl,avx512dq")]
fn channel_l1(w: &[__m512; 4], at: [__m512; 4], r: f32) -> __m512 {
    let s = _mm512_add_ps(
        _mm512_add_ps(
            _mm512_add_ps(_mm512_mul_ps(w[0], at[0]), _mm512_mul_ps(w[1], at[1])),
            _mm512_mul_ps(w[2], at[2]),
        ),
        _mm512_mul_ps(w[3], at[3]),
    );
    _mm512_abs_ps(_mm512_sub_ps(_mm512_set1_ps(r), s))
}

/// [`l1_rgb16`] from the packed map: the four corners' words (one 16-byte load of the quad table
/// per lane, [`corner_quads`]; from the words themselves by one 4-byte gather per corner for a map
/// one pixel wide or high), each word split into its three byte values, converted to `f32` exactly;
/// then the same per-lane expressions.
///
/// # Safety
/// Every valid lane's corners `o + {0, dx, dy, dy + dx}` must lie inside `packed`, with `dx = 1`
/// and `dy = W` where the map has quads.
#[inline]
#[target_feature(enable = "avx512f,avx512bw,avx512vl,avx512dq")]
unsafe fn l1_rgb16_packed(packed: &PackedRgb, b: &Block, dx: i32, dy: i32, r: &[f32]) -> __m512 {
    let p = packed.as_slice().as_ptr().cast::<i32>();
    let at: [__m512i; 4] = if !packed.quads.is_empty() {
        // SAFETY: a valid lane's top-left corner `o` has a row below and a right neighbour, so it
        // indexes the quad table (the caller's contract).
        unsafe { corner_quads(&packed.quads, b.ok, b.offset) }
    } else {
        // A map one pixel wide or high: one 4-byte gather per corner.
        [0, dx, dy, dy + dx].map(|o| {
            // SAFETY: only valid lanes load, inside `packed` (the caller's contract).
            unsafe {
                _mm512_mask_i32gather_epi32::<4>(
                    _mm512_setzero_si512(),
                    b.ok,
                    _mm512_add_epi32(b.offset, _mm512_set1_epi32(o)),
                    p,
                )
            }
        })
    };
    let byte = _mm512_set1_epi32(0xff);
    let channel = |v: __m512i, ch: u32| {
        let shifted = match ch {
            0 => v,
            1 => _mm512_srli_epi32::<8>(v),
            _ => _mm512_srli_epi32::<16>(v),
        };
        _mm512_cvtepi32_ps(_mm512_and_si512(shifted, byte))
    };
    let mut d = [_mm512_setzero_ps(); 3];
    for (ch, d) in d.iter_mut().enumerate() {
        *d = channel_l1(&b.w, at.map(|a| channel(a, ch as u32)), r[ch]);
    }
    _mm512_add_ps(_mm512_add_ps(d[0], d[2]), d[1])
}

/// The four corners' words `[top-left, top-right, bottom-left, bottom-right]` of 16 lanes from the
/// quad table: one plain 16-byte load per lane (a lane outside `ok` loads entry 0 and its values
/// are never used), four lanes to a register, then regrouped into one register per corner (four
/// two-source permutes and four 128-bit shuffles). On Zen 5 sixteen loads cost about two thirds of
/// the four 8-lane, 8-byte gathers that fetched the same words before (SPEC.md §9.4).
///
/// # Safety
/// `o` must index `quads` in every lane of `ok`.
#[inline]
#[target_feature(enable = "avx512f,avx512bw,avx512vl,avx512dq")]
unsafe fn corner_quads(quads: &[[u32; 4]], ok: __mmask16, o: __m512i) -> [__m512i; 4] {
    let mut at = [0u32; BLOCK];
    // SAFETY: `at` holds 16 `u32`, 64 bytes.
    unsafe { _mm512_storeu_si512(at.as_mut_ptr().cast(), _mm512_maskz_mov_epi32(ok, o)) };
    // SAFETY: every index is a valid lane's (inside `quads`, the caller's contract) or 0 (`quads` is
    // not empty: the caller has a valid lane).
    let load = |l: usize| unsafe { _mm_loadu_si128(quads.as_ptr().add(at[l] as usize).cast()) };
    // `r[g]`: lanes `4g .. 4g + 4`, each `[TL, TR, BL, BR]`.
    let r: [__m512i; 4] = std::array::from_fn(|g| {
        let v = _mm512_castsi128_si512(load(4 * g));
        let v = _mm512_inserti32x4::<1>(v, load(4 * g + 1));
        let v = _mm512_inserti32x4::<2>(v, load(4 * g + 2));
        _mm512_inserti32x4::<3>(v, load(4 * g + 3))
    });
    // Lanes 0-7's top corners `[TL 0..8, TR 0..8]` from `r[0], r[1]`, likewise the bottom ones and
    // lanes 8-15's from `r[2], r[3]`.
    let top = _mm512_setr_epi32(0, 4, 8, 12, 16, 20, 24, 28, 1, 5, 9, 13, 17, 21, 25, 29);
    let bottom = _mm512_setr_epi32(2, 6, 10, 14, 18, 22, 26, 30, 3, 7, 11, 15, 19, 23, 27, 31);
    let (t0, b0) =
        (_mm512_permutex2var_epi32(r[0], top, r[1]), _mm512_permutex2var_epi32(r[0], bottom, r[1]));
    let (t1, b1) =
        (_mm512_permutex2var_epi32(r[2], top, r[3]), _mm512_permutex2var_epi32(r[2], bottom, r[3]));
    // Low halves (128-bit lanes 0, 1) of both: the left corner; high halves: the right one.
    const LOW: i32 = 0b01_00_01_00;
    const HIGH: i32 = 0b11_10_11_10;
    [
        _mm512_shuffle_i64x2::<LOW>(t0, t1),
        _mm512_shuffle_i64x2::<HIGH>(t0, t1),
        _mm512_shuffle_i64x2::<LOW>(b0, b1),
        _mm512_shuffle_i64x2::<HIGH>(b0, b1),
    ]
}

/// `p[o]` in the lanes of `ok`, 0 elsewhere.
///
/// # Safety
/// `p + o` must be readable in every lane of `ok`.
#[inline]
#[target_feature(enable = "avx512f,avx512bw,avx512vl,avx512dq")]
unsafe fn gather(ok: __mmask16, o: __m512i, p: *const f32) -> __m512 {
    // SAFETY: the caller's contract.
    unsafe { _mm512_mask_i32gather_ps::<4>(_mm512_setzero_ps(), ok, o, p) }
}

/// Any channel count, 16 hypotheses: per valid lane, `l1_distance`'s 16-lane channel loop and
/// pairwise fold.
///
/// # Safety
/// Every valid lane's corners `o + {0, dx, dy, dy + dx} + [0, C)` must lie inside `live`.
#[inline]
#[target_feature(enable = "avx512f,avx512bw,avx512vl,avx512dq")]
unsafe fn l1_any16(live: &[f32], b: &Block, dx: usize, dy: usize, r: &[f32]) -> __m512 {
    let mut offsets = [0i32; BLOCK];
    let mut weights = [[0.0f32; BLOCK]; 4];
    // SAFETY: plain stores of whole vectors into arrays of their size.
    unsafe {
        _mm512_storeu_si512(offsets.as_mut_ptr().cast(), b.offset);
        for (dst, src) in weights.iter_mut().zip(&b.w) {
            _mm512_storeu_ps(dst.as_mut_ptr(), *src);
        }
    }
    let mut out = [0.0f32; BLOCK];
    let mut ok = b.ok;
    while ok != 0 {
        let j = ok.trailing_zeros() as usize;
        ok &= ok - 1;
        let o = offsets[j] as usize;
        let wj = [weights[0][j], weights[1][j], weights[2][j], weights[3][j]];
        // SAFETY: the caller's contract for valid lane `j`.
        out[j] = unsafe { l1_zmm(live.as_ptr(), o, dx, dy, r, wj) };
    }
    // SAFETY: a whole-vector load of an array of its size.
    unsafe { _mm512_loadu_ps(out.as_ptr()) }
}

/// `l1_distance` of one hypothesis with `zmm` registers: lane `l` accumulates channels `l, l+16,
/// ...` (the tail chunk under a mask, the lanes past it unchanged), then the fold
/// `acc[l] += acc[l + width]` for width 8, 4, 2, 1.
///
/// # Safety
/// `p + o + {0, dx, dy, dy + dx} + [0, C)` must be readable, `C = r.len()`.
#[inline]
#[target_feature(enable = "avx512f,avx512bw,avx512vl,avx512dq")]
unsafe fn l1_zmm(p: *const f32, o: usize, dx: usize, dy: usize, r: &[f32], w: [f32; 4]) -> f32 {
    let c = r.len();
    let wv = w.map(|v| _mm512_set1_ps(v));
    let abs_mask = _mm512_set1_epi32(0x7fff_ffff);
    let mut acc = _mm512_setzero_ps();
    let mut i = 0;
    while i < c {
        let n = (c - i).min(16);
        let m: __mmask16 = if n == 16 { u16::MAX } else { (1u16 << n) - 1 };
        // SAFETY: masked loads of channels `i..i+n` of the four corners and the reference.
        let (rv, a, bb, cc, d) = unsafe {
            let q = p.add(o + i);
            (
                _mm512_maskz_loadu_ps(m, r.as_ptr().add(i)),
                _mm512_maskz_loadu_ps(m, q),
                _mm512_maskz_loadu_ps(m, q.add(dx)),
                _mm512_maskz_loadu_ps(m, q.add(dy)),
                _mm512_maskz_loadu_ps(m, q.add(dy + dx)),
            )
        };
        let s = _mm512_add_ps(
            _mm512_add_ps(
                _mm512_add_ps(_mm512_mul_ps(wv[0], a), _mm512_mul_ps(wv[1], bb)),
                _mm512_mul_ps(wv[2], cc),
            ),
            _mm512_mul_ps(wv[3], d),
        );
        let dist = _mm512_castsi512_ps(_mm512_and_si512(_mm512_castps_si512(_mm512_sub_ps(rv, s)), abs_mask));
        acc = _mm512_mask_add_ps(acc, m, acc, dist);
        i += 16;
    }
    let s8 = _mm256_add_ps(_mm512_castps512_ps256(acc), _mm512_extractf32x8_ps::<1>(acc));
    let s4 = _mm_add_ps(_mm256_castps256_ps128(s8), _mm256_extractf128_ps::<1>(s8));
    let s2 = _mm_add_ps(s4, _mm_movehl_ps(s4, s4));
    _mm_cvtss_f32(_mm_add_ss(s2, _mm_shuffle_ps::<0b01>(s2, s2)))
}

/// `N·16` channels, 16 hypotheses: per hypothesis the 16-lane partial sums of `l1_distance` (lane
/// `l` holds channels `l, l+16, ...`, added in that order), then the pairwise fold `acc[l] +=
/// acc[l + width]`, width 8, 4, 2, 1, done for the 16 hypotheses at once: each fold level adds the
/// same pairs of lanes as the one-hypothesis fold, two hypotheses' halves per instruction, so every
/// result has the bits of `l1_distance`. Invalid lanes read the map at offset 0 (in bounds) and are
/// discarded by the caller.
///
/// The fold leaves hypothesis `4q + r` in lane `4r + q`, so slot `s` is computed for hypothesis
/// `4(s mod 4) + s/4` and the result comes out in hypothesis order.
///
/// # Safety
/// Every valid lane's corners `o + {0, dx, dy, dy + dx} + [0, 16N)` must lie inside `live`, and so
/// must `{0, dx, dy, dy + dx} + [0, 16N)`.
#[inline]
#[target_feature(enable = "avx512f,avx512bw,avx512vl,avx512dq")]
unsafe fn l1_chunks16<const N: usize>(live: &[f32], b: &Block, dx: usize, dy: usize, r: &[f32]) -> __m512 {
    debug_assert_eq!(r.len(), 16 * N);
    let mut offsets = [0i32; BLOCK];
    let mut weights = [[0.0f32; BLOCK]; 4];
    let mut refs = [_mm512_setzero_ps(); N];
    // SAFETY: whole-vector stores into arrays of their size; `r` has 16N elements.
    unsafe {
        _mm512_storeu_si512(offsets.as_mut_ptr().cast(), _mm512_maskz_mov_epi32(b.ok, b.offset));
        for (dst, src) in weights.iter_mut().zip(&b.w) {
            _mm512_storeu_ps(dst.as_mut_ptr(), *src);
        }
        for (i, v) in refs.iter_mut().enumerate() {
            *v = _mm512_loadu_ps(r.as_ptr().add(16 * i));
        }
    }
    let abs_mask = _mm512_set1_epi32(0x7fff_ffff);
    let p = live.as_ptr();
    let mut acc = [_mm512_setzero_ps(); BLOCK];
    for (s, acc) in acc.iter_mut().enumerate() {
        let j = 4 * (s % 4) + s / 4;
        let o = offsets[j] as usize;
        let wv = [0, 1, 2, 3].map(|i| _mm512_set1_ps(weights[i][j]));
        for (i, rv) in refs.iter().enumerate() {
            // SAFETY: corner reads of hypothesis `j` (valid) or of offset 0 (the caller's contract).
            let (a, bb, cc, d) = unsafe {
                let q = p.add(o + 16 * i);
                (
                    _mm512_loadu_ps(q),
                    _mm512_loadu_ps(q.add(dx)),
                    _mm512_loadu_ps(q.add(dy)),
                    _mm512_loadu_ps(q.add(dy + dx)),
                )
            };
            let sum = _mm512_add_ps(
                _mm512_add_ps(
                    _mm512_add_ps(_mm512_mul_ps(wv[0], a), _mm512_mul_ps(wv[1], bb)),
                    _mm512_mul_ps(wv[2], cc),
                ),
                _mm512_mul_ps(wv[3], d),
            );
            let dist =
                _mm512_castsi512_ps(_mm512_and_si512(_mm512_castps_si512(_mm512_sub_ps(*rv, sum)), abs_mask));
            // `0 + dist` is `dist` (never -0, quiet if NaN), so the first chunk starts the sum.
            *acc = if i == 0 { dist } else { _mm512_add_ps(*acc, dist) };
        }
    }
    fold16(acc)
}

/// Width 8, 4, 2, 1 of the pairwise fold for 16 vectors at once (see [`l1_chunks16`]): lane
/// `4r + q` of the result is vector `4q + r`'s fold.
#[inline]
#[target_feature(enable = "avx512f,avx512bw,avx512vl,avx512dq")]
fn fold16(v: [__m512; BLOCK]) -> __m512 {
    // Width 8: quarters (0,1) + (2,3) of two vectors.
    let u: [__m512; 8] = std::array::from_fn(|i| {
        let (a, b) = (v[2 * i], v[2 * i + 1]);
        _mm512_add_ps(
            _mm512_shuffle_f32x4::<0b01_00_01_00>(a, b),
            _mm512_shuffle_f32x4::<0b11_10_11_10>(a, b),
        )
    });
    // Width 4: quarter 0 + quarter 1, quarter 2 + quarter 3.
    let z: [__m512; 4] = std::array::from_fn(|i| {
        let (a, b) = (u[2 * i], u[2 * i + 1]);
        _mm512_add_ps(
            _mm512_shuffle_f32x4::<0b10_00_10_00>(a, b),
            _mm512_shuffle_f32x4::<0b11_01_11_01>(a, b),
        )
    });
    // Width 2, inside each quarter: lanes (0,1) + (2,3).
    let y: [__m512; 2] = std::array::from_fn(|i| {
        let (a, b) = (z[2 * i], z[2 * i + 1]);
        _mm512_add_ps(_mm512_shuffle_ps::<0b01_00_01_00>(a, b), _mm512_shuffle_ps::<0b11_10_11_10>(a, b))
    });
    // Width 1: lane 0 + lane 1.
    _mm512_add_ps(
        _mm512_shuffle_ps::<0b10_00_10_00>(y[0], y[1]),
        _mm512_shuffle_ps::<0b11_01_11_01>(y[0], y[1]),
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::costvolume::fast::l1_distance;
    use crate::costvolume::fast::portable::tests::value;
    use proptest::prelude::*;

    fn same(a: f32, b: f32) -> bool {
        a.to_bits() == b.to_bits() || (a.is_nan() && b.is_nan())
    }

    /// Block kernels against `l1_distance` on each valid lane, special values included.
    fn check(c: usize, live: &[f32], r: &[f32], lanes: &[(usize, [f32; 4])], ok: u16, dx: usize, dy: usize) {
        if !available() {
            eprintln!("no AVX-512 F/BW/VL/DQ: block kernel not tested on this CPU");
            return;
        }
        let offsets: [i32; BLOCK] = std::array::from_fn(|j| lanes[j].0 as i32);
        let w: [[f32; BLOCK]; 4] = std::array::from_fn(|i| std::array::from_fn(|j| lanes[j].1[i]));
        let mut got = [0.0f32; BLOCK];
        // SAFETY: `available()` holds; offsets plus corners plus C lie in `live` (the strategies).
        unsafe {
            let b = Block {
                ok,
                offset: _mm512_loadu_si512(offsets.as_ptr().cast()),
                w: w.map(|v| _mm512_loadu_ps(v.as_ptr())),
            };
            let v = match c {
                3 => l1_rgb16(live, &b, dx as i32, dy as i32, r),
                32 => l1_chunks16::<2>(live, &b, dx, dy, r),
                _ => l1_any16(live, &b, dx, dy, r),
            };
            _mm512_storeu_ps(got.as_mut_ptr(), v);
        }
        for (j, &(o, wj)) in lanes.iter().enumerate() {
            if ok >> j & 1 == 0 {
                continue;
            }
            let want = l1_distance(
                r,
                &live[o..o + c],
                &live[o + dx..o + dx + c],
                &live[o + dy..o + dy + c],
                &live[o + dy + dx..o + dy + dx + c],
                wj,
            );
            assert!(same(got[j], want), "C = {c}, lane {j}: {} vs {want}", got[j]);
        }
    }

    proptest! {
        #![proptest_config(ProptestConfig { cases: 64, ..ProptestConfig::default() })]
        /// Each block kernel gives `l1_distance`'s bits on every valid lane (NaN: any NaN).
        #[test]
        fn block_kernels_equal_l1_distance(
            c in prop::sample::select(vec![3usize, 32, 35]),
            seed in prop::collection::vec(value(), 4 * 35 * 4),
            r in prop::collection::vec(value(), 35),
            lanes in prop::collection::vec((0usize..4, prop::array::uniform4(0.0f32..1.0)), BLOCK),
            ok: u16,
        ) {
            // A 4x4-pixel map of C channels; corners (x0, y0) in 0..3 so the 2x2 stencil fits.
            let (w, h) = (4, 4);
            let live: Vec<f32> = (0..w * h * c).map(|i| seed[i % seed.len()]).collect();
            let (dx, dy) = (c, w * c);
            let lanes: Vec<(usize, [f32; 4])> =
                lanes.iter().enumerate().map(|(j, &(x, wt))| (((j % 3) * w + x.min(2)) * c, wt)).collect();
            check(c, &live, &r[..c], &lanes, ok, dx, dy);
        }

        /// The packed-byte RGB kernel gives `l1_distance`'s bits on every valid lane, and packing
        /// accepts exactly the maps whose every value is an integer `0..=255`.
        #[test]
        fn packed_rgb_kernel_equals_l1_distance(
            live in prop::collection::vec(0u8..=255, 4 * 4 * 3),
            r in prop::collection::vec(value(), 3),
            lanes in prop::collection::vec((0usize..4, prop::array::uniform4(0.0f32..1.0)), BLOCK),
            ok: u16,
            spoil in prop::sample::select(vec![None, Some(-0.0f32), Some(0.5), Some(256.0), Some(f32::NAN)]),
        ) {
            if !available() {
                eprintln!("no AVX-512 F/BW/VL/DQ: packed kernel not tested on this CPU");
                return Ok(());
            }
            let (w, c) = (4, 3);
            let mut live: Vec<f32> = live.into_iter().map(f32::from).collect();
            let packed = PackedRgb::new(&live, c, w).expect("byte values pack");
            prop_assert!(!packed.quads.is_empty(), "a 4x4 map has quads");
            prop_assert!(PackedRgb::new(&live, 4, w).is_none(), "only three channels pack");
            // The same words without quads: the 4-byte gathers of a map one pixel wide or high.
            let pairs = PackedRgb { words: packed.words.clone(), quads: Vec::new() };
            let lanes: Vec<(usize, [f32; 4])> =
                lanes.iter().enumerate().map(|(j, &(x, wt))| ((j % 3) * w + x.min(2), wt)).collect();
            let (mut got, mut got_pairs) = ([0.0f32; BLOCK], [0.0f32; BLOCK]);
            // SAFETY: `available()` holds; every corner lies in the 4x4 map.
            unsafe {
                let offsets: [i32; BLOCK] = std::array::from_fn(|j| lanes[j].0 as i32);
                let b = Block {
                    ok,
                    offset: _mm512_loadu_si512(offsets.as_ptr().cast()),
                    w: std::array::from_fn(|i| {
                        let v: [f32; BLOCK] = std::array::from_fn(|j| lanes[j].1[i]);
                        _mm512_loadu_ps(v.as_ptr())
                    }),
                };
                _mm512_storeu_ps(got.as_mut_ptr(), l1_rgb16_packed(&packed, &b, 1, w as i32, &r));
                _mm512_storeu_ps(got_pairs.as_mut_ptr(), l1_rgb16_packed(&pairs, &b, 1, w as i32, &r));
            }
            for (j, &(o, wj)) in lanes.iter().enumerate() {
                if ok >> j & 1 == 0 {
                    continue;
                }
                let at = |p: usize| &live[p * c..p * c + c];
                let want = l1_distance(&r, at(o), at(o + 1), at(o + w), at(o + w + 1), wj);
                prop_assert!(same(got[j], want), "lane {}: {} vs {}", j, got[j], want);
                prop_assert!(same(got_pairs[j], want), "lane {} (pairs): {} vs {}", j, got_pairs[j], want);
            }
            if let Some(v) = spoil {
                live[7] = v;
                prop_assert!(PackedRgb::new(&live, c, w).is_none(), "{} must not pack", v);
            }
        }
    }
}
