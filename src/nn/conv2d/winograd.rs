//! Winograd F(2x2, 3x3) convolution for stride-1 layers (SPEC.md §7.11,
//! [`Conv2dImpl::Winograd`](super::Conv2dImpl::Winograd)).
//!
//! The output is cut into 2x2 tiles anchored at the origin; tile `(ty, tx)` covers output rows
//! `2 ty, 2 ty + 1` and columns `2 tx, 2 tx + 1` and reads the 4x4 input window `d` of rows
//! `2 ty - 1 ..= 2 ty + 2` and columns `2 tx - 1 ..= 2 tx + 2` (zero outside the image). Per tile
//! and channel, per output channel:
//!
//! ```text
//! V = Bᵀ d B   (input transform: additions only)        Bᵀ = [1  0 -1  0]   G = [ 1    0    0 ]
//! U = G g Gᵀ   (weights, once per layer, f64 -> f32)         [0  1  1  0]       [1/2  1/2  1/2]
//! M = Σ_c V_c ⊙ U_c  (16 dot products over c_in: FMA)         [0 -1  1  0]       [1/2 -1/2 1/2]
//! Y = Aᵀ M A   (output transform), out = act(Y + b)           [0  1  0 -1]       [ 0    0    1 ]
//!                                                       Aᵀ = [1  1  1  0]
//!                                                            [0  1 -1 -1]
//! ```
//!
//! 16 multiplications per tile and channel pair instead of 36: 2.25x fewer than the direct
//! convolution. Every addition is done in the order written in SPEC.md §7.11 (rows of the tile
//! first, then columns), the dot products are FMA chains over `c = 0 .. c_in` starting from zero,
//! and the bias is added last, so the bits depend only on the geometry: the AVX-512F kernel
//! ([`WinogradKernel::Avx512F`]), the AVX2+FMA one ([`WinogradKernel::Avx2Fma`]) and the portable
//! one ([`WinogradKernel::Portable`], `f32::mul_add`) give the same bits, for any thread count. The error is bounded against the magnitude
//! [`winograd_magnitude_reference`] (the same algorithm on absolute values), not §7.5's `M`.
//!
//! Work units are tile rows (two output rows); within one, tiles run in groups of [`TILES`].

use std::sync::Arc;

use ndarray::{Array3, ArrayView1, ArrayView3, ArrayView4};
use rayon::prelude::*;

use crate::error::{Error, Result};
use crate::nn::geometry::Conv2dGeometry;
use crate::nn::{expect_len, expect_shape, Activation};

/// Winograd points per tile (the 4x4 transformed window).
pub const POINTS: usize = 16;

/// Tiles per group: the AVX-512 GEMM holds `TILES` tiles x 32 output channels in 28 zmm
/// accumulators (the direct kernel's register blocking).
pub const TILES: usize = 14;

/// Output channels of the AVX-512 kernel.
pub const AVX512_C_OUT: usize = 32;

/// `G` of F(2, 3) (`U = G g Gᵀ`).
const G: [[f64; 3]; 4] = [[1.0, 0.0, 0.0], [0.5, 0.5, 0.5], [0.5, -0.5, 0.5], [0.0, 0.0, 1.0]];
/// `Bᵀ` of F(2, 3) (`V = Bᵀ d B`).
const BT: [[f64; 4]; 4] =
    [[1.0, 0.0, -1.0, 0.0], [0.0, 1.0, 1.0, 0.0], [0.0, -1.0, 1.0, 0.0], [0.0, 1.0, 0.0, -1.0]];
/// `Aᵀ` of F(2, 3) (`Y = Aᵀ M A`).
const AT: [[f64; 4]; 2] = [[1.0, 1.0, 1.0, 0.0], [0.0, 1.0, -1.0, -1.0]];

/// Weights transformed for F(2x2, 3x3): `U[ξ][c][o]` (`ξ = 4 i + j`, `o` contiguous), computed in
/// f64 and rounded once to f32, and the bias. Pack once per layer; clones share the values.
#[derive(Clone, Debug)]
pub struct PackedWinograd {
    geom: Conv2dGeometry,
    u: Arc<[f32]>,
    bias: Arc<[f32]>,
}

