//! Winograd convolution for stride-1 layers, F(2x2, 3x3) and F(4x4, 3x3) (SPEC.md §7.11,
//! [`Conv2dImpl::WinogradF2`](super::Conv2dImpl::WinogradF2),
//! [`Conv2dImpl::WinogradF4`](super::Conv2dImpl::WinogradF4)).
//!
//! The output is cut into `m x m` tiles anchored at the origin (`m` = 2 or 4); tile `(ty, tx)`
//! covers output rows `m ty .. m ty + m` and columns `m tx .. m tx + m` and reads the `r x r`
//! input window `d` (`r = m + 2`) of rows `m ty - 1 ..` and columns `m tx - 1 ..` (zero outside
//! the image). Per tile and channel, per output channel:
//!
//! ```text
//! V = Bᵀ d B          input transform                          (r x r)
//! U = G g Gᵀ          weights, once per layer, f64 -> f32      (r x r)
//! M = Σ_c V_c ⊙ U_c   r² dot products over c_in: FMA chains    (r x r)
//! Y = Aᵀ M A          output transform, out = act(Y + b)       (m x m)
//! ```
//!
//! (matrices in `tiles`). F(2x2, 3x3) multiplies 2.25x less than the direct convolution, F(4x4,
//! 3x3) 4x less. Every transform row is evaluated by one rule (`tiles::fold`: nonzero
//! coefficients in index order, the first a product, the rest FMAs; rows of the tile first, then
//! columns), the dot products are FMA chains over `c = 0 .. c_in` starting from zero, and the bias
//! is added last, so the bits depend only on the geometry: the AVX-512F kernel
//! ([`WinogradKernel::Avx512F`]), the AVX2+FMA one ([`WinogradKernel::Avx2Fma`]) and the portable
//! one ([`WinogradKernel::Portable`], `f32::mul_add`) give the same bits, for any thread count. The
//! error is bounded against the magnitude [`winograd_magnitude_reference`] (the same algorithm on
//! absolute values), not §7.5's `M`.
//!
//! Work units are tile rows (`m` output rows); within one, tiles run in groups of [`TILES`], and
//! the SIMD kernels run the dot products and the output transform once per 32 output channels.
//!
//! **Transposed convolutions** (SPEC.md §7.3) run here too: the 5x5 stride-2 transposed
//! convolution is one stride-1 3x3 convolution of its input with `4 c_out` outputs (one block of
//! `c_out` per output parity, [`OutputLayout::Deconv`]), whose value `(y, x, (2 q_y + q_x) c_out + o)`
//! is stored at output pixel `(2y + q_y, 2x + q_x)`, channel `o` (`crate::ops::deconv2d::winograd`).

#[cfg(target_arch = "x86_64")]
mod avx2;
#[cfg(target_arch = "x86_64")]
mod avx512;
mod magnitude;
mod portable;
#[cfg(target_arch = "x86_64")]
mod simd;
pub(crate) mod tiles;

use std::sync::Arc;

use ndarray::{ArrayView1, ArrayView4};
use rayon::prelude::*;

pub use magnitude::{winograd_budget, winograd_magnitude_reference};
use tiles::{transform_weights, Tile, F2, F4};

use crate::error::{Error, Result};
use crate::ops::geometry::Conv2dGeometry;
use crate::ops::{expect_len, expect_shape, Activation};
use crate::runtime::CpuFeatureLevel;

/// Tiles per group: the AVX-512 dot products hold `TILES` tiles x 32 output channels in 28 zmm
/// accumulators (the direct kernel's register blocking).
pub const TILES: usize = 14;

/// Output channels per pass of the SIMD kernels' dot products and output transform; they run
/// `c_out` a multiple of it.
pub const SIMD_C_OUT: usize = 32;

/// Where output value `(y, x, o)` of the (3x3, stride-1) convolution goes.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum OutputLayout {
    /// `[h, w, c_out]`, value `(y, x, o)` at `(y, x, o)`: a convolution.
    Conv,
    /// `[2h, 2w, c_out / 4]`, value `(y, x, p c + o)` (`c = c_out / 4`, parity `p = 2 q_y + q_x`) at
    /// `(2y + q_y, 2x + q_x, o)`: a transposed convolution as four parity convolutions.
    Deconv,
}

