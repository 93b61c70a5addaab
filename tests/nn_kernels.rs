//! The network's kernels (SPEC.md §7): fast implementations against the f64 references within the
//! §7.5 budget, bit-identical results for any thread count, and known answers pinning PyTorch's
//! semantics.

use crate::common;

use common::{bits, lcg, thread_pool};
use densefeat::ops::conv2d::{
    conv2d_direct, conv2d_direct_concat_with, conv2d_direct_with, conv2d_im2col, direct, im2col, scratch_len,
    winograd_budget, winograd_magnitude_reference, DirectKernel, PackedConv2d, WinogradTile,
};
use densefeat::ops::deconv2d::{
    deconv2d_direct, deconv2d_direct_with, deconv2d_fast, deconv2d_winograd_magnitude_reference,
    scratch_len as deconv_scratch_len, PackedDeconv2d,
};
use densefeat::ops::geometry::DownsampleGeometry;
use densefeat::ops::{
    add, concat_channels, conv2d, conv2d_concat_into, deconv2d, downsample2x, downsample2x_reference,
    Activation, Conv2dGeometry, Conv2dImpl, Deconv2dGeometry, Deconv2dImpl,
};
use densefeat::testing::within_budget;
use ndarray::{array, s, Array1, Array3, Array4};
use proptest::prelude::*;

// ---------------------------------------------------------------------------------------------
// Cases

fn bits_of(a: &[f32]) -> Vec<u32> {
    a.iter().map(|v| v.to_bits()).collect()
}

/// Spatial sizes that stress borders, strides and GEMM tile edges (16 is a microkernel width).
const SIZES: [usize; 12] = [1, 2, 3, 4, 5, 7, 8, 15, 16, 17, 31, 33];
const C_INS: [usize; 4] = [1, 3, 32, 35];
const C_OUTS: [usize; 3] = [1, 8, 32];

#[derive(Clone, Debug)]
struct ConvCase {
    g: Conv2dGeometry,
    x: Array3<f32>,
    w: Array4<f32>,
    b: Array1<f32>,
    act: Activation,
}

impl ConvCase {
    fn new(shape: (usize, usize, usize, usize, usize), act: Activation, seed: u64) -> Self {
        let (h, w, c_in, c_out, stride) = shape;
        let g = Conv2dGeometry::new(h, w, c_in, c_out, stride).unwrap();
        let mut next = lcg(seed);
        let x = Array3::from_shape_simple_fn(g.input_shape(), &mut next);
        let w = Array4::from_shape_simple_fn(g.weight_shape(), &mut next);
        let b = Array1::from_shape_simple_fn(c_out, &mut next);
        ConvCase { g, x, w, b, act }
    }
    fn run(&self, imp: Conv2dImpl) -> Array3<f32> {
        conv2d(imp, &self.g, self.x.view(), self.w.view(), self.b.view(), self.act).unwrap()
    }
    /// Runs Direct with a chosen kernel.
    fn run_direct(&self, kernel: DirectKernel) -> Array3<f32> {
        let packed = PackedConv2d::new(&self.g, self.w.view(), self.b.view()).unwrap();
        let mut out = Array3::from_elem(self.g.output_shape(), f32::NAN);
        conv2d_direct_with(
            kernel,
            &packed,
            self.x.as_slice().unwrap(),
            self.act,
            out.as_slice_mut().unwrap(),
        )
        .unwrap();
        out
    }
    /// Runs the staged concatenation kernel with `x`'s channels split `ca + (c_in - ca)`.
    fn run_direct_concat(&self, kernel: DirectKernel, ca: usize) -> Array3<f32> {
        let packed = PackedConv2d::new(&self.g, self.w.view(), self.b.view()).unwrap();
        let (a, b) = self.split(ca);
        let mut out = Array3::from_elem(self.g.output_shape(), f32::NAN);
        let (sa, sb) = (a.as_slice().unwrap(), b.as_slice().unwrap());
        let cb = self.g.c_in() - ca;
        conv2d_direct_concat_with(kernel, &packed, (sa, ca), (sb, cb), self.act, out.as_slice_mut().unwrap())
            .unwrap();
        out
    }
    /// `x` as two maps whose concatenation it is: channels `..ca` and `ca..`.
    fn split(&self, ca: usize) -> (Array3<f32>, Array3<f32>) {
        (self.x.slice(s![.., .., ..ca]).to_owned(), self.x.slice(s![.., .., ca..]).to_owned())
    }
    /// The same case on |x|, |w|, |b| without activation: its reference output is Σ|x||w| + |b|.
    fn abs(&self) -> Self {
        let abs = |v: f32| v.abs();
        ConvCase {
            g: self.g,
            x: self.x.mapv(abs),
            w: self.w.mapv(abs),
            b: self.b.mapv(abs),
            act: Activation::None,
        }
    }
}

fn conv_cases() -> impl Strategy<Value = ConvCase> {
    (
        prop::sample::select(SIZES.to_vec()),
        prop::sample::select(SIZES.to_vec()),
        prop::sample::select(C_INS.to_vec()),
        prop::sample::select(C_OUTS.to_vec()),
        prop::sample::select(vec![1usize, 2]),
        any::<bool>(),
        any::<u64>(),
    )
        .prop_map(|(h, w, c_in, c_out, stride, relu, seed)| {
            let act = if relu { Activation::Relu } else { Activation::None };
            ConvCase::new((h, w, c_in, c_out, stride), act, seed)
        })
}

#[derive(Clone, Debug)]
struct DeconvCase {
    g: Deconv2dGeometry,
    x: Array3<f32>,
    w: Array4<f32>,
    b: Array1<f32>,
}