impl PackedWinograd {
    /// Transforms PyTorch-layout weights `[c_out, c_in, 3, 3]` and keeps the bias `[c_out]`:
    /// `U = G g Gᵀ` per `(o, c)`, each entry a fixed-order f64 sum `Σ_ky G[i][ky] Σ_kx g[ky][kx]
    /// G[j][kx]` rounded to f32.
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] if a shape disagrees with `geom` or its stride is not 1.
    pub fn new(geom: &Conv2dGeometry, weight: ArrayView4<f32>, bias: ArrayView1<f32>) -> Result<Self> {
        check_geometry(geom)?;
        expect_shape("conv2d weight", weight.shape(), &geom.weight_shape())?;
        expect_shape("conv2d bias", bias.shape(), &[geom.c_out()])?;
        let (c_in, c_out) = (geom.c_in(), geom.c_out());
        let mut u = vec![0.0f32; POINTS * c_in * c_out];
        for o in 0..c_out {
            for c in 0..c_in {
                let g = |ky: usize, kx: usize| f64::from(weight[[o, c, ky, kx]]);
                for (xi, t) in transform_weights(g).iter().enumerate() {
                    u[(xi * c_in + c) * c_out + o] = *t as f32;
                }
            }
        }
        Ok(PackedWinograd { geom: *geom, u: u.into(), bias: bias.to_vec().into() })
    }

    /// The same transformed weights for another stride-1 geometry with the same channel counts.
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] if `geom`'s channel counts differ or its stride is not 1.
    pub fn with_geometry(&self, geom: &Conv2dGeometry) -> Result<Self> {
        check_geometry(geom)?;
        expect_shape("conv2d weight", &self.geom.weight_shape(), &geom.weight_shape())?;
        Ok(PackedWinograd { geom: *geom, ..self.clone() })
    }

    /// The geometry the weights were packed for.
    pub fn geometry(&self) -> &Conv2dGeometry {
        &self.geom
    }

    /// `U[ξ][c][o]`, `POINTS · c_in · c_out` floats.
    pub fn transformed(&self) -> &[f32] {
        &self.u
    }

    /// The bias `[c_out]`.
    pub fn bias(&self) -> &[f32] {
        &self.bias
    }
}

/// `G g Gᵀ` of one 3x3 kernel `g(ky, kx)`, row-major over `ξ = 4 i + j`, in f64 (the rows of the
/// kernel first: `h[ky][j] = Σ_kx g[ky][kx] G[j][kx]`, then `Σ_ky G[i][ky] h[ky][j]`, terms in index
/// order).
fn transform_weights(g: impl Fn(usize, usize) -> f64) -> [f64; POINTS] {
    let mut h = [[0.0f64; 4]; 3];
    for (ky, row) in h.iter_mut().enumerate() {
        for (j, v) in row.iter_mut().enumerate() {
            *v = (0..3).fold(0.0, |s, kx| s + g(ky, kx) * G[j][kx]);
        }
    }
    let mut u = [0.0f64; POINTS];
    for i in 0..4 {
        for j in 0..4 {
            u[4 * i + j] = (0..3).fold(0.0, |s, ky| s + G[i][ky] * h[ky][j]);
        }
    }
    u
}

/// `Ok` for a stride-1 geometry.
fn check_geometry(geom: &Conv2dGeometry) -> Result<()> {
    if geom.stride() != 1 {
        return Err(Error::invalid_argument(
            "conv2d Winograd stride",
            format!("{}: F(2x2, 3x3) is for stride-1 layers only", geom.stride()),
        ));
    }
    Ok(())
}

/// A kernel of [`Conv2dImpl::Winograd`](super::Conv2dImpl::Winograd).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum WinogradKernel {
    /// x86-64 AVX-512F: groups of [`TILES`] tiles x 32 output channels, channel-vectorised
    /// transforms. Only for `c_out = 32` on a CPU with AVX-512F (detected at run time).
    Avx512F,
    /// x86-64 AVX2 + FMA (CPUs without AVX-512): blocks of 6 tiles x 16 output channels, run once
    /// per channel half; transforms 8 channels per ymm. Only for `c_out = 32` and `c_in` a
    /// multiple of 8. The same bits as [`WinogradKernel::Avx512F`].
    Avx2Fma,
    /// Plain Rust, any `c_out`, every target; the dot products use `f32::mul_add` (a fused
    /// multiply-add everywhere), so it gives [`WinogradKernel::Avx512F`]'s bits.
    Portable,
}

impl WinogradKernel {
    /// Every kernel, for tests.
    pub const ALL: [WinogradKernel; 3] =
        [WinogradKernel::Avx512F, WinogradKernel::Avx2Fma, WinogradKernel::Portable];

    /// The kernel [`conv2d_winograd`] runs for `geom` on this CPU: the first of AVX-512F,
    /// AVX2+FMA and portable that supports it.
    pub fn select(geom: &Conv2dGeometry) -> WinogradKernel {
        WinogradKernel::ALL.into_iter().find(|k| k.supports(geom)).unwrap_or(WinogradKernel::Portable)
    }