impl OutputLayout {
    /// Offset of value `(r, x, o)` in the output rows of a tile row (`r` the row within it, `w`
    /// the input width, `c_out` the convolution's output channels).
    #[inline(always)]
    pub(crate) fn offset(self, w: usize, c_out: usize, r: usize, x: usize, o: usize) -> usize {
        match self {
            OutputLayout::Conv => (r * w + x) * c_out + o,
            OutputLayout::Deconv => {
                let c = c_out / 4;
                let (p, o) = (o / c, o % c);
                ((2 * r + p / 2) * 2 * w + 2 * x + p % 2) * c + o
            }
        }
    }

    /// Whether `lanes`-wide channel vectors never straddle a parity block, so that the SIMD
    /// kernels can store them whole.
    fn fits_lanes(self, c_out: usize, lanes: usize) -> bool {
        match self {
            OutputLayout::Conv => true,
            OutputLayout::Deconv => (c_out / 4).is_multiple_of(lanes),
        }
    }
}

/// Which Winograd variant: the output tile's side.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum WinogradTile {
    /// F(2x2, 3x3): 4x4 windows, 16 points, 2.25x fewer multiplications than direct.
    F2x2,
    /// F(4x4, 3x3): 6x6 windows, 36 points, 4x fewer multiplications; larger transform
    /// coefficients, so a larger error budget.
    F4x4,
}

impl WinogradTile {
    /// Output tile side `m`.
    pub fn m(self) -> usize {
        match self {
            WinogradTile::F2x2 => F2::M,
            WinogradTile::F4x4 => F4::M,
        }
    }

    /// Points per tile, `(m + 2)²`.
    pub fn points(self) -> usize {
        match self {
            WinogradTile::F2x2 => F2::P,
            WinogradTile::F4x4 => F4::P,
        }
    }

    /// `"f2x2"` or `"f4x4"`.
    pub fn name(self) -> &'static str {
        match self {
            WinogradTile::F2x2 => "f2x2",
            WinogradTile::F4x4 => "f4x4",
        }
    }
}

/// Weights transformed for one variant: `U[ξ][c][o]` (`ξ = r i + j`, `o` contiguous), computed in
/// f64 and rounded once to f32, and the bias. Pack once per layer; clones share the values.
#[derive(Clone, Debug)]
pub struct PackedWinograd {
    tile: WinogradTile,
    geom: Conv2dGeometry,
    u: Arc<[f32]>,
    bias: Arc<[f32]>,
    layout: OutputLayout,
}

impl PackedWinograd {
    /// Transforms PyTorch-layout weights `[c_out, c_in, 3, 3]` for `tile` and keeps the bias
    /// `[c_out]`: `U = G g Gᵀ` per `(o, c)` (`tiles::transform_weights`), rounded to f32.
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] if a shape disagrees with `geom` or its stride is not 1.
    pub fn new(
        tile: WinogradTile,
        geom: &Conv2dGeometry,
        weight: ArrayView4<f32>,
        bias: ArrayView1<f32>,
    ) -> Result<Self> {
        check_geometry(geom)?;
        expect_shape("conv2d weight", weight.shape(), &geom.weight_shape())?;
        expect_shape("conv2d bias", bias.shape(), &[geom.c_out()])?;
        let (c_in, c_out, points) = (geom.c_in(), geom.c_out(), tile.points());
        let mut u = vec![0.0f32; points * c_in * c_out];
        for o in 0..c_out {
            for c in 0..c_in {
                let g = |ky: usize, kx: usize| f64::from(weight[[o, c, ky, kx]]);
                let t = match tile {
                    WinogradTile::F2x2 => transform_weights::<F2>(g),
                    WinogradTile::F4x4 => transform_weights::<F4>(g),
                };
                for (xi, v) in t.iter().take(points).enumerate() {
                    u[(xi * c_in + c) * c_out + o] = *v as f32;
                }
            }
        }
        Ok(PackedWinograd {
            tile,
            geom: *geom,
            u: u.into(),
            bias: bias.to_vec().into(),
            layout: OutputLayout::Conv,
        })
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

    /// The same weights with their outputs stored by `layout` (`c_out` a multiple of 4 for
    /// [`OutputLayout::Deconv`], which `crate::ops::deconv2d::winograd` checks).
    pub(crate) fn with_layout(self, layout: OutputLayout) -> Self {
        PackedWinograd { layout, ..self }
    }

    /// Where the outputs go.
    pub fn layout(&self) -> OutputLayout {
        self.layout
    }

    /// The variant.
    pub fn tile(&self) -> WinogradTile {
        self.tile
    }

    /// The geometry the weights were packed for.
    pub fn geometry(&self) -> &Conv2dGeometry {
        &self.geom
    }

    /// `U[ξ][c][o]`, `points · c_in · c_out` floats.
    pub fn transformed(&self) -> &[f32] {
        &self.u
    }

    /// The bias `[c_out]`.
    pub fn bias(&self) -> &[f32] {
        &self.bias
    }
}