impl DeconvCase {
    fn new(h: usize, w: usize, c_in: usize, c_out: usize, seed: u64) -> Self {
        let g = Deconv2dGeometry::new(h, w, c_in, c_out).unwrap();
        let mut next = lcg(seed);
        let x = Array3::from_shape_simple_fn(g.input_shape(), &mut next);
        let w = Array4::from_shape_simple_fn(g.weight_shape(), &mut next);
        let b = Array1::from_shape_simple_fn(c_out, &mut next);
        DeconvCase { g, x, w, b }
    }
    fn run(&self, imp: Deconv2dImpl) -> Array3<f32> {
        deconv2d(imp, &self.g, self.x.view(), self.w.view(), self.b.view()).unwrap()
    }
    fn abs(&self) -> Self {
        let abs = |v: f32| v.abs();
        DeconvCase { g: self.g, x: self.x.mapv(abs), w: self.w.mapv(abs), b: self.b.mapv(abs) }
    }
}

/// Deconv inputs are coarse maps; smaller sizes keep the f64 scatter reference quick.
const DECONV_SIZES: [usize; 10] = [1, 2, 3, 4, 5, 7, 8, 9, 16, 17];

fn deconv_cases() -> impl Strategy<Value = DeconvCase> {
    (
        prop::sample::select(DECONV_SIZES.to_vec()),
        prop::sample::select(DECONV_SIZES.to_vec()),
        prop::sample::select(C_INS.to_vec()),
        prop::sample::select(C_OUTS.to_vec()),
        any::<u64>(),
    )
        .prop_map(|(h, w, c_in, c_out, seed)| DeconvCase::new(h, w, c_in, c_out, seed))
}

/// The §7.5 budget for a K-term dot product plus bias: 2 K ε_f32 (Σ|x||w| + |b|).
fn budget(k: usize) -> f32 {
    2.0 * k as f32 * f32::EPSILON
}

// ---------------------------------------------------------------------------------------------
// Fast against reference