    /// Whether this kernel can run `geom` (stride 1) on this CPU.
    pub fn supports(self, geom: &Conv2dGeometry) -> bool {
        geom.stride() == 1
            && match self {
                WinogradKernel::Avx512F => {
                    cfg!(target_arch = "x86_64")
                        && geom.c_out() == AVX512_C_OUT
                        && crate::runtime::has_avx512f()
                }
                WinogradKernel::Avx2Fma => {
                    cfg!(target_arch = "x86_64")
                        && geom.c_out() == AVX512_C_OUT
                        && geom.c_in().is_multiple_of(8)
                        && crate::runtime::has_avx2_fma()
                }
                WinogradKernel::Portable => true,
            }
    }

    /// A short name, for logs and tests.
    pub fn name(self) -> &'static str {
        match self {
            WinogradKernel::Avx512F => "winograd-f2x2-avx512f-14x32",
            WinogradKernel::Avx2Fma => "winograd-f2x2-avx2-6x16",
            WinogradKernel::Portable => "winograd-f2x2-portable",
        }
    }
}

/// Scratch of one work unit (one per rayon job): `V[ξ][t][c]` and `M[ξ][t][o]` for a group of
/// tiles, and a row of zeros standing for the rows above and below the image, each 64-byte
/// aligned (a vector store or load then touches one cache line).
pub(super) struct Scratch {
    buf: Vec<f32>,
    /// Offsets of V, M and the zero row in `buf`, and their lengths.
    at: [usize; 3],
    len: [usize; 3],
}

impl Scratch {
    /// Scratch for a `w`-wide map with `c_in` input and `c_out` output channels.
    fn new(w: usize, c_in: usize, c_out: usize) -> Self {
        const ALIGN: usize = 16; // floats per 64 bytes
        let len = [POINTS * TILES * c_in, POINTS * TILES * c_out, w * c_in];
        let buf = vec![0.0f32; len.iter().map(|l| l.next_multiple_of(ALIGN)).sum::<usize>() + ALIGN];
        let first = buf.as_ptr().align_offset(64).min(ALIGN);
        let at1 = first + len[0].next_multiple_of(ALIGN);
        let at = [first, at1, at1 + len[1].next_multiple_of(ALIGN)];
        Scratch { buf, at, len }
    }

    /// `(V, M, zeros)`.
    pub(super) fn parts(&mut self) -> (&mut [f32], &mut [f32], &[f32]) {
        let (head, zeros) = self.buf.split_at_mut(self.at[2]);
        let (head, m) = head.split_at_mut(self.at[1]);
        let v = &mut head[self.at[0]..self.at[0] + self.len[0]];
        (v, &mut m[..self.len[1]], &zeros[..self.len[2]])
    }
}

/// Winograd convolution of a channels-last input slice `[h, w, c_in]` into `out` (`[h, w, c_out]`,
/// fully overwritten) with the best kernel for this CPU, parallel over tile rows. Returns the
/// kernel that ran.
///
/// # Errors
/// [`Error::InvalidArgument`] if a slice has the wrong length.
pub fn conv2d_winograd(
    packed: &PackedWinograd,
    input: &[f32],
    activation: Activation,
    out: &mut [f32],
) -> Result<WinogradKernel> {
    let kernel = WinogradKernel::select(packed.geometry());
    conv2d_winograd_with(kernel, packed, input, activation, out)?;
    Ok(kernel)
}

/// [`conv2d_winograd`] with a chosen kernel.
///
/// # Errors
/// [`Error::InvalidArgument`] if a slice has the wrong length or `kernel` cannot run this geometry
/// on this CPU ([`WinogradKernel::supports`]).
pub fn conv2d_winograd_with(
    kernel: WinogradKernel,
    packed: &PackedWinograd,
    input: &[f32],
    activation: Activation,
    out: &mut [f32],
) -> Result<()> {
    let geom = packed.geometry();
    let [h, w, c_in] = geom.input_shape();
    let c_out = geom.c_out();
    expect_len("conv2d input", input.len(), h * w * c_in)?;
    expect_len("conv2d output", out.len(), h * w * c_out)?;
    if !kernel.supports(geom) {
        return Err(Error::invalid_argument(
            "conv2d Winograd kernel",
            format!("{} cannot run c_out = {} on this CPU", kernel.name(), c_out),
        ));
    }
    let tile_row_len = 2 * w * c_out;
    let tiles = w.div_ceil(2);
    let init = || Scratch::new(w, c_in, c_out);
    out.par_chunks_mut(tile_row_len).enumerate().for_each_init(init, |scratch, (ty, rows)| {
        for tx0 in (0..tiles).step_by(TILES) {
            let group = Group { ty, tx0, n: TILES.min(tiles - tx0) };
            match kernel {
                #[cfg(target_arch = "x86_64")]
                // SAFETY: `supports` found AVX-512F and c_out = 32; the slice lengths were checked
                // against the geometry; `rows` holds output rows 2 ty .. (one or two of them).
                WinogradKernel::Avx512F => unsafe {
                    super::winograd_avx512::group(packed, input, group, activation, scratch, rows);
                },
                #[cfg(target_arch = "x86_64")]
                // SAFETY: `supports` found AVX2, FMA, c_out = 32 and c_in a multiple of 8; lengths
                // and rows as above.
                WinogradKernel::Avx2Fma => unsafe {
                    super::winograd_avx2::group(packed, input, group, activation, scratch, rows);
                },
                _ => group_portable(packed, input, group, activation, scratch, rows),
            }
        }
    });
    Ok(())
}