/// `Ok` for a stride-1 geometry.
fn check_geometry(geom: &Conv2dGeometry) -> Result<()> {
    if geom.stride() != 1 {
        return Err(Error::invalid_argument(
            "conv2d Winograd stride",
            format!("{}: Winograd F(m x m, 3x3) is for stride-1 layers only", geom.stride()),
        ));
    }
    Ok(())
}

/// A kernel of the Winograd convolutions.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum WinogradKernel {
    /// x86-64 AVX-512F: groups of [`TILES`] tiles x 32 output channels, channel-vectorised
    /// transforms, per 32 output channels. Only for `c_out` a multiple of 32 on a CPU with AVX-512F
    /// (detected at run time).
    Avx512F,
    /// x86-64 AVX2 + FMA (CPUs without AVX-512): blocks of 6 tiles x 16 output channels, run once
    /// per channel half; transforms 8 channels per ymm. Only for `c_out` a multiple of 32 and `c_in` a
    /// multiple of 8. The same bits as [`WinogradKernel::Avx512F`].
    Avx2Fma,
    /// Plain Rust, any `c_out`, every target; FMAs by `f32::mul_add` (fused everywhere), so it
    /// gives [`WinogradKernel::Avx512F`]'s bits.
    Portable,
}

impl WinogradKernel {
    /// Every kernel, for tests.
    pub const ALL: [WinogradKernel; 3] =
        [WinogradKernel::Avx512F, WinogradKernel::Avx2Fma, WinogradKernel::Portable];

    /// The kernel [`conv2d_winograd`] runs for `geom` on this CPU: the first of AVX-512F,
    /// AVX2+FMA and portable that supports it.
    pub fn select(geom: &Conv2dGeometry) -> WinogradKernel {
        Self::select_for(geom, OutputLayout::Conv)
    }

    /// [`WinogradKernel::select`] for outputs stored by `layout`.
    pub fn select_for(geom: &Conv2dGeometry, layout: OutputLayout) -> WinogradKernel {
        Self::select_for_at(geom, layout, CpuFeatureLevel::get())
    }

    /// [`WinogradKernel::select_for`] at the CPU-feature level `level` (a backend passes its own).
    pub fn select_for_at(
        geom: &Conv2dGeometry,
        layout: OutputLayout,
        level: CpuFeatureLevel,
    ) -> WinogradKernel {
        WinogradKernel::ALL
            .into_iter()
            .find(|k| k.supports_layout_at(geom, layout, level))
            .unwrap_or(WinogradKernel::Portable)
    }

    /// Whether this kernel can run `geom` (stride 1) on this CPU: the SIMD kernels need `c_out` a
    /// multiple of 32 ([`SIMD_C_OUT`]; 32 is the network's).
    pub fn supports(self, geom: &Conv2dGeometry) -> bool {
        self.supports_layout(geom, OutputLayout::Conv)
    }

    /// [`WinogradKernel::supports`] for outputs stored by `layout` (a transposed convolution's
    /// SIMD kernels also need its `c_out / 4` a multiple of their vector width: 16 for AVX-512F,
    /// 8 for AVX2).
    pub fn supports_layout(self, geom: &Conv2dGeometry, layout: OutputLayout) -> bool {
        self.supports_layout_at(geom, layout, CpuFeatureLevel::get())
    }

