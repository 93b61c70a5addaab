//! The 5x5 stride-2 transposed convolution by Winograd (SPEC.md §7.3, §7.11): the four parity
//! convolutions as one 3x3 convolution with `4 c_out` outputs. Within the Winograd budget of the
//! f64 reference, the same bits from every kernel and any thread count, the fused U-Net sum the
//! bits of a separate addition, F(2x2) exact where the arithmetic is exact.

use crate::common;

use common::{bits, lcg, thread_pool};
use densefeat::ops::conv2d::{winograd_budget, OutputLayout, WinogradKernel, WinogradTile};
use densefeat::ops::deconv2d::winograd::{equivalent_geometry, equivalent_weight};
use densefeat::ops::deconv2d::{
    deconv2d_winograd_magnitude_reference, deconv2d_winograd_with, pack_deconv_winograd,
};
use densefeat::ops::{deconv2d, deconv2d_into, Deconv2dGeometry, Deconv2dImpl};
use densefeat::testing::within_budget;
use ndarray::{Array1, Array3, Array4};
use proptest::prelude::*;

#[derive(Clone, Debug)]
struct Case {
    g: Deconv2dGeometry,
    x: Array3<f32>,
    w: Array4<f32>,
    b: Array1<f32>,
    skip: Array3<f32>,
}

impl Case {
    fn new((h, w, c_in, c_out): (usize, usize, usize, usize), seed: u64) -> Self {
        let g = Deconv2dGeometry::new(h, w, c_in, c_out).unwrap();
        let mut next = lcg(seed);
        let x = Array3::from_shape_simple_fn(g.input_shape(), &mut next);
        let w = Array4::from_shape_simple_fn(g.weight_shape(), &mut next);
        let b = Array1::from_shape_simple_fn(c_out, &mut next);
        let skip = Array3::from_shape_simple_fn(g.output_shape(), &mut next);
        Case { g, x, w, b, skip }
    }
    fn run(&self, imp: Deconv2dImpl) -> Array3<f32> {
        deconv2d(imp, &self.g, self.x.view(), self.w.view(), self.b.view()).unwrap()
    }
    fn run_kernel(&self, tile: WinogradTile, kernel: WinogradKernel, skip: bool) -> Array3<f32> {
        let packed = pack_deconv_winograd(tile, &self.g, self.w.view(), self.b.view()).unwrap();
        let mut out = Array3::from_elem(self.g.output_shape(), f32::NAN);
        let skip = skip.then(|| self.skip.as_slice().unwrap());
        let x = self.x.as_slice().unwrap();
        deconv2d_winograd_with(kernel, &packed, x, skip, out.as_slice_mut().unwrap()).unwrap();
        out
    }
    /// `M_W` of SPEC.md §7.11 for the equivalent convolution, rounded to f32 for `within_budget`.
    fn winograd_magnitude(&self, tile: WinogradTile) -> Array3<f32> {
        let f = |v: &f32| f64::from(*v);
        let (x, w, b) = (self.x.map(f), self.w.map(f), self.b.map(f));
        let m = deconv2d_winograd_magnitude_reference(tile, &self.g, x.view(), w.view(), b.view()).unwrap();
        m.mapv(|v| v as f32)
    }
    fn kernels(&self) -> Vec<WinogradKernel> {
        let g = equivalent_geometry(&self.g).unwrap();
        WinogradKernel::ALL.into_iter().filter(|k| k.supports_layout(&g, OutputLayout::Deconv)).collect()
    }
}

const SIZES: [usize; 10] = [1, 2, 3, 4, 5, 7, 8, 9, 16, 17];

fn cases() -> impl Strategy<Value = Case> {
    (
        prop::sample::select(SIZES.to_vec()),
        prop::sample::select(SIZES.to_vec()),
        prop::sample::select(vec![1usize, 3, 16, 32, 35]),
        prop::sample::select(vec![1usize, 8, 16, 32]),
        any::<u64>(),
    )
        .prop_map(|(h, w, c_in, c_out, seed)| Case::new((h, w, c_in, c_out), seed))
}

