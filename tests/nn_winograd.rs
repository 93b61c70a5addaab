//! Winograd F(2x2, 3x3) and F(4x4, 3x3) convolutions (SPEC.md §7.11): within their budgets of the
//! f64 reference, the same bits from every kernel and any thread count, F(2x2) exact where the
//! arithmetic is exact.

use crate::common;

use common::{bits, lcg, thread_pool};
use densefeat::ops::conv2d::{
    conv2d_winograd_with, winograd_budget, winograd_magnitude_reference, PackedWinograd, WinogradKernel,
    WinogradTile,
};
use densefeat::ops::{conv2d, Activation, Conv2dGeometry, Conv2dImpl};
use densefeat::testing::within_budget;
use ndarray::{Array1, Array3, Array4};
use proptest::prelude::*;

#[derive(Clone, Debug)]
struct Case {
    g: Conv2dGeometry,
    x: Array3<f32>,
    w: Array4<f32>,
    b: Array1<f32>,
    act: Activation,
}

impl Case {
    fn new((h, w, c_in, c_out): (usize, usize, usize, usize), act: Activation, seed: u64) -> Self {
        let g = Conv2dGeometry::new(h, w, c_in, c_out, 1).unwrap();
        let mut next = lcg(seed);
        let x = Array3::from_shape_simple_fn(g.input_shape(), &mut next);
        let w = Array4::from_shape_simple_fn(g.weight_shape(), &mut next);
        let b = Array1::from_shape_simple_fn(c_out, &mut next);
        Case { g, x, w, b, act }
    }
    fn run(&self, imp: Conv2dImpl) -> Array3<f32> {
        conv2d(imp, &self.g, self.x.view(), self.w.view(), self.b.view(), self.act).unwrap()
    }
    fn run_kernel(&self, tile: WinogradTile, kernel: WinogradKernel) -> Array3<f32> {
        let packed = PackedWinograd::new(tile, &self.g, self.w.view(), self.b.view()).unwrap();
        let mut out = Array3::from_elem(self.g.output_shape(), f32::NAN);
        conv2d_winograd_with(
            kernel,
            &packed,
            self.x.as_slice().unwrap(),
            self.act,
            out.as_slice_mut().unwrap(),
        )
        .unwrap();
        out
    }
    /// `M_W` of SPEC.md §7.11, rounded to f32 for `within_budget`.
    fn winograd_magnitude(&self, tile: WinogradTile) -> Array3<f32> {
        let f = |v: &f32| f64::from(*v);
        let m = winograd_magnitude_reference(
            tile,
            &self.g,
            self.x.map(f).view(),
            self.w.map(f).view(),
            self.b.map(f).view(),
        )
        .unwrap();
        m.mapv(|v| v as f32)
    }
    /// §7.5's `M = Σ |x| |w| + |b|` (the reference on absolute values).
    fn magnitude(&self) -> Array3<f32> {
        let abs = |v: f32| v.abs();
        let (x, w, b) = (self.x.mapv(abs), self.w.mapv(abs), self.b.mapv(abs));
        conv2d(Conv2dImpl::Reference, &self.g, x.view(), w.view(), b.view(), Activation::None).unwrap()
    }
    fn kernels(&self) -> impl Iterator<Item = WinogradKernel> + '_ {
        WinogradKernel::ALL.into_iter().filter(|k| k.supports(&self.g))
    }
}

/// Sizes around the 2x2 tile and the 14-tile group: odd and even, one tile, a group and a bit.
const SIZES: [usize; 11] = [1, 2, 3, 4, 5, 7, 16, 17, 28, 29, 33];

fn cases() -> impl Strategy<Value = Case> {
    (
        prop::sample::select(SIZES.to_vec()),
        prop::sample::select(SIZES.to_vec()),
        prop::sample::select(vec![1usize, 3, 16, 17, 32, 35]),
        prop::sample::select(vec![1usize, 8, 32, 64]),
        any::<bool>(),
        any::<u64>(),
    )
        .prop_map(|(h, w, c_in, c_out, relu, seed)| {
            let act = if relu { Activation::Relu } else { Activation::None };
            Case::new((h, w, c_in, c_out), act, seed)
        })
}

const TILES: [(WinogradTile, Conv2dImpl); 2] =
    [(WinogradTile::F2x2, Conv2dImpl::WinogradF2), (WinogradTile::F4x4, Conv2dImpl::WinogradF4)];

proptest! {
    /// Every kernel of both variants within `2 (n + 2) ε M_W` of the f64 reference, all kernels
    /// (and the public entry point) with the same bits.
    #[test]
    fn winograd_matches_reference(case in cases()) {
        let oracle = case.run(Conv2dImpl::Reference);
        for (tile, imp) in TILES {
            let magnitude = case.winograd_magnitude(tile);
            let rel = winograd_budget(tile, case.g.c_in());
            let portable = case.run_kernel(tile, WinogradKernel::Portable);
            within_budget(portable.view(), oracle.view(), magnitude.view(), rel)
                .map_err(|e| TestCaseError::fail(format!("{tile:?}: {e}")))?;
            for kernel in case.kernels() {
                let got = case.run_kernel(tile, kernel);
                prop_assert_eq!(bits(&got), bits(&portable), "{:?} kernel {}", tile, kernel.name());
            }
            prop_assert_eq!(bits(&case.run(imp)), bits(&portable), "{:?}", tile);
        }
    }

    /// `M_W >= M`: every product of the convolution appears in `M_W` with a coefficient of at
    /// least one, so the Winograd budget is never tighter than the exact magnitude allows.
    #[test]
    fn winograd_magnitude_bounds_the_convolution_magnitude(case in cases()) {
        let m = case.magnitude();
        for (tile, _) in TILES {
            let mw = case.winograd_magnitude(tile);
            for (a, b) in mw.iter().zip(m.iter()) {
                prop_assert!(*a >= *b * (1.0 - 1e-6), "{:?}: M_W {} < M {}", tile, a, b);
            }
        }
    }
}