    /// [`WinogradKernel::supports_layout`] at the CPU-feature level `level` (which also checks the
    /// CPU).
    pub fn supports_layout_at(
        self,
        geom: &Conv2dGeometry,
        layout: OutputLayout,
        level: CpuFeatureLevel,
    ) -> bool {
        let c_out = geom.c_out();
        let simd = cfg!(target_arch = "x86_64") && c_out > 0 && c_out.is_multiple_of(SIMD_C_OUT);
        geom.stride() == 1
            && match self {
                WinogradKernel::Avx512F => simd && layout.fits_lanes(c_out, 16) && level.avx512f(),
                WinogradKernel::Avx2Fma => {
                    simd && layout.fits_lanes(c_out, 8) && geom.c_in().is_multiple_of(8) && level.avx2_fma()
                }
                WinogradKernel::Portable => true,
            }
    }

    /// A short name, for logs and tests.
    pub fn name(self) -> &'static str {
        match self {
            WinogradKernel::Avx512F => "winograd-avx512f-14x32",
            WinogradKernel::Avx2Fma => "winograd-avx2-6x16",
            WinogradKernel::Portable => "winograd-portable",
        }
    }
}

/// Scratch of one work unit (one per rayon job): `V[ξ][t][c]` and `M[ξ][t][o]` for a group of
/// tiles, and a row of zeros standing for the rows above and below the image, each 64-byte
/// aligned (a vector store or load then touches one cache line).
pub(crate) struct Scratch {
    buf: Vec<f32>,
    /// Offsets of V, M and the zero row in `buf`, and their lengths.
    at: [usize; 3],
    len: [usize; 3],
}

impl Scratch {
    /// Scratch for `points` points, a `w`-wide map with `c_in` input channels, and `M` holding
    /// `m_channels` output channels per tile (the SIMD kernels fill it 32 channels at a time, the
    /// portable one with all of `c_out`).
    fn new(points: usize, w: usize, c_in: usize, m_channels: usize) -> Self {
        const ALIGN: usize = 16; // floats per 64 bytes
        let len = [points * TILES * c_in, points * TILES * m_channels, w * c_in];
        let buf = vec![0.0f32; len.iter().map(|l| l.next_multiple_of(ALIGN)).sum::<usize>() + ALIGN];
        let first = buf.as_ptr().align_offset(64).min(ALIGN);
        let at1 = first + len[0].next_multiple_of(ALIGN);
        let at = [first, at1, at1 + len[1].next_multiple_of(ALIGN)];
        Scratch { buf, at, len }
    }

    /// `(V, M, zeros)`.
    pub(crate) fn parts(&mut self) -> (&mut [f32], &mut [f32], &[f32]) {
        let (head, zeros) = self.buf.split_at_mut(self.at[2]);
        let (head, m) = head.split_at_mut(self.at[1]);
        let v = &mut head[self.at[0]..self.at[0] + self.len[0]];
        (v, &mut m[..self.len[1]], &zeros[..self.len[2]])
    }
}

/// The output rows of one tile row, the matching `skip` values, and the layout.
pub(crate) struct Rows<'a> {
    pub(crate) rows: &'a mut [f32],
    pub(crate) skip: Option<&'a [f32]>,
    pub(crate) layout: OutputLayout,
}

impl Rows<'_> {
    /// A shorter-lived handle on the same rows.
    fn reborrow(&mut self) -> Rows<'_> {
        Rows { rows: self.rows, skip: self.skip, layout: self.layout }
    }
}

/// A group of tiles of one tile row: tiles `tx0 .. tx0 + n` of tile row `ty`.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Group {
    pub(crate) ty: usize,
    pub(crate) tx0: usize,
    pub(crate) n: usize,
}

