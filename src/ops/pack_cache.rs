//! Packed layer weights cached by content (SPEC.md §7.9): the CPU backend repacks a layer's
//! weights ([`PackedConv2d`], [`PackedDeconv2d`]) once per process instead of once per call.
//!
//! An entry is found by the address of the weight's data and kept only while the weight and bias
//! are bit-for-bit those it was packed from (compared on every lookup, a few µs per layer), so a
//! weight updated in place (training) or a new array at a reused address is repacked: a hit is
//! always the packing of the values passed. Packing is a pure permutation of the values (the
//! Winograd weight transform, [`PackedWinograd`], a fixed f64 computation), so cached and fresh
//! packings are identical and results never depend on the cache. The cache holds at most
//! [`MAX_LAYERS`] layers per kind and starts over when full (like the GPU backend's weight cache).

use std::sync::Mutex;

use ndarray::{ArrayView1, ArrayView4};

use crate::error::Result;
use crate::ops::conv2d::{PackedConv2d, PackedWinograd, WinogradTile};
use crate::ops::deconv2d::winograd::{equivalent_geometry, pack_deconv_winograd};
use crate::ops::deconv2d::PackedDeconv2d;
use crate::ops::geometry::{Conv2dGeometry, Deconv2dGeometry};

/// Layers kept per kind before the cache starts over (the network has 19).
pub const MAX_LAYERS: usize = 256;

/// One cached layer: the values it was packed from and the packing.
struct Entry<P> {
    key: (usize, usize),
    weight: Vec<u32>,
    bias: Vec<u32>,
    packed: P,
}

static CONV: Mutex<Vec<Entry<PackedConv2d>>> = Mutex::new(Vec::new());
static DECONV: Mutex<Vec<Entry<PackedDeconv2d>>> = Mutex::new(Vec::new());
static WINOGRAD_F2: Mutex<Vec<Entry<PackedWinograd>>> = Mutex::new(Vec::new());
static WINOGRAD_F4: Mutex<Vec<Entry<PackedWinograd>>> = Mutex::new(Vec::new());
static DECONV_WINOGRAD_F2: Mutex<Vec<Entry<PackedWinograd>>> = Mutex::new(Vec::new());
static DECONV_WINOGRAD_F4: Mutex<Vec<Entry<PackedWinograd>>> = Mutex::new(Vec::new());

/// The bit patterns of `v`, without a copy.
fn bits(v: &[f32]) -> &[u32] {
    // SAFETY: `u32` has the size and alignment of `f32` and every bit pattern is a valid `u32`.
    unsafe { std::slice::from_raw_parts(v.as_ptr().cast::<u32>(), v.len()) }
}

/// Whether `v` has exactly the bits `stored` (one `memcmp`).
fn same_bits(stored: &[u32], v: &[f32]) -> bool {
    stored == bits(v)
}

/// The cached packing of `(weight, bias)` (re-targeted with `retarget`), or `pack()` stored.
fn lookup<P: Clone>(
    cache: &Mutex<Vec<Entry<P>>>,
    weight: ArrayView4<f32>,
    bias: ArrayView1<f32>,
    pack: impl FnOnce() -> Result<P>,
    retarget: impl FnOnce(&P) -> Result<P>,
) -> Result<P> {
    let (Some(w), Some(b)) = (weight.as_slice(), bias.as_slice()) else {
        return pack(); // Not contiguous: not worth caching.
    };
    let key = (w.as_ptr() as usize, w.len());
    {
        let entries = cache.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(e) = entries.iter().find(|e| e.key == key) {
            if same_bits(&e.weight, w) && same_bits(&e.bias, b) {
                return retarget(&e.packed);
            }
        }
    }
    let packed = pack()?;
    let mut entries = cache.lock().unwrap_or_else(|e| e.into_inner());
    entries.retain(|e| e.key != key);
    if entries.len() >= MAX_LAYERS {
        entries.clear();
    }
    entries.push(Entry { key, weight: bits(w).to_vec(), bias: bits(b).to_vec(), packed: packed.clone() });
    Ok(packed)
}

/// [`PackedConv2d::new`]`(geom, weight, bias)`, packed once per distinct weight.
///
/// # Errors
/// As [`PackedConv2d::new`].
pub fn packed_conv(
    geom: &Conv2dGeometry,
    weight: ArrayView4<f32>,
    bias: ArrayView1<f32>,
) -> Result<PackedConv2d> {
    crate::ops::expect_shape("conv2d weight", weight.shape(), &geom.weight_shape())?;
    crate::ops::expect_shape("conv2d bias", bias.shape(), &[geom.c_out()])?;
    lookup(&CONV, weight, bias, || PackedConv2d::new(geom, weight, bias), |p| p.with_geometry(geom))
}

/// [`PackedDeconv2d::new`]`(geom, weight, bias)`, packed once per distinct weight.
///
/// # Errors
/// As [`PackedDeconv2d::new`].
pub fn packed_deconv(
    geom: &Deconv2dGeometry,
    weight: ArrayView4<f32>,
    bias: ArrayView1<f32>,
) -> Result<PackedDeconv2d> {
    crate::ops::expect_shape("deconv2d weight", weight.shape(), &geom.weight_shape())?;
    crate::ops::expect_shape("deconv2d bias", bias.shape(), &[geom.c_out()])?;
    lookup(&DECONV, weight, bias, || PackedDeconv2d::new(geom, weight, bias), |p| p.with_geometry(geom))
}

/// [`PackedWinograd::new`]`(tile, geom, weight, bias)`, transformed once per distinct weight and
/// variant.
///
/// # Errors
/// As [`PackedWinograd::new`].
pub fn packed_winograd(
    tile: WinogradTile,
    geom: &Conv2dGeometry,
    weight: ArrayView4<f32>,
    bias: ArrayView1<f32>,
) -> Result<PackedWinograd> {
    crate::ops::expect_shape("conv2d weight", weight.shape(), &geom.weight_shape())?;
    crate::ops::expect_shape("conv2d bias", bias.shape(), &[geom.c_out()])?;
    let cache = match tile {
        WinogradTile::F2x2 => &WINOGRAD_F2,
        WinogradTile::F4x4 => &WINOGRAD_F4,
    };
    lookup(cache, weight, bias, || PackedWinograd::new(tile, geom, weight, bias), |p| p.with_geometry(geom))
}

/// [`pack_deconv_winograd`]`(tile, geom, weight, bias)` (a transposed convolution by Winograd,
/// SPEC.md §7.3), transformed once per distinct weight and variant.
///
/// # Errors
/// As [`pack_deconv_winograd`].
pub fn packed_deconv_winograd(
    tile: WinogradTile,
    geom: &Deconv2dGeometry,
    weight: ArrayView4<f32>,
    bias: ArrayView1<f32>,
) -> Result<PackedWinograd> {
    crate::ops::expect_shape("deconv2d weight", weight.shape(), &geom.weight_shape())?;
    crate::ops::expect_shape("deconv2d bias", bias.shape(), &[geom.c_out()])?;
    let cache = match tile {
        WinogradTile::F2x2 => &DECONV_WINOGRAD_F2,
        WinogradTile::F4x4 => &DECONV_WINOGRAD_F4,
    };
    let g = equivalent_geometry(geom)?;
    lookup(cache, weight, bias, || pack_deconv_winograd(tile, geom, weight, bias), |p| p.with_geometry(&g))
}