/// Small integer inputs and weights with even weights keep every intermediate an exact f32 (the
/// transforms halve weights at most twice), so Winograd gives the exact result, which is also the
/// reference's.
#[test]
fn winograd_is_exact_where_the_arithmetic_is_exact() {
    for (shape, seed) in [((9, 11, 32, 32), 1), ((6, 5, 3, 8), 2), ((1, 1, 4, 32), 3)] {
        let mut case = Case::new(shape, Activation::None, seed);
        case.x.mapv_inplace(|v| (v * 8.0).round());
        case.w.mapv_inplace(|v| 4.0 * (v * 4.0).round());
        case.b.mapv_inplace(|v| (v * 8.0).round());
        let oracle = case.run(Conv2dImpl::Reference);
        for kernel in case.kernels() {
            let got = case.run_kernel(WinogradTile::F2x2, kernel);
            assert_eq!(bits(&got), bits(&oracle), "shape {shape:?}, {}", kernel.name());
        }
    }
}

#[test]
fn winograd_output_independent_of_thread_count() {
    for (shape, seed) in
        [((37, 29, 32, 32), 7), ((66, 47, 32, 32), 8), ((5, 300, 3, 32), 9), ((17, 13, 35, 8), 10)]
    {
        let case = Case::new(shape, Activation::Relu, seed);
        for (tile, _) in TILES {
            for kernel in case.kernels() {
                let run = |n| thread_pool(n).install(|| case.run_kernel(tile, kernel));
                let one = run(1);
                for n in [2, 3, 8] {
                    let k = kernel.name();
                    assert_eq!(bits(&run(n)), bits(&one), "shape {shape:?}, {tile:?} {k}, threads = {n}");
                }
            }
        }
    }
}

#[test]
fn winograd_rejects_stride_2_and_bad_lengths() {
    let g2 = Conv2dGeometry::new(6, 6, 32, 32, 2).unwrap();
    let (w, b) = (Array4::<f32>::zeros((32, 32, 3, 3)), Array1::<f32>::zeros(32));
    for (tile, imp) in TILES {
        let err = PackedWinograd::new(tile, &g2, w.view(), b.view()).unwrap_err();
        assert!(err.to_string().contains("stride"), "{err}");
        assert!(!imp.supports(&g2));
        let x = Array3::<f32>::zeros((6, 6, 32));
        assert!(conv2d(imp, &g2, x.view(), w.view(), b.view(), Activation::None).is_err());
    }
    let case = Case::new((5, 6, 3, 8), Activation::None, 4);
    let packed = PackedWinograd::new(WinogradTile::F4x4, &case.g, case.w.view(), case.b.view()).unwrap();
    let mut out = vec![0.0; case.g.output_shape().iter().product()];
    let x = case.x.as_slice().unwrap();
    let k = WinogradKernel::Portable;
    assert!(conv2d_winograd_with(k, &packed, &x[1..], Activation::None, &mut out).is_err());
    assert!(conv2d_winograd_with(k, &packed, x, Activation::None, &mut out[1..]).is_err());
    // c_out = 8: the AVX-512 kernel is an error, not a fallback.
    assert!(conv2d_winograd_with(WinogradKernel::Avx512F, &packed, x, Activation::None, &mut out).is_err());
}

/// `fastest_for` picks Winograd exactly for the stride-1, `c_in >= 16`, `c_out = 32` layers where
/// one of its SIMD kernels runs; `select` prefers AVX-512F, then AVX2+FMA.
#[test]
fn fastest_picks_winograd_for_wide_stride_1_layers_with_simd() {
    let g = Conv2dGeometry::new(8, 8, 32, 32, 1).unwrap();
    let (avx512, avx2) = (WinogradKernel::Avx512F.supports(&g), WinogradKernel::Avx2Fma.supports(&g));
    let simd = avx512 || avx2;
    let want = if avx512 {
        WinogradKernel::Avx512F
    } else if avx2 {
        WinogradKernel::Avx2Fma
    } else {
        WinogradKernel::Portable
    };
    assert_eq!(WinogradKernel::select(&g), want);
    // The AVX2 kernel needs c_in a multiple of 8; the AVX-512 one takes any.
    let g17 = Conv2dGeometry::new(8, 8, 17, 32, 1).unwrap();
    assert!(!WinogradKernel::Avx2Fma.supports(&g17));
    assert_eq!(WinogradKernel::Avx512F.supports(&g17), avx512);
    for (c_in, c_out, stride, want) in
        [(32, 32, 1, simd), (16, 32, 1, simd), (3, 32, 1, false), (32, 32, 2, false), (32, 8, 1, false)]
    {
        let g = Conv2dGeometry::new(40, 40, c_in, c_out, stride).unwrap();
        let winograd = Conv2dImpl::fastest_for(&g).winograd_tile().is_some();
        assert_eq!(winograd, want, "{c_in} -> {c_out}, s {stride}");
    }
}