proptest! {
    #[test]
    fn im2col_matches_reference(case in conv_cases()) {
        let fast = case.run(Conv2dImpl::Im2colGemm);
        let oracle = case.run(Conv2dImpl::Reference);
        let magnitude = case.abs().run(Conv2dImpl::Reference);
        within_budget(fast.view(), oracle.view(), magnitude.view(), budget(case.g.k()))?;
    }

    #[test]
    fn direct_matches_reference(case in conv_cases()) {
        let oracle = case.run(Conv2dImpl::Reference);
        let magnitude = case.abs().run(Conv2dImpl::Reference);
        let fast = case.run(Conv2dImpl::Direct);
        within_budget(fast.view(), oracle.view(), magnitude.view(), budget(case.g.k()))?;
        // Every kernel this CPU can run, not only the one Direct picks.
        for kernel in DirectKernel::ALL.into_iter().filter(|k| k.supports(&case.g)) {
            let got = case.run_direct(kernel);
            within_budget(got.view(), oracle.view(), magnitude.view(), budget(case.g.k()))
                .map_err(|e| TestCaseError::fail(format!("kernel {}: {e}", kernel.name())))?;
        }
    }

    /// The staged concatenation (SPEC.md §7.10): within §7.5 of the reference on the concatenated
    /// map, and bit-identical to the direct kernel on it, for every kernel and channel split.
    #[test]
    fn direct_concat_matches_reference_and_direct_on_the_concatenation(
        case in conv_cases().prop_filter("two channel parts", |c| c.g.c_in() >= 2),
        split in 0.0..1.0f64,
    ) {
        let ca = 1 + ((case.g.c_in() - 1) as f64 * split) as usize; // 1 ..= c_in - 1
        let oracle = case.run(Conv2dImpl::Reference);
        let magnitude = case.abs().run(Conv2dImpl::Reference);
        for kernel in DirectKernel::ALL.into_iter().filter(|k| k.supports(&case.g)) {
            let got = case.run_direct_concat(kernel, ca);
            within_budget(got.view(), oracle.view(), magnitude.view(), budget(case.g.k()))
                .map_err(|e| TestCaseError::fail(format!("kernel {}: {e}", kernel.name())))?;
            prop_assert_eq!(bits(&got), bits(&case.run_direct(kernel)), "kernel {}, ca = {}", kernel.name(), ca);
        }
        // The public entry point, every implementation: the same bits as conv2d on concat(a, b).
        let (a, b) = case.split(ca);
        for imp in [Conv2dImpl::Im2colGemm, Conv2dImpl::Direct] {
            let mut out = Array3::from_elem(case.g.output_shape(), f32::NAN);
            conv2d_concat_into(imp, &case.g, a.view(), b.view(), case.w.view(), case.b.view(), case.act,
                out.as_slice_mut().unwrap()).unwrap();
            prop_assert_eq!(bits(&out), bits(&case.run(imp)), "{:?}, ca = {}", imp, ca);
        }
    }

    #[test]
    fn deconv_parity_gemm_matches_reference(case in deconv_cases()) {
        let fast = case.run(Deconv2dImpl::ParityGemm);
        let oracle = case.run(Deconv2dImpl::Reference);
        let magnitude = case.abs().run(Deconv2dImpl::Reference);
        within_budget(fast.view(), oracle.view(), magnitude.view(), budget(case.g.k()))?;
    }

    /// The direct kernel (where this CPU runs it; `ParityGemm` elsewhere), and its fused U-Net sum:
    /// `skip + deconv` equals the separate `add` of the unfused output bit for bit.
    #[test]
    fn deconv_direct_matches_reference(case in deconv_cases()) {
        let fast = case.run(Deconv2dImpl::Direct);
        let oracle = case.run(Deconv2dImpl::Reference);
        let magnitude = case.abs().run(Deconv2dImpl::Reference);
        within_budget(fast.view(), oracle.view(), magnitude.view(), budget(case.g.k()))?;
        if densefeat::ops::deconv2d::direct::supported(&case.g) {
            let packed = PackedDeconv2d::new(&case.g, case.w.view(), case.b.view()).unwrap();
            let skip: Vec<f32> = (0..fast.len()).map(|i| ((i * 7919) % 113) as f32 * 0.37 - 20.0).collect();
            let mut fused = vec![0.0f32; fast.len()];
            deconv2d_direct(&packed, case.x.as_slice().unwrap(), Some(&skip), &mut fused).unwrap();
            let want: Vec<u32> = fast.as_slice().unwrap().iter().zip(&skip).map(|(a, s)| (s + a).to_bits()).collect();
            prop_assert_eq!(fused.iter().map(|v| v.to_bits()).collect::<Vec<_>>(), want);
            // Every strip kernel this CPU runs gives the same bits (one FMA per product, same order).
            for kernel in [DirectKernel::Avx512F, DirectKernel::Avx2Fma] {
                let mut other = vec![0.0f32; fast.len()];
                if deconv2d_direct_with(kernel, &packed, case.x.as_slice().unwrap(), Some(&skip), &mut other).is_ok() {
                    prop_assert_eq!(bits_of(&other), bits_of(&fused), "{}", kernel.name());
                }
            }
        }
    }

    #[test]
    fn im2col_gather_is_bit_exact(case in conv_cases(), start in 0.0..1.0f64, rows in 1usize..4) {
        let g = case.g;
        let y0 = (start * g.h_out() as f64) as usize;
        let rows = rows.min(g.h_out() - y0);
        let mut cols = vec![f32::NAN; rows * g.w_out() * g.k()];
        im2col::im2col_rows(&g, case.x.as_slice().unwrap(), y0, rows, &mut cols);
        let (h, w, c_in, s) = (g.h() as isize, g.w() as isize, g.c_in(), g.stride() as isize);
        let mut i = 0;
        for y in y0..y0 + rows {
            for x in 0..g.w_out() {
                for ky in 0..3isize {
                    for kx in 0..3isize {
                        let (iy, ix) = (s * y as isize + ky - 1, s * x as isize + kx - 1);
                        for c in 0..c_in {
                            let want = if iy < 0 || ix < 0 || iy >= h || ix >= w {
                                0.0
                            } else {
                                case.x[[iy as usize, ix as usize, c]]
                            };
                            prop_assert_eq!(cols[i].to_bits(), want.to_bits(), "y {} x {} ky {} kx {} c {}", y, x, ky, kx, c);
                            i += 1;
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn downsample_equals_the_reference_bit_for_bit(
        h in 1usize..14, w in 1usize..40, c in 1usize..5,
        vals in proptest::collection::vec(
            prop_oneof![
                8 => -1.0e3f32..1.0e3,
                1 => Just(f32::NAN), 1 => Just(f32::INFINITY), 1 => Just(f32::NEG_INFINITY),
                1 => Just(-0.0f32), 1 => Just(f32::MAX), 1 => Just(-f32::MAX),
                1 => Just(f32::MIN_POSITIVE), 1 => Just(1.0e-30f32), 1 => Just(3.0e30f32),
            ],
            14 * 40 * 4,
        ),
    ) {
        // The column-vectorised kernel keeps every output's nine f64 terms in the definition's
        // order, so it equals the plain-loop reference bit for bit, specials and extreme
        // magnitudes (where f64 sums round) included. A NaN's sign and payload are not part of
        // the contract (the compiler may commute an addition's operands), only that it is NaN.
        let img = Array3::from_shape_fn((h, w, c), |(y, x, ch)| vals[(y * w + x) * c + ch]);
        let fast = downsample2x(img.view()).unwrap();
        let want = downsample2x_reference(img.view()).unwrap();
        prop_assert_eq!(fast.dim(), want.dim());
        let canon = |a: &Array3<f32>| a.iter().map(|v| if v.is_nan() { u32::MAX } else { v.to_bits() }).collect::<Vec<_>>();
        prop_assert_eq!(canon(&fast), canon(&want));
        // Each CPU-feature level handed in explicitly (issue 33 item 3): the same bits.
        for level in densefeat::runtime::CpuFeatureLevel::ALL {
            let at = densefeat::ops::downsample2x_at(img.view(), level).unwrap();
            prop_assert_eq!(canon(&at), canon(&want), "{:?}", level);
        }
    }

    #[test]
    fn downsample_is_exact_on_affine_images(h in 1usize..12, w in 1usize..12, a in -8i32..8, b in -8i32..8, c0 in -64i32..64) {
        // Small-integer affine images: every tent sum is exact, so interior samples equal the
        // image at 2j and border samples the replicated-edge average.
        let img = Array3::from_shape_fn((h, w, 1), |(y, x, _)| (a * x as i32 + b * y as i32 + c0) as f32);
        let out = downsample2x(img.view()).unwrap();
        let clamp = |v: isize, n: usize| v.clamp(0, n as isize - 1) as f64;
        for ((j, i, _), &v) in out.indexed_iter() {
            let ey = (clamp(2 * j as isize - 1, h) + 2.0 * (2 * j) as f64 + clamp(2 * j as isize + 1, h)) / 4.0;
            let ex = (clamp(2 * i as isize - 1, w) + 2.0 * (2 * i) as f64 + clamp(2 * i as isize + 1, w)) / 4.0;
            let want = a as f64 * ex + b as f64 * ey + c0 as f64;
            prop_assert_eq!(v as f64, want, "at ({}, {})", j, i);
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Determinism

#[test]
fn im2col_output_independent_of_thread_count() {
    for (shape, seed) in [((37, 29, 35, 32, 1), 7), ((41, 30, 32, 8, 2), 8), ((5, 300, 3, 32, 1), 9)] {
        let case = ConvCase::new(shape, Activation::Relu, seed);
        let run = |n| thread_pool(n).install(|| case.run(Conv2dImpl::Im2colGemm));
        let one = run(1);
        for n in [2, 3, 8] {
            assert_eq!(bits(&run(n)), bits(&one), "shape {shape:?}, threads = {n}");
        }
    }
}

#[test]
fn direct_output_independent_of_thread_count() {
    for (shape, seed) in [
        ((37, 29, 35, 32, 1), 7),
        ((41, 30, 32, 8, 2), 8),
        ((5, 300, 3, 32, 1), 9),
        ((66, 47, 32, 32, 2), 10),
    ] {
        let case = ConvCase::new(shape, Activation::Relu, seed);
        for kernel in DirectKernel::ALL.into_iter().filter(|k| k.supports(&case.g)) {
            let run = |n| thread_pool(n).install(|| case.run_direct(kernel));
            let one = run(1);
            for n in [2, 3, 8] {
                assert_eq!(bits(&run(n)), bits(&one), "shape {shape:?}, {}, threads = {n}", kernel.name());
            }
        }
        let auto = thread_pool(3).install(|| case.run(Conv2dImpl::Direct));
        assert_eq!(bits(&auto), bits(&case.run_direct(DirectKernel::select(&case.g))), "shape {shape:?}");
    }
}

#[test]
fn direct_concat_output_independent_of_thread_count() {
    for (shape, ca, seed) in
        [((37, 29, 35, 32, 2), 32, 11), ((41, 30, 35, 32, 1), 3, 12), ((66, 47, 35, 8, 2), 32, 13)]
    {
        let case = ConvCase::new(shape, Activation::Relu, seed);
        for kernel in DirectKernel::ALL.into_iter().filter(|k| k.supports(&case.g)) {
            let run = |n| thread_pool(n).install(|| case.run_direct_concat(kernel, ca));
            let one = run(1);
            for n in [2, 3, 8] {
                assert_eq!(bits(&run(n)), bits(&one), "shape {shape:?}, {}, threads = {n}", kernel.name());
            }
        }
    }
}

#[test]
fn direct_concat_rejects_bad_channel_splits_and_lengths() {
    let case = ConvCase::new((5, 6, 35, 32, 2), Activation::None, 3);
    let packed = PackedConv2d::new(&case.g, case.w.view(), case.b.view()).unwrap();
    let (a, b) = case.split(32);
    let (sa, sb) = (a.as_slice().unwrap(), b.as_slice().unwrap());
    let mut out = vec![0.0; case.g.output_shape().iter().product()];
    let k = DirectKernel::Portable;
    assert!(conv2d_direct_concat_with(k, &packed, (sa, 32), (sb, 3), Activation::None, &mut out).is_ok());
    assert!(conv2d_direct_concat_with(k, &packed, (sa, 32), (sb, 4), Activation::None, &mut out).is_err());
    assert!(conv2d_direct_concat_with(k, &packed, (sa, 35), (&[], 0), Activation::None, &mut out).is_err());
    assert!(
        conv2d_direct_concat_with(k, &packed, (&sa[1..], 32), (sb, 3), Activation::None, &mut out).is_err()
    );
    assert!(
        conv2d_direct_concat_with(k, &packed, (sa, 32), (sb, 3), Activation::None, &mut out[1..]).is_err()
    );
    let wrong = Array3::<f32>::zeros((4, 6, 3));
    let r = conv2d_concat_into(
        Conv2dImpl::Direct,
        &case.g,
        a.view(),
        wrong.view(),
        case.w.view(),
        case.b.view(),
        Activation::None,
        &mut out,
    );
    assert!(r.is_err());
}

#[test]
fn direct_selects_the_avx512_kernel_exactly_when_available() {
    let g32 = Conv2dGeometry::new(9, 40, 35, 32, 2).unwrap();
    let g8 = Conv2dGeometry::new(9, 40, 35, 8, 2).unwrap();
    let avx512 = cfg!(target_arch = "x86_64") && avx512f_available();
    let avx2 = cfg!(target_arch = "x86_64") && avx2_fma_available();
    let want = match (avx512, avx2) {
        (true, _) => "avx512f-14x32",
        (false, true) => "avx2-6x16",
        _ => "portable",
    };
    assert_eq!(direct::kernel_name(&g32), want);
    assert_eq!(direct::kernel_name(&g8), "portable");
    assert_eq!(DirectKernel::Avx512F.supports(&g32), avx512);
    assert_eq!(DirectKernel::Avx2Fma.supports(&g32), avx2);
    assert!(!DirectKernel::Avx512F.supports(&g8));
    assert!(!DirectKernel::Avx2Fma.supports(&g8));
    let simd = avx512 || avx2;
    assert_eq!(Conv2dImpl::fastest(), if simd { Conv2dImpl::Direct } else { Conv2dImpl::Im2colGemm });
    assert_eq!(Conv2dImpl::default(), Conv2dImpl::fastest());
    assert_eq!(Conv2dImpl::fastest_for(&g8), Conv2dImpl::Im2colGemm);
    // conv2d_direct reports the kernel that ran; an unavailable kernel is an error, not a fallback.
    let case = ConvCase::new((9, 40, 35, 8, 2), Activation::None, 4);
    let packed = PackedConv2d::new(&case.g, case.w.view(), case.b.view()).unwrap();
    let mut out = vec![0.0; case.g.output_shape().iter().product()];
    let x = case.x.as_slice().unwrap();
    assert_eq!(conv2d_direct(&packed, x, Activation::None, &mut out).unwrap(), DirectKernel::Portable);
    assert!(conv2d_direct_with(DirectKernel::Avx512F, &packed, x, Activation::None, &mut out).is_err());
    assert!(conv2d_direct_with(DirectKernel::Avx2Fma, &packed, x, Activation::None, &mut out).is_err());
    // Machines that run the AVX-512 checks say so in the test log.
    eprintln!("direct kernel for c_out = 32: {}", direct::kernel_name(&g32));
}

#[cfg(target_arch = "x86_64")]
fn avx512f_available() -> bool {
    std::arch::is_x86_feature_detected!("avx512f")
        && std::env::var_os(densefeat::runtime::NO_AVX512_ENV).is_none()
}

#[cfg(target_arch = "x86_64")]
fn avx2_fma_available() -> bool {
    std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma")
}

#[cfg(not(target_arch = "x86_64"))]
fn avx2_fma_available() -> bool {
    false
}

/// The two FMA kernels accumulate every output in the same order with one FMA per product, so
/// they agree bit for bit (SPEC.md §7.7), on every network shape and on odd ones.
#[test]
fn avx2_kernel_gives_the_avx512_kernels_bits() {
    for (shape, seed) in [
        ((37, 29, 35, 32, 1), 1),
        ((41, 30, 32, 32, 2), 2),
        ((5, 300, 3, 32, 1), 3),
        ((66, 47, 3, 32, 2), 4),
        ((1, 1, 32, 32, 1), 5),
        ((2, 13, 7, 32, 2), 6),
    ] {
        let case = ConvCase::new(shape, Activation::Relu, seed);
        if DirectKernel::Avx512F.supports(&case.g) && DirectKernel::Avx2Fma.supports(&case.g) {
            let (a, b) = (case.run_direct(DirectKernel::Avx512F), case.run_direct(DirectKernel::Avx2Fma));
            assert_eq!(bits(&a), bits(&b), "shape {shape:?}");
            let (a, b) = (
                case.run_direct_concat(DirectKernel::Avx512F, 2),
                case.run_direct_concat(DirectKernel::Avx2Fma, 2),
            );
            assert_eq!(bits(&a), bits(&b), "concat, shape {shape:?}");
        }
    }
}

#[cfg(not(target_arch = "x86_64"))]
fn avx512f_available() -> bool {
    false
}

#[test]
fn im2col_output_independent_of_scratch_lanes() {
    let case = ConvCase::new((37, 29, 35, 32, 1), Activation::None, 3);
    let packed = PackedConv2d::new(&case.g, case.w.view(), case.b.view()).unwrap();
    let run = |lanes: usize| {
        let mut scratch = vec![0.0; lanes * scratch_len(&case.g)];
        let mut out = vec![0.0f32; case.g.output_shape().iter().product()];
        conv2d_im2col(&packed, case.x.as_slice().unwrap(), Activation::None, &mut scratch, &mut out).unwrap();
        out.iter().map(|v| v.to_bits()).collect::<Vec<_>>()
    };
    let one = run(1);
    for lanes in [2, 3, 64] {
        assert_eq!(run(lanes), one, "lanes = {lanes}");
    }
}

#[test]
fn deconv_output_independent_of_thread_count() {
    let case = DeconvCase::new(19, 23, 35, 32, 11);
    let direct = |n| thread_pool(n).install(|| case.run(Deconv2dImpl::Direct));
    let one = direct(1);
    for n in [2, 3, 8] {
        assert_eq!(bits(&direct(n)), bits(&one), "direct, threads = {n}");
    }
    let run = |n| thread_pool(n).install(|| case.run(Deconv2dImpl::ParityGemm));
    let one = run(1);
    for n in [2, 3, 8] {
        assert_eq!(bits(&run(n)), bits(&one), "threads = {n}");
    }
    let packed = PackedDeconv2d::new(&case.g, case.w.view(), case.b.view()).unwrap();
    for kernel in [DirectKernel::Avx512F, DirectKernel::Avx2Fma] {
        let run = |n| {
            let mut out = vec![0.0f32; case.g.output_shape().iter().product()];
            let x = case.x.as_slice().unwrap();
            let ok =
                thread_pool(n).install(|| deconv2d_direct_with(kernel, &packed, x, None, &mut out).is_ok());
            ok.then(|| bits_of(&out))
        };
        let one = run(1);
        for n in [2, 3, 8] {
            assert_eq!(run(n), one, "{}, threads = {n}", kernel.name());
        }
    }
    let mut out = vec![0.0f32; case.g.output_shape().iter().product()];
    let mut scratch = vec![0.0; deconv_scratch_len(&case.g)];
    deconv2d_fast(&packed, case.x.as_slice().unwrap(), &mut scratch, &mut out).unwrap();
    assert_eq!(out.iter().map(|v| v.to_bits()).collect::<Vec<_>>(), bits(&one), "one lane");
}

#[test]
fn downsample_output_independent_of_thread_count() {
    let mut next = lcg(5);
    let img = Array3::from_shape_simple_fn((57, 43, 3), &mut next);
    let run = |n| thread_pool(n).install(|| downsample2x(img.view()).unwrap());
    let one = run(1);
    for n in [2, 3, 8] {
        assert_eq!(bits(&run(n)), bits(&one), "threads = {n}");
    }
}

// ---------------------------------------------------------------------------------------------
// Known answers (PyTorch semantics)

/// `(x, w, b)` as absolute values in f64, for the Winograd magnitudes.
type AbsF64 = (Array3<f64>, Array4<f64>, Array1<f64>);

/// Holds an F(4x4, 3x3) result to its budget (SPEC.md §7.11) against the reference: its weight
/// transform has factors 1/6, 1/12 and 1/24, which binary cannot hold exactly, so known answers
/// that are exact in f32 are not exact for it. `magnitude` gets the inputs' absolute values.
fn hold_f4_to_budget(
    got: Array3<f32>,
    want: Array3<f32>,
    c_in: usize,
    (x, w, b): (&Array3<f32>, &Array4<f32>, &Array1<f32>),
    magnitude: impl Fn(AbsF64) -> Array3<f64>,
) {
    let f = |v: &f32| f64::from(v.abs());
    let mag = magnitude((x.map(f), w.map(f), b.map(f))).mapv(|v| v as f32);
    within_budget(got.view(), want.view(), mag.view(), winograd_budget(WinogradTile::F4x4, c_in)).unwrap();
}

/// Every implementation's output, for known answers that are exact in f32, except F(4x4), which is
/// held to its budget instead ([`hold_f4_to_budget`]).
fn conv_all(g: &Conv2dGeometry, x: &Array3<f32>, w: &Array4<f32>, b: &Array1<f32>) -> Vec<Array3<f32>> {
    let run = |imp| conv2d(imp, g, x.view(), w.view(), b.view(), Activation::None).unwrap();
    if Conv2dImpl::WinogradF4.supports(g) {
        hold_f4_to_budget(
            run(Conv2dImpl::WinogradF4),
            run(Conv2dImpl::Reference),
            g.c_in(),
            (x, w, b),
            |a| {
                winograd_magnitude_reference(WinogradTile::F4x4, g, a.0.view(), a.1.view(), a.2.view())
                    .unwrap()
            },
        );
    }
    Conv2dImpl::ALL
        .iter()
        .filter(|imp| imp.supports(g) && **imp != Conv2dImpl::WinogradF4)
        .map(|&imp| run(imp))
        .collect()
}

#[test]
fn conv_ones_kernel_sums_neighbourhoods_like_pytorch() {
    // torch.nn.functional.conv2d(torch.arange(1., 10.).view(1, 1, 3, 3), torch.ones(1, 1, 3, 3),
    //                            padding=1, stride=s)
    let x = Array3::from_shape_fn((3, 3, 1), |(y, x, _)| (3 * y + x + 1) as f32);
    let w = Array4::ones((1, 1, 3, 3));
    let b = array![0.0f32];
    let g1 = Conv2dGeometry::new(3, 3, 1, 1, 1).unwrap();
    for y in conv_all(&g1, &x, &w, &b) {
        assert_eq!(
            y.into_shape_with_order((3, 3)).unwrap(),
            array![[12.0, 21.0, 16.0], [27.0, 45.0, 33.0], [24.0, 39.0, 28.0]]
        );
    }
    let g2 = Conv2dGeometry::new(3, 3, 1, 1, 2).unwrap();
    for y in conv_all(&g2, &x, &w, &b) {
        assert_eq!(y.into_shape_with_order((2, 2)).unwrap(), array![[12.0, 16.0], [24.0, 28.0]]);
    }
}

#[test]
fn conv_stride2_centre_delta_picks_input_pixel_2j() {
    // SPEC §2.1: stride-2 output j is centred on input pixel 2j.
    let (h, w, c) = (7, 6, 3);
    let x = Array3::from_shape_fn((h, w, c), |(y, x, ch)| (100 * y + 10 * x + ch) as f32);
    let mut wt = Array4::zeros((c, c, 3, 3));
    for ch in 0..c {
        wt[[ch, ch, 1, 1]] = 1.0;
    }
    let g = Conv2dGeometry::new(h, w, c, c, 2).unwrap();
    assert_eq!(g.output_shape(), [4, 3, c]);
    for y in conv_all(&g, &x, &wt, &Array1::zeros(c)) {
        assert_eq!(y, x.slice(s![..;2, ..;2, ..]));
    }
}

#[test]
fn conv_is_cross_correlation_not_convolution() {
    // Only tap (ky, kx) = (0, 0) set: out[y, x] = in[y - 1, x - 1] (a flipped kernel would read
    // in[y + 1, x + 1]).
    let x = Array3::from_shape_fn((4, 5, 1), |(y, x, _)| (10 * y + x + 1) as f32);
    let mut wt = Array4::zeros((1, 1, 3, 3));
    wt[[0, 0, 0, 0]] = 1.0;
    let g = Conv2dGeometry::new(4, 5, 1, 1, 1).unwrap();
    for y in conv_all(&g, &x, &wt, &array![0.5]) {
        for ((yy, xx, _), &v) in y.indexed_iter() {
            let want = if yy == 0 || xx == 0 { 0.0 } else { x[[yy - 1, xx - 1, 0]] };
            assert_eq!(v, want + 0.5, "at ({yy}, {xx})");
        }
    }
}

#[test]
fn conv_weight_layout_is_out_in_ky_kx() {
    // w[o, c, 1, 1] = 10 o + c + 1: out[.., o] = Σ_c (10 o + c + 1) in[.., c].
    let x = Array3::from_shape_fn((2, 2, 2), |(y, x, c)| [1.0, 100.0][c] * (1 + y + x) as f32);
    let mut wt = Array4::zeros((3, 2, 3, 3));
    for o in 0..3 {
        for c in 0..2 {
            wt[[o, c, 1, 1]] = (10 * o + c + 1) as f32;
        }
    }
    let g = Conv2dGeometry::new(2, 2, 2, 3, 1).unwrap();
    for y in conv_all(&g, &x, &wt, &array![0.0, 0.0, 0.0]) {
        for ((yy, xx, o), &v) in y.indexed_iter() {
            let want = (10 * o + 1) as f32 * x[[yy, xx, 0]] + (10 * o + 2) as f32 * x[[yy, xx, 1]];
            assert_eq!(v, want);
        }
    }
}

#[test]
fn conv_relu_clamps_negative_outputs() {
    let x = array![[[1.0f32], [-2.0]]];
    let mut wt = Array4::zeros((1, 1, 3, 3));
    wt[[0, 0, 1, 1]] = 1.0;
    let g = Conv2dGeometry::new(1, 2, 1, 1, 1).unwrap();
    for imp in Conv2dImpl::ALL {
        let y = conv2d(imp, &g, x.view(), wt.view(), array![0.5].view(), Activation::Relu).unwrap();
        assert_eq!(y, array![[[1.5f32], [0.0]]], "{imp:?}");
    }
}

/// Every implementation's output, except F(4x4), held to its budget ([`hold_f4_to_budget`]; F(2x2)
/// is exact on these small integers).
fn deconv_all(g: &Deconv2dGeometry, x: &Array3<f32>, w: &Array4<f32>, b: &Array1<f32>) -> Vec<Array3<f32>> {
    let run = |imp| deconv2d(imp, g, x.view(), w.view(), b.view()).unwrap();
    hold_f4_to_budget(
        run(Deconv2dImpl::WinogradF4),
        run(Deconv2dImpl::Reference),
        g.c_in(),
        (x, w, b),
        |a| {
            deconv2d_winograd_magnitude_reference(WinogradTile::F4x4, g, a.0.view(), a.1.view(), a.2.view())
                .unwrap()
        },
    );
    Deconv2dImpl::ALL.iter().filter(|imp| **imp != Deconv2dImpl::WinogradF4).map(|&imp| run(imp)).collect()
}

#[test]
fn deconv_impulse_spreads_unflipped_kernel_over_2i_minus_2_to_2i_plus_2() {
    // torch.nn.ConvTranspose2d(1, 1, 5, stride=2, padding=2, output_padding=1): an impulse at input
    // (iy, ix) writes w[ky, kx] at output (2 iy - 2 + ky, 2 ix - 2 + kx), cropped to 2h x 2w.
    let kernel = Array4::from_shape_fn((1, 1, 5, 5), |(_, _, ky, kx)| (10 * ky + kx + 1) as f32);
    let g = Deconv2dGeometry::new(4, 3, 1, 1).unwrap();
    assert_eq!(g.output_shape(), [8, 6, 1]);
    for (iy, ix) in [(0, 0), (2, 1), (3, 2), (1, 1)] {
        let mut x = Array3::zeros((4, 3, 1));
        x[[iy, ix, 0]] = 1.0;
        for y in deconv_all(&g, &x, &kernel, &array![0.0]) {
            for ((oy, ox, _), &v) in y.indexed_iter() {
                let (ky, kx) = (oy as isize - 2 * iy as isize + 2, ox as isize - 2 * ix as isize + 2);
                let want = if (0..5).contains(&ky) && (0..5).contains(&kx) {
                    kernel[[0, 0, ky as usize, kx as usize]]
                } else {
                    0.0
                };
                assert_eq!(v, want, "impulse ({iy}, {ix}), output ({oy}, {ox})");
            }
        }
    }
}

#[test]
fn deconv_weight_layout_is_in_out_ky_kx() {
    // c_in = 2, c_out = 3; an impulse in input channel 1 reproduces w[1, co, .., ..] in channel co.
    let w =
        Array4::from_shape_fn((2, 3, 5, 5), |(ci, co, ky, kx)| (1000 * ci + 100 * co + 10 * ky + kx) as f32);
    let g = Deconv2dGeometry::new(3, 3, 2, 3).unwrap();
    let mut x = Array3::zeros((3, 3, 2));
    x[[1, 1, 1]] = 1.0;
    for y in deconv_all(&g, &x, &w, &array![0.25, 0.5, 0.75]) {
        for co in 0..3 {
            for ky in 0..5 {
                for kx in 0..5 {
                    assert_eq!(y[[ky, kx, co]], w[[1, co, ky, kx]] + [0.25, 0.5, 0.75][co]);
                }
            }
        }
    }
}

#[test]
fn downsample_of_a_constant_is_the_constant() {
    for (h, w) in [(1, 1), (1, 4), (5, 1), (6, 7), (9, 8)] {
        let img = Array3::from_elem((h, w, 3), 0.1f32);
        let out = downsample2x(img.view()).unwrap();
        assert_eq!(out.dim(), (h.div_ceil(2), w.div_ceil(2), 3));
        assert!(out.iter().all(|&v| v == 0.1f32), "{h}x{w}");
    }
}

#[test]
fn downsample_of_a_ramp_samples_it_at_2j() {
    // Interior: the tent is symmetric, so a ramp keeps its value at 2j. Border: the replicated
    // edge pulls the value by a quarter step.
    let img = Array3::from_shape_fn((1, 7, 1), |(_, x, _)| 4.0 * x as f32);
    let out = downsample2x(img.view()).unwrap();
    assert_eq!(out.into_raw_vec_and_offset().0, vec![1.0, 8.0, 16.0, 23.0]);
    let img = Array3::from_shape_fn((6, 1, 1), |(y, _, _)| 4.0 * y as f32);
    let out = downsample2x(img.view()).unwrap();
    assert_eq!(out.into_raw_vec_and_offset().0, vec![1.0, 8.0, 16.0]);
}

// ---------------------------------------------------------------------------------------------
// Shapes, helpers and errors

#[test]
fn output_sizes_follow_spec() {
    for n in 1..40 {
        let g1 = Conv2dGeometry::new(n, n + 1, 1, 1, 1).unwrap();
        assert_eq!((g1.h_out(), g1.w_out()), (n, n + 1));
        let g2 = Conv2dGeometry::new(n, n + 1, 1, 1, 2).unwrap();
        assert_eq!((g2.h_out(), g2.w_out()), (n.div_ceil(2), (n + 1).div_ceil(2)));
        let d = Deconv2dGeometry::new(n, n + 1, 1, 1).unwrap();
        assert_eq!((d.h_out(), d.w_out()), (2 * n, 2 * n + 2));
        assert_eq!(
            DownsampleGeometry::new(n, n + 1, 3).unwrap().output_shape(),
            [n.div_ceil(2), (n + 1).div_ceil(2), 3]
        );
    }
}

#[test]
fn geometry_rejects_zero_sizes_and_bad_strides() {
    assert!(Conv2dGeometry::new(0, 4, 1, 1, 1).is_err());
    assert!(Conv2dGeometry::new(4, 4, 0, 1, 1).is_err());
    assert!(Conv2dGeometry::new(4, 4, 1, 0, 2).is_err());
    for s in [0, 3, 4] {
        assert!(Conv2dGeometry::new(4, 4, 1, 1, s).is_err(), "stride {s}");
    }
    assert!(Conv2dGeometry::new(usize::MAX / 2, 4, 8, 8, 1).is_err());
    assert!(Deconv2dGeometry::new(4, 0, 1, 1).is_err());
    assert!(Deconv2dGeometry::new(usize::MAX / 2, 1, 1, 1).is_err());
    assert!(DownsampleGeometry::new(1, usize::MAX, 1).is_err());
    assert!(Deconv2dGeometry::new(4, 4, 1, 0).is_err());
    assert!(DownsampleGeometry::new(4, 4, 0).is_err());
}

#[test]
fn kernels_reject_mismatched_shapes_and_short_scratch() {
    let case = ConvCase::new((5, 6, 3, 8, 1), Activation::None, 1);
    let other = Conv2dGeometry::new(5, 7, 3, 8, 1).unwrap();
    for imp in Conv2dImpl::ALL {
        assert!(conv2d(imp, &other, case.x.view(), case.w.view(), case.b.view(), Activation::None).is_err());
        assert!(conv2d(
            imp,
            &case.g,
            case.x.view(),
            case.w.view(),
            Array1::zeros(7).view(),
            Activation::None
        )
        .is_err());
    }
    let packed = PackedConv2d::new(&case.g, case.w.view(), case.b.view()).unwrap();
    let mut out = vec![0.0; case.g.output_shape().iter().product()];
    let x = case.x.as_slice().unwrap();
    assert!(conv2d_direct(&packed, &x[1..], Activation::None, &mut out).is_err());
    assert!(conv2d_direct(&packed, x, Activation::None, &mut out[1..]).is_err());
    let mut short = vec![0.0; scratch_len(&case.g) - 1];
    assert!(
        conv2d_im2col(&packed, case.x.as_slice().unwrap(), Activation::None, &mut short, &mut out).is_err()
    );
    let d = DeconvCase::new(3, 4, 2, 5, 1);
    let bad = Array4::zeros((5, 2, 5, 5)); // [c_out, c_in] is the Conv2d layout, not ConvTranspose2d's
    for imp in Deconv2dImpl::ALL {
        assert!(deconv2d(imp, &d.g, d.x.view(), bad.view(), d.b.view()).is_err());
    }
}

#[test]
fn concat_and_add_are_channels_last() {
    let a = Array3::from_shape_fn((2, 3, 2), |(y, x, c)| (100 * y + 10 * x + c) as f32);
    let b = Array3::from_shape_fn((2, 3, 1), |(y, x, _)| -((100 * y + 10 * x) as f32));
    let cat = concat_channels(a.view(), b.view()).unwrap();
    assert_eq!(cat.dim(), (2, 3, 3));
    assert_eq!(cat.slice(s![.., .., ..2]), a);
    assert_eq!(cat.slice(s![.., .., 2..]), b);
    assert!(concat_channels(a.view(), Array3::zeros((2, 4, 1)).view()).is_err());
    let sum = add(a.view(), a.view()).unwrap();
    assert_eq!(sum, &a * 2.0);
    assert!(add(a.view(), b.view()).is_err());
}

#[test]
fn within_budget_reports_first_mismatches() {
    let want = Array1::from_elem(10, 1.0f32);
    let got = Array1::from_shape_fn(10, |i| if i >= 2 { 1.5 } else { 1.0 });
    let err = within_budget(got.view(), want.view(), want.view(), 0.1).unwrap_err();
    assert_eq!(err.count, 8);
    assert_eq!(err.first.len(), 5);
    assert_eq!(err.first[0].index, vec![2]);
    let text = err.to_string();
    assert!(text.contains("8 of 10") && text.contains("and 3 more"), "{text}");
    assert!(within_budget(want.view(), want.view(), want.view(), 0.0).is_ok());
}