const TILES: [(WinogradTile, Deconv2dImpl); 2] =
    [(WinogradTile::F2x2, Deconv2dImpl::WinogradF2), (WinogradTile::F4x4, Deconv2dImpl::WinogradF4)];

proptest! {
    #![proptest_config(ProptestConfig::with_cases(48))]
    /// Both variants within `2 (n + 2) ε M_W` of the f64 reference (`n` of the equivalent
    /// convolution's `c_in`), every kernel and the public entry point with the same bits, and the
    /// fused skip value the bits of `out + skip` computed afterwards.
    #[test]
    fn deconv_winograd_matches_reference(case in cases()) {
        let oracle = case.run(Deconv2dImpl::Reference);
        for (tile, imp) in TILES {
            let magnitude = case.winograd_magnitude(tile);
            let rel = winograd_budget(tile, case.g.c_in());
            let portable = case.run_kernel(tile, WinogradKernel::Portable, false);
            within_budget(portable.view(), oracle.view(), magnitude.view(), rel)
                .map_err(|e| TestCaseError::fail(format!("{tile:?}: {e}")))?;
            let summed = &portable + &case.skip;
            for kernel in case.kernels() {
                let got = case.run_kernel(tile, kernel, false);
                prop_assert_eq!(bits(&got), bits(&portable), "{:?} kernel {}", tile, kernel.name());
                let fused = case.run_kernel(tile, kernel, true);
                prop_assert_eq!(bits(&fused), bits(&summed), "{:?} kernel {} + skip", tile, kernel.name());
            }
            prop_assert_eq!(bits(&case.run(imp)), bits(&portable), "{:?}", tile);
            let mut out = Array3::from_elem(case.g.output_shape(), f32::NAN);
            let (x, w, b) = (case.x.view(), case.w.view(), case.b.view());
            let skip = Some(case.skip.as_slice().unwrap());
            deconv2d_into(imp, &case.g, x, w, b, skip, out.as_slice_mut().unwrap()).unwrap();
            prop_assert_eq!(bits(&out), bits(&summed), "{:?} deconv2d_into + skip", tile);
        }
    }
}

/// The equivalent weights put each tap where the parity rule says (SPEC.md §7.3): parity `(0, 0)`
/// window `(j_y, j_x)` holds tap `(4 - 2 j_y, 4 - 2 j_x)`, parity `(1, 1)` tap `(5 - 2j, ..)` with
/// zeros in the first row and column.
#[test]
fn equivalent_weights_follow_the_parity_rule() {
    let w = Array4::from_shape_fn((1, 1, 5, 5), |(_, _, ky, kx)| (10 * ky + kx) as f32 + 1.0);
    let e = equivalent_weight(w.view());
    assert_eq!(e.shape(), &[4, 1, 3, 3]);
    for j in 0..3 {
        for i in 0..3 {
            assert_eq!(e[[0, 0, j, i]], w[[0, 0, 4 - 2 * j, 4 - 2 * i]]);
            let odd = |k: usize| (k > 0).then(|| 5 - 2 * k);
            let want = |ky: Option<usize>, kx: Option<usize>| match (ky, kx) {
                (Some(ky), Some(kx)) => w[[0, 0, ky, kx]],
                _ => 0.0,
            };
            assert_eq!(e[[1, 0, j, i]], want(Some(4 - 2 * j), odd(i)), "parity (0, 1)");
            assert_eq!(e[[2, 0, j, i]], want(odd(j), Some(4 - 2 * i)), "parity (1, 0)");
            assert_eq!(e[[3, 0, j, i]], want(odd(j), odd(i)), "parity (1, 1)");
        }
    }
}

/// Small integers and weights that are multiples of 4 keep F(2x2)'s arithmetic exact (its
/// transforms halve weights at most twice), so it gives the reference's result exactly.
#[test]
fn deconv_winograd_f2_is_exact_where_the_arithmetic_is_exact() {
    for (shape, seed) in [((9, 11, 32, 32), 1), ((6, 5, 3, 8), 2), ((1, 1, 4, 16), 3)] {
        let mut case = Case::new(shape, seed);
        case.x.mapv_inplace(|v| (v * 8.0).round());
        case.w.mapv_inplace(|v| 4.0 * (v * 4.0).round());
        case.b.mapv_inplace(|v| (v * 8.0).round());
        let oracle = case.run(Deconv2dImpl::Reference);
        for kernel in case.kernels() {
            let got = case.run_kernel(WinogradTile::F2x2, kernel, false);
            assert_eq!(bits(&got), bits(&oracle), "shape {shape:?}, {}", kernel.name());
        }
    }
}