/// A group of tiles of one tile row: tiles `tx0 .. tx0 + n` of tile row `ty`.
#[derive(Clone, Copy, Debug)]
pub(super) struct Group {
    pub(super) ty: usize,
    pub(super) tx0: usize,
    pub(super) n: usize,
}

/// The portable kernel on one group: the three stages in plain Rust.
fn group_portable(
    packed: &PackedWinograd,
    input: &[f32],
    g: Group,
    activation: Activation,
    scratch: &mut Scratch,
    rows: &mut [f32],
) {
    let geom = packed.geometry();
    let (h, w, c_in, c_out) = (geom.h(), geom.w(), geom.c_in(), geom.c_out());
    let (v, m, _) = scratch.parts();
    // Input transform, per tile and channel.
    for t in 0..g.n {
        let tx = g.tx0 + t;
        for c in 0..c_in {
            let d = |r: usize, j: usize| {
                let (iy, ix) = ((2 * g.ty + r).wrapping_sub(1), (2 * tx + j).wrapping_sub(1));
                if iy < h && ix < w {
                    input[(iy * w + ix) * c_in + c]
                } else {
                    0.0
                }
            };
            let tile = input_transform(std::array::from_fn(|k| d(k / 4, k % 4)));
            for (xi, val) in tile.iter().enumerate() {
                v[(xi * g.n + t) * c_in + c] = *val;
            }
        }
    }
    // Dot products over channels (FMA chains from zero).
    let u = packed.transformed();
    for xi in 0..POINTS {
        for t in 0..g.n {
            for o in 0..c_out {
                let mut acc = 0.0f32;
                for c in 0..c_in {
                    acc = v[(xi * g.n + t) * c_in + c].mul_add(u[(xi * c_in + c) * c_out + o], acc);
                }
                m[(xi * g.n + t) * c_out + o] = acc;
            }
        }
    }
    // Output transform, bias, activation.
    let bias = packed.bias();
    for t in 0..g.n {
        let tx = g.tx0 + t;
        for o in 0..c_out {
            let y = output_transform(std::array::from_fn(|xi| m[(xi * g.n + t) * c_out + o]));
            for (r, y_row) in y.iter().enumerate() {
                for (j, val) in y_row.iter().enumerate() {
                    let (oy, ox) = (2 * g.ty + r, 2 * tx + j);
                    if oy < h && ox < w {
                        rows[(r * w + ox) * c_out + o] = relu_like_maxps(activation, *val + bias[o]);
                    }
                }
            }
        }
    }
}

/// The activation as AVX-512's `max(v, +0)` computes it: `v` if `v > 0`, else `+0` (so also for
/// `-0` and NaN), which the AVX-512 kernel's bits follow.
fn relu_like_maxps(activation: Activation, v: f32) -> f32 {
    match activation {
        Activation::Relu if v > 0.0 => v,
        Activation::Relu => 0.0,
        Activation::None => v,
    }
}

/// `Bᵀ d B` of one 4x4 window (row-major), rows first, in SPEC.md §7.11's order.
pub(super) fn input_transform(d: [f32; POINTS]) -> [f32; POINTS] {
    let mut e = [0.0f32; POINTS];
    for r in 0..4 {
        let x = &d[4 * r..4 * r + 4];
        e[4 * r] = x[0] - x[2];
        e[4 * r + 1] = x[1] + x[2];
        e[4 * r + 2] = x[2] - x[1];
        e[4 * r + 3] = x[1] - x[3];
    }
    let mut v = [0.0f32; POINTS];
    for j in 0..4 {
        v[j] = e[j] - e[8 + j];
        v[4 + j] = e[4 + j] + e[8 + j];
        v[8 + j] = e[8 + j] - e[4 + j];
        v[12 + j] = e[4 + j] - e[12 + j];
    }
    v
}