/// Pointers to the `R` input rows a tile row of variant `T` reads (`M ty - 1 ..`), a row outside the
/// image pointing at `zeros` (`w · c_in` zeros), so that the SIMD kernels load rows without checks.
pub(crate) fn window_rows<T: Tile>(
    input: &[f32],
    g: Group,
    (h, w, c_in): (usize, usize, usize),
    zeros: &[f32],
) -> [*const f32; tiles::MAX_R] {
    std::array::from_fn(|r| {
        let iy = (T::M * g.ty + r).wrapping_sub(1);
        if iy < h {
            input[iy * w * c_in..].as_ptr()
        } else {
            zeros.as_ptr()
        }
    })
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
    if packed.layout != OutputLayout::Conv {
        return Err(Error::invalid_argument(
            "conv2d Winograd weights",
            "packed for a transposed convolution (use deconv2d_winograd)",
        ));
    }
    dispatch(kernel, packed, input, activation, None, out)
}

/// Runs `kernel` (after checking it supports the packed geometry and layout) on slices whose
/// lengths the caller checked: `input [h, w, c_in]`, `out` and `skip` (added to every output value
/// after the bias and activation) of the layout's size.
///
/// # Errors
/// [`Error::InvalidArgument`] if `kernel` cannot run this geometry and layout on this CPU.
pub(crate) fn dispatch(
    kernel: WinogradKernel,
    packed: &PackedWinograd,
    input: &[f32],
    activation: Activation,
    skip: Option<&[f32]>,
    out: &mut [f32],
) -> Result<()> {
    let geom = packed.geometry();
    if !kernel.supports_layout(geom, packed.layout) {
        return Err(Error::invalid_argument(
            "conv2d Winograd kernel",
            format!(
                "{} cannot run c_in = {}, c_out = {} ({:?} layout) on this CPU",
                kernel.name(),
                geom.c_in(),
                geom.c_out(),
                packed.layout
            ),
        ));
    }
    match packed.tile {
        WinogradTile::F2x2 => run::<F2>(kernel, packed, input, activation, skip, out),
        WinogradTile::F4x4 => run::<F4>(kernel, packed, input, activation, skip, out),
    }
    Ok(())
}

/// The driver: tile rows in parallel, groups of [`TILES`] tiles in turn. A tile row's outputs are
/// `M w c_out` consecutive floats in either layout (`M` rows of `w c_out`, or `2M` rows of
/// `2w c_out / 4`), and so are its `skip` values.
fn run<T: Tile>(
    kernel: WinogradKernel,
    packed: &PackedWinograd,
    input: &[f32],
    act: Activation,
    skip: Option<&[f32]>,
    out: &mut [f32],
) {
    let geom = packed.geometry();
    let (w, c_in, c_out) = (geom.w(), geom.c_in(), geom.c_out());
    let tiles = w.div_ceil(T::M);
    let chunk = T::M * w * c_out;
    let m_channels = if kernel == WinogradKernel::Portable { c_out } else { SIMD_C_OUT };
    let init = || Scratch::new(T::P, w, c_in, m_channels);
    out.par_chunks_mut(chunk).enumerate().for_each_init(init, |scratch, (ty, rows)| {
        let skip = skip.map(|s| &s[ty * chunk..ty * chunk + rows.len()]);
        let mut out = Rows { rows, skip, layout: packed.layout };
        for tx0 in (0..tiles).step_by(TILES) {
            let group = Group { ty, tx0, n: TILES.min(tiles - tx0) };
            match kernel {
                #[cfg(target_arch = "x86_64")]
                // SAFETY: `supports_layout` found AVX-512F and c_out a multiple of 32 (with whole
                // vectors per parity block for a transposed convolution); the slice lengths were
                // checked against the geometry; `out` holds the tile row's outputs (and skip values).
                WinogradKernel::Avx512F => unsafe {
                    avx512::group::<T>(packed, input, group, act, scratch, out.reborrow());
                },
                #[cfg(target_arch = "x86_64")]
                // SAFETY: `supports_layout` found AVX2, FMA, c_out a multiple of 32 and c_in of 8;
                // lengths and outputs as above.
                WinogradKernel::Avx2Fma => unsafe {
                    avx2::group::<T>(packed, input, group, act, scratch, out.reborrow());
                },
                _ => portable::group::<T>(packed, input, group, act, scratch, out.reborrow()),
            }
        }
    });
}