#[test]
fn deconv_winograd_output_independent_of_thread_count() {
    for (shape, seed) in [((37, 29, 32, 32), 7), ((20, 41, 32, 16), 8), ((9, 13, 35, 8), 9)] {
        let case = Case::new(shape, seed);
        for (tile, _) in TILES {
            for kernel in case.kernels() {
                let run = |n| thread_pool(n).install(|| case.run_kernel(tile, kernel, true));
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
fn deconv_winograd_rejects_bad_lengths_and_convolution_weights() {
    let case = Case::new((5, 6, 3, 8), 4);
    let packed = pack_deconv_winograd(WinogradTile::F4x4, &case.g, case.w.view(), case.b.view()).unwrap();
    let mut out = vec![0.0; case.g.output_shape().iter().product()];
    let (x, skip) = (case.x.as_slice().unwrap(), case.skip.as_slice().unwrap());
    let k = WinogradKernel::Portable;
    assert!(deconv2d_winograd_with(k, &packed, &x[1..], None, &mut out).is_err());
    assert!(deconv2d_winograd_with(k, &packed, x, None, &mut out[1..]).is_err());
    assert!(deconv2d_winograd_with(k, &packed, x, Some(&skip[1..]), &mut out).is_err());
    // c_out = 8: 8-channel parity blocks do not fill a zmm, so the AVX-512 kernel is an error.
    assert!(deconv2d_winograd_with(WinogradKernel::Avx512F, &packed, x, None, &mut out).is_err());
    // The transposed convolution's [c_in, c_out] weights, not a convolution's.
    let bad = Array4::<f32>::zeros((8, 3, 5, 5));
    assert!(pack_deconv_winograd(WinogradTile::F2x2, &case.g, bad.view(), case.b.view()).is_err());
    // Convolution weights are not taken for a transposed convolution.
    let g = densefeat::ops::Conv2dGeometry::new(5, 6, 3, 32, 1).unwrap();
    let conv = densefeat::ops::conv2d::PackedWinograd::new(
        WinogradTile::F2x2,
        &g,
        Array4::<f32>::zeros((32, 3, 3, 3)).view(),
        Array1::<f32>::zeros(32).view(),
    )
    .unwrap();
    let err = deconv2d_winograd_with(k, &conv, x, None, &mut out).unwrap_err();
    assert!(err.to_string().contains("convolution"), "{err}");
}

/// `fastest_for` picks Winograd F(4x4) for the network's `32 -> 32` transposed convolutions where a
/// SIMD Winograd kernel runs them, Direct for narrow inputs.
#[test]
fn fastest_picks_winograd_for_wide_transposed_convolutions_with_simd() {
    let simd = |g: &Deconv2dGeometry| {
        let e = equivalent_geometry(g).unwrap();
        WinogradKernel::select_for(&e, OutputLayout::Deconv) != WinogradKernel::Portable
    };
    for (c_in, c_out) in [(32, 32), (16, 32), (3, 32), (32, 8)] {
        let g = Deconv2dGeometry::new(20, 20, c_in, c_out).unwrap();
        let want = if simd(&g) && c_in >= 16 { Deconv2dImpl::WinogradF4 } else { Deconv2dImpl::Direct };
        assert_eq!(Deconv2dImpl::fastest_for(&g), want, "{c_in} -> {c_out}");
    }
    let g = Deconv2dGeometry::new(20, 20, 32, 32).unwrap();
    let e = equivalent_geometry(&g).unwrap();
    let avx = WinogradKernel::Avx512F.supports_layout(&e, OutputLayout::Deconv)
        || WinogradKernel::Avx2Fma.supports_layout(&e, OutputLayout::Deconv);
    assert_eq!(simd(&g), avx);
}