/// `Aᵀ M A` of one tile's 16 dot products (row-major), rows first, in SPEC.md §7.11's order.
pub(super) fn output_transform(m: [f32; POINTS]) -> [[f32; 2]; 2] {
    let mut s = [[0.0f32; 2]; 4];
    for (i, row) in s.iter_mut().enumerate() {
        let x = &m[4 * i..4 * i + 4];
        *row = [(x[0] + x[1]) + x[2], (x[1] - x[2]) - x[3]];
    }
    let mut y = [[0.0f32; 2]; 2];
    for j in 0..2 {
        y[0][j] = (s[0][j] + s[1][j]) + s[2][j];
        y[1][j] = (s[1][j] - s[2][j]) - s[3][j];
    }
    y
}

/// The magnitude that bounds the Winograd kernels' error (SPEC.md §7.11): the same algorithm with
/// every transform entry, weight, bias and input replaced by its absolute value, in f64, plain
/// loops: `M_W[y, x, o] = |b_o| + Σ_c Σ_ξ |Aᵀ|⊗|Aᵀ| [(|G| |g_oc| |Gᵀ|) ⊙ (|Bᵀ| |d_c| |B|)]`.
/// It is at least §7.5's `M = Σ |x| |w| + |b|` (each product of the convolution appears in it with
/// a coefficient of at least one).
///
/// # Errors
/// [`Error::InvalidArgument`] if a shape disagrees with `geom` or the stride is not 1.
pub fn winograd_magnitude_reference(
    geom: &Conv2dGeometry,
    input: ArrayView3<f64>,
    weight: ArrayView4<f64>,
    bias: ArrayView1<f64>,
) -> Result<Array3<f64>> {
    check_geometry(geom)?;
    expect_shape("conv2d input", input.shape(), &geom.input_shape())?;
    expect_shape("conv2d weight", weight.shape(), &geom.weight_shape())?;
    expect_shape("conv2d bias", bias.shape(), &[geom.c_out()])?;
    let (h, w, c_in, c_out) = (geom.h(), geom.w(), geom.c_in(), geom.c_out());
    let abs_g: [[f64; 3]; 4] = G.map(|r| r.map(f64::abs));
    let abs_bt: [[f64; 4]; 4] = BT.map(|r| r.map(f64::abs));
    let abs_at: [[f64; 4]; 2] = AT.map(|r| r.map(f64::abs));
    let mut out = Array3::<f64>::zeros(geom.output_shape());
    for ty in 0..h.div_ceil(2) {
        for tx in 0..w.div_ceil(2) {
            for o in 0..c_out {
                let mut m = [0.0f64; POINTS];
                for c in 0..c_in {
                    let d = |r: usize, j: usize| {
                        let (iy, ix) = ((2 * ty + r).wrapping_sub(1), (2 * tx + j).wrapping_sub(1));
                        if iy < h && ix < w {
                            input[[iy, ix, c]].abs()
                        } else {
                            0.0
                        }
                    };
                    for i in 0..4 {
                        for j in 0..4 {
                            let mut vv = 0.0;
                            let mut uu = 0.0;
                            for a in 0..4 {
                                for b in 0..4 {
                                    vv += abs_bt[i][a] * d(a, b) * abs_bt[j][b];
                                }
                            }
                            for ky in 0..3 {
                                for kx in 0..3 {
                                    uu += abs_g[i][ky] * weight[[o, c, ky, kx]].abs() * abs_g[j][kx];
                                }
                            }
                            m[4 * i + j] += uu * vv;
                        }
                    }
                }
                for r in 0..2 {
                    for j in 0..2 {
                        let (oy, ox) = (2 * ty + r, 2 * tx + j);
                        if oy < h && ox < w {
                            let mut y = bias[o].abs();
                            for a in 0..4 {
                                for b in 0..4 {
                                    y += abs_at[r][a] * m[4 * a + b] * abs_at[j][b];
                                }
                            }
                            out[[oy, ox, o]] = y;
                        }
                    }
                }
            }
        }
    }
    Ok(out)
}

/// Relative budget of the Winograd kernels against [`winograd_magnitude_reference`] (SPEC.md
/// §7.11): `|fast - ref| <= 2 (c_in + 10) ε_f32 · M_W`.
pub fn winograd_budget(c_in: usize) -> f32 {
    2.0 * (c_in + 10) as f32 * f32::EPSILON
}
