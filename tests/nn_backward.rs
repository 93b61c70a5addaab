//! Backward passes of the network's kernels (SPEC.md §7.8): the f64 references against central
//! finite differences of the f64 forward references (directional derivatives), the fast f32
//! versions against the f64 references within the §7.5-style budget, bit-identical results for any
//! thread count, and the ReLU's backward convention.

use densefeat::ops::conv2d::{
    conv2d_backward_input, conv2d_backward_input_reference, conv2d_backward_weight,
    conv2d_backward_weight_reference, conv2d_reference, relu_backward,
};
use densefeat::ops::deconv2d::{
    deconv2d_backward_input, deconv2d_backward_input_reference, deconv2d_backward_weight,
    deconv2d_backward_weight_reference, deconv2d_reference,
};
use densefeat::ops::{Activation, Conv2dGeometry, Deconv2dGeometry};
use densefeat::testing::within_budget;
use ndarray::{array, Array, Array1, Array3, Array4, Dimension};
use proptest::prelude::*;

// ---------------------------------------------------------------------------------------------
// Cases

/// Values in [-1, 1) from a seeded LCG (all randomness comes from the proptest seed).
fn lcg(seed: u64) -> impl FnMut() -> f64 {
    let mut s = seed ^ 0x9E37_79B9_7F4A_7C15;
    move || {
        s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        ((s >> 40) as f32 / (1u64 << 23) as f32 - 1.0) as f64
    }
}

fn bits<D: Dimension>(a: &Array<f32, D>) -> Vec<u32> {
    a.iter().map(|v| v.to_bits()).collect()
}

fn thread_pool(n: usize) -> rayon::ThreadPool {
    rayon::ThreadPoolBuilder::new().num_threads(n).build().unwrap()
}

fn dot<D: Dimension>(a: &Array<f64, D>, b: &Array<f64, D>) -> f64 {
    assert_eq!(a.shape(), b.shape());
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

fn f32s<D: Dimension>(a: &Array<f64, D>) -> Array<f32, D> {
    a.mapv(|v| v as f32)
}

fn abs<D: Dimension>(a: &Array<f64, D>) -> Array<f64, D> {
    a.mapv(f64::abs)
}

/// A convolution with its operands, an upstream gradient `g` and a probe direction for each of the
/// input, the weight and the bias. Every value is an f32 in [-1, 1), so f64 and f32 runs see the
/// same inputs.
#[derive(Clone, Debug)]
struct ConvCase {
    geom: Conv2dGeometry,
    x: Array3<f64>,
    w: Array4<f64>,
    b: Array1<f64>,
    g: Array3<f64>,
    vx: Array3<f64>,
    vw: Array4<f64>,
    vb: Array1<f64>,
}

impl ConvCase {
    fn new(shape: Shape, seed: u64) -> Self {
        let (h, w, c_in, c_out, stride) = shape;
        let geom = Conv2dGeometry::new(h, w, c_in, c_out, stride).unwrap();
        let mut next = lcg(seed);
        ConvCase {
            geom,
            x: Array3::from_shape_simple_fn(geom.input_shape(), &mut next),
            w: Array4::from_shape_simple_fn(geom.weight_shape(), &mut next),
            b: Array1::from_shape_simple_fn(c_out, &mut next),
            g: Array3::from_shape_simple_fn(geom.output_shape(), &mut next),
            vx: Array3::from_shape_simple_fn(geom.input_shape(), &mut next),
            vw: Array4::from_shape_simple_fn(geom.weight_shape(), &mut next),
            vb: Array1::from_shape_simple_fn(c_out, &mut next),
        }
    }

    /// `L = <g, conv(x, w, b)>` by the f64 forward reference, without activation.
    fn loss(&self, x: &Array3<f64>, w: &Array4<f64>, b: &Array1<f64>) -> f64 {
        let out = conv2d_reference(&self.geom, x.view(), w.view(), b.view(), Activation::None).unwrap();
        dot(&self.g, &out)
    }
}

/// Small shapes for the finite-difference checks.
fn small_cases() -> impl Strategy<Value = ConvCase> {
    (1usize..6, 1usize..6, prop::sample::select(vec![1usize, 3, 4]), prop::sample::select(vec![1usize, 2, 5]))
        .prop_flat_map(|(h, w, c_in, c_out)| (Just((h, w, c_in, c_out)), 1usize..=2, any::<u64>()))
        .prop_map(|((h, w, c_in, c_out), stride, seed)| ConvCase::new((h, w, c_in, c_out, stride), seed))
}

/// Sizes that stress borders and strides, with the network's channel counts.
const SIZES: [usize; 8] = [1, 2, 3, 4, 5, 8, 16, 17];
const C_INS: [usize; 4] = [1, 3, 32, 35];
const C_OUTS: [usize; 3] = [1, 8, 32];

fn fast_cases() -> impl Strategy<Value = ConvCase> {
    (
        prop::sample::select(SIZES.to_vec()),
        prop::sample::select(SIZES.to_vec()),
        prop::sample::select(C_INS.to_vec()),
        prop::sample::select(C_OUTS.to_vec()),
        1usize..=2,
        any::<u64>(),
    )
        .prop_map(|(h, w, c_in, c_out, stride, seed)| ConvCase::new((h, w, c_in, c_out, stride), seed))
}

/// Step of the central differences, and the tolerance `TOL (1 + |analytic|)`. The convolution is
/// linear in each operand, so the central difference is exact up to rounding.
const H: f64 = 1e-6;
const TOL: f64 = 1e-6;

fn close(numeric: f64, analytic: f64) -> bool {
    (numeric - analytic).abs() <= TOL * (1.0 + analytic.abs())
}

/// The §7.5-style budget for a sum of `k` products: `2 k ε_f32 Σ|terms|`.
fn budget(k: usize) -> f32 {
    2.0 * k as f32 * f32::EPSILON
}

// ---------------------------------------------------------------------------------------------
// References against finite differences

proptest! {
    #[test]
    fn conv_backward_input_matches_central_difference(case in small_cases()) {
        let c = &case;
        let numeric = (c.loss(&(&c.x + &(H * &c.vx)), &c.w, &c.b) - c.loss(&(&c.x - &(H * &c.vx)), &c.w, &c.b))
            / (2.0 * H);
        let d_x = conv2d_backward_input_reference(&c.geom, c.g.view(), c.w.view()).unwrap();
        let analytic = dot(&d_x, &c.vx);
        prop_assert!(close(numeric, analytic), "numeric {numeric:e} vs analytic {analytic:e}");
    }

    #[test]
    fn conv_backward_weight_matches_central_difference(case in small_cases()) {
        let c = &case;
        let numeric = (c.loss(&c.x, &(&c.w + &(H * &c.vw)), &c.b) - c.loss(&c.x, &(&c.w - &(H * &c.vw)), &c.b))
            / (2.0 * H);
        let (d_w, _) = conv2d_backward_weight_reference(&c.geom, c.x.view(), c.g.view()).unwrap();
        let analytic = dot(&d_w, &c.vw);
        prop_assert!(close(numeric, analytic), "numeric {numeric:e} vs analytic {analytic:e}");
    }

    #[test]
    fn conv_backward_bias_matches_central_difference(case in small_cases()) {
        let c = &case;
        let numeric = (c.loss(&c.x, &c.w, &(&c.b + &(H * &c.vb))) - c.loss(&c.x, &c.w, &(&c.b - &(H * &c.vb))))
            / (2.0 * H);
        let (_, d_b) = conv2d_backward_weight_reference(&c.geom, c.x.view(), c.g.view()).unwrap();
        let analytic = dot(&d_b, &c.vb);
        prop_assert!(close(numeric, analytic), "numeric {numeric:e} vs analytic {analytic:e}");
    }
}

// ---------------------------------------------------------------------------------------------
// Fast f32 against the f64 references

proptest! {
    #[test]
    fn conv_backward_input_fast_matches_reference(case in fast_cases()) {
        let c = &case;
        let fast = conv2d_backward_input(&c.geom, f32s(&c.g).view(), f32s(&c.w).view()).unwrap();
        let oracle = conv2d_backward_input_reference(&c.geom, c.g.view(), c.w.view()).unwrap();
        let magnitude = conv2d_backward_input_reference(&c.geom, abs(&c.g).view(), abs(&c.w).view()).unwrap();
        let k = 9 * c.geom.c_out();
        within_budget(fast.view(), f32s(&oracle).view(), f32s(&magnitude).view(), budget(k))?;
    }

    #[test]
    fn conv_backward_weight_fast_matches_reference(case in fast_cases()) {
        let c = &case;
        let (fast_w, fast_b) = conv2d_backward_weight(&c.geom, f32s(&c.x).view(), f32s(&c.g).view()).unwrap();
        let (ref_w, ref_b) = conv2d_backward_weight_reference(&c.geom, c.x.view(), c.g.view()).unwrap();
        let (mag_w, mag_b) = conv2d_backward_weight_reference(&c.geom, abs(&c.x).view(), abs(&c.g).view()).unwrap();
        let k = c.geom.h_out() * c.geom.w_out();
        within_budget(fast_w.view(), f32s(&ref_w).view(), f32s(&mag_w).view(), budget(k))?;
        within_budget(fast_b.view(), f32s(&ref_b).view(), f32s(&mag_b).view(), budget(k))?;
    }
}

// ---------------------------------------------------------------------------------------------
// Determinism

/// `(h, w, c_in, c_out, stride)`.
type Shape = (usize, usize, usize, usize, usize);

const DETERMINISM_SHAPES: [(Shape, u64); 3] =
    [((37, 29, 35, 32, 1), 7), ((41, 30, 32, 8, 2), 8), ((5, 300, 3, 32, 1), 9)];

#[test]
fn conv_backward_input_independent_of_thread_count() {
    for (shape, seed) in DETERMINISM_SHAPES {
        let c = ConvCase::new(shape, seed);
        let (g, w) = (f32s(&c.g), f32s(&c.w));
        let run = |n| thread_pool(n).install(|| conv2d_backward_input(&c.geom, g.view(), w.view()).unwrap());
        let one = run(1);
        for n in [2, 3, 8] {
            assert_eq!(bits(&run(n)), bits(&one), "shape {shape:?}, threads = {n}");
        }
    }
}

#[test]
fn conv_backward_weight_independent_of_thread_count() {
    for (shape, seed) in DETERMINISM_SHAPES {
        let c = ConvCase::new(shape, seed);
        let (x, g) = (f32s(&c.x), f32s(&c.g));
        let run = |n| thread_pool(n).install(|| conv2d_backward_weight(&c.geom, x.view(), g.view()).unwrap());
        let (one_w, one_b) = run(1);
        for n in [2, 3, 8] {
            let (d_w, d_b) = run(n);
            assert_eq!(bits(&d_w), bits(&one_w), "weight, shape {shape:?}, threads = {n}");
            assert_eq!(bits(&d_b), bits(&one_b), "bias, shape {shape:?}, threads = {n}");
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Known answers and conventions

#[test]
fn relu_backward_passes_gradient_only_where_positive_zero_at_zero() {
    let pre = array![-2.0f32, -0.0, 0.0, 1e-30, 3.0, f32::NAN];
    let d_out = array![1.0f32, 2.0, 3.0, 4.0, 5.0, 6.0];
    let want = array![0.0f32, 0.0, 0.0, 4.0, 5.0, 0.0];
    assert_eq!(relu_backward(pre.view(), d_out.view()).unwrap(), want);
    // The ReLU's output gives the same mask as its pre-activation.
    let post = pre.mapv(|v| Activation::Relu.apply_f32(v));
    assert_eq!(relu_backward(post.view(), d_out.view()).unwrap(), want);
    assert!(relu_backward(pre.view(), array![1.0f32].view()).is_err());
}

#[test]
fn conv_backward_of_centre_tap_delta_is_identity_on_input() {
    // A kernel with only the centre tap (1 for o = c) is the identity for stride 1; its input
    // gradient is the upstream gradient, and its weight gradient at the centre is <g, x>.
    let geom = Conv2dGeometry::new(3, 4, 1, 1, 1).unwrap();
    let mut w = Array4::<f32>::zeros(geom.weight_shape());
    w[[0, 0, 1, 1]] = 1.0;
    let g = Array3::from_shape_fn(geom.output_shape(), |(y, x, _)| (y * 4 + x) as f32);
    assert_eq!(conv2d_backward_input(&geom, g.view(), w.view()).unwrap(), g);
    let x = Array3::<f32>::ones(geom.input_shape());
    let (d_w, d_b) = conv2d_backward_weight(&geom, x.view(), g.view()).unwrap();
    assert_eq!(d_w[[0, 0, 1, 1]], 66.0);
    assert_eq!(d_w[[0, 0, 0, 0]], (5 + 6 + 7 + 9 + 10 + 11) as f32); // reads (y - 1, x - 1)
    assert_eq!(d_b[0], 66.0);
}

#[test]
fn conv_backward_rejects_mismatched_shapes() {
    let geom = Conv2dGeometry::new(4, 4, 2, 3, 2).unwrap();
    let w = Array4::<f32>::zeros(geom.weight_shape());
    let x = Array3::<f32>::zeros(geom.input_shape());
    let bad_g = Array3::<f32>::zeros((4, 4, 3));
    assert!(conv2d_backward_input(&geom, bad_g.view(), w.view()).is_err());
    assert!(conv2d_backward_weight(&geom, x.view(), bad_g.view()).is_err());
    assert!(conv2d_backward_weight(&geom, bad_g.view(), bad_g.view()).is_err());
}

// ---------------------------------------------------------------------------------------------
// Transposed convolution

/// A transposed convolution with its operands, an upstream gradient and probe directions.
#[derive(Clone, Debug)]
struct DeconvCase {
    geom: Deconv2dGeometry,
    x: Array3<f64>,
    w: Array4<f64>,
    b: Array1<f64>,
    g: Array3<f64>,
    vx: Array3<f64>,
    vw: Array4<f64>,
    vb: Array1<f64>,
}

impl DeconvCase {
    fn new(h: usize, w: usize, c_in: usize, c_out: usize, seed: u64) -> Self {
        let geom = Deconv2dGeometry::new(h, w, c_in, c_out).unwrap();
        let mut next = lcg(seed);
        DeconvCase {
            geom,
            x: Array3::from_shape_simple_fn(geom.input_shape(), &mut next),
            w: Array4::from_shape_simple_fn(geom.weight_shape(), &mut next),
            b: Array1::from_shape_simple_fn(c_out, &mut next),
            g: Array3::from_shape_simple_fn(geom.output_shape(), &mut next),
            vx: Array3::from_shape_simple_fn(geom.input_shape(), &mut next),
            vw: Array4::from_shape_simple_fn(geom.weight_shape(), &mut next),
            vb: Array1::from_shape_simple_fn(c_out, &mut next),
        }
    }

    /// `L = <g, deconv(x, w, b)>` by the f64 forward reference.
    fn loss(&self, x: &Array3<f64>, w: &Array4<f64>, b: &Array1<f64>) -> f64 {
        dot(&self.g, &deconv2d_reference(&self.geom, x.view(), w.view(), b.view()).unwrap())
    }
}

fn small_deconv_cases() -> impl Strategy<Value = DeconvCase> {
    (
        1usize..6,
        1usize..6,
        prop::sample::select(vec![1usize, 3, 4]),
        prop::sample::select(vec![1usize, 2, 5]),
        any::<u64>(),
    )
        .prop_map(|(h, w, c_in, c_out, seed)| DeconvCase::new(h, w, c_in, c_out, seed))
}

fn fast_deconv_cases() -> impl Strategy<Value = DeconvCase> {
    (
        prop::sample::select(SIZES.to_vec()),
        prop::sample::select(SIZES.to_vec()),
        prop::sample::select(C_INS.to_vec()),
        prop::sample::select(C_OUTS.to_vec()),
        any::<u64>(),
    )
        .prop_map(|(h, w, c_in, c_out, seed)| DeconvCase::new(h, w, c_in, c_out, seed))
}

proptest! {
    #[test]
    fn deconv_backward_input_matches_central_difference(case in small_deconv_cases()) {
        let c = &case;
        let numeric = (c.loss(&(&c.x + &(H * &c.vx)), &c.w, &c.b) - c.loss(&(&c.x - &(H * &c.vx)), &c.w, &c.b))
            / (2.0 * H);
        let d_x = deconv2d_backward_input_reference(&c.geom, c.g.view(), c.w.view()).unwrap();
        let analytic = dot(&d_x, &c.vx);
        prop_assert!(close(numeric, analytic), "numeric {numeric:e} vs analytic {analytic:e}");
    }

    #[test]
    fn deconv_backward_weight_matches_central_difference(case in small_deconv_cases()) {
        let c = &case;
        let numeric = (c.loss(&c.x, &(&c.w + &(H * &c.vw)), &c.b) - c.loss(&c.x, &(&c.w - &(H * &c.vw)), &c.b))
            / (2.0 * H);
        let (d_w, _) = deconv2d_backward_weight_reference(&c.geom, c.x.view(), c.g.view()).unwrap();
        let analytic = dot(&d_w, &c.vw);
        prop_assert!(close(numeric, analytic), "numeric {numeric:e} vs analytic {analytic:e}");
    }

    #[test]
    fn deconv_backward_bias_matches_central_difference(case in small_deconv_cases()) {
        let c = &case;
        let numeric = (c.loss(&c.x, &c.w, &(&c.b + &(H * &c.vb))) - c.loss(&c.x, &c.w, &(&c.b - &(H * &c.vb))))
            / (2.0 * H);
        let (_, d_b) = deconv2d_backward_weight_reference(&c.geom, c.x.view(), c.g.view()).unwrap();
        let analytic = dot(&d_b, &c.vb);
        prop_assert!(close(numeric, analytic), "numeric {numeric:e} vs analytic {analytic:e}");
    }

    #[test]
    fn deconv_backward_input_fast_matches_reference(case in fast_deconv_cases()) {
        let c = &case;
        let fast = deconv2d_backward_input(&c.geom, f32s(&c.g).view(), f32s(&c.w).view()).unwrap();
        let oracle = deconv2d_backward_input_reference(&c.geom, c.g.view(), c.w.view()).unwrap();
        let magnitude =
            deconv2d_backward_input_reference(&c.geom, abs(&c.g).view(), abs(&c.w).view()).unwrap();
        let k = 25 * c.geom.c_out();
        within_budget(fast.view(), f32s(&oracle).view(), f32s(&magnitude).view(), budget(k))?;
    }

    #[test]
    fn deconv_backward_weight_fast_matches_reference(case in fast_deconv_cases()) {
        let c = &case;
        let (fast_w, fast_b) =
            deconv2d_backward_weight(&c.geom, f32s(&c.x).view(), f32s(&c.g).view()).unwrap();
        let (ref_w, ref_b) = deconv2d_backward_weight_reference(&c.geom, c.x.view(), c.g.view()).unwrap();
        let (mag_w, mag_b) =
            deconv2d_backward_weight_reference(&c.geom, abs(&c.x).view(), abs(&c.g).view()).unwrap();
        let (hw, k_b) = (c.geom.h() * c.geom.w(), c.geom.h_out() * c.geom.w_out());
        within_budget(fast_w.view(), f32s(&ref_w).view(), f32s(&mag_w).view(), budget(hw))?;
        within_budget(fast_b.view(), f32s(&ref_b).view(), f32s(&mag_b).view(), budget(k_b))?;
    }
}

#[test]
fn deconv_backward_independent_of_thread_count() {
    for (h, w, c_in, c_out, seed) in [(19, 23, 32, 32, 3), (7, 150, 35, 8, 4)] {
        let c = DeconvCase::new(h, w, c_in, c_out, seed);
        let (x, wt, g) = (f32s(&c.x), f32s(&c.w), f32s(&c.g));
        let run = |n| {
            thread_pool(n).install(|| {
                let d_x = deconv2d_backward_input(&c.geom, g.view(), wt.view()).unwrap();
                let (d_w, d_b) = deconv2d_backward_weight(&c.geom, x.view(), g.view()).unwrap();
                (d_x, d_w, d_b)
            })
        };
        let (one_x, one_w, one_b) = run(1);
        for n in [2, 3, 8] {
            let (d_x, d_w, d_b) = run(n);
            assert_eq!(bits(&d_x), bits(&one_x), "input, shape {:?}, threads = {n}", (h, w, c_in, c_out));
            assert_eq!(bits(&d_w), bits(&one_w), "weight, shape {:?}, threads = {n}", (h, w, c_in, c_out));
            assert_eq!(bits(&d_b), bits(&one_b), "bias, shape {:?}, threads = {n}", (h, w, c_in, c_out));
        }
    }
}

#[test]
fn deconv_backward_input_is_a_strided_5x5_convolution_of_the_gradient() {
    // An impulse of g at output (oy, ox) reaches input (iy, ix) through tap (oy - 2iy + 2, ox - 2ix + 2).
    let geom = Deconv2dGeometry::new(3, 3, 1, 1).unwrap();
    let w = Array4::from_shape_fn(geom.weight_shape(), |(_, _, ky, kx)| (5 * ky + kx) as f32);
    let mut g = Array3::<f32>::zeros(geom.output_shape());
    g[[3, 2, 0]] = 1.0;
    let d_x = deconv2d_backward_input(&geom, g.view(), w.view()).unwrap();
    let want = Array3::from_shape_fn(geom.input_shape(), |(iy, ix, _)| {
        let (ky, kx) = (3 + 2 - 2 * iy as isize, 2 + 2 - 2 * ix as isize);
        if (0..5).contains(&ky) && (0..5).contains(&kx) {
            (5 * ky + kx) as f32
        } else {
            0.0
        }
    });
    assert_eq!(d_x, want);
    // Input rows 1 and 2 reach output row 3 through ky = 3 and 1; columns 0, 1, 2 reach column 2
    // through kx = 4, 2, 0.
    assert_eq!(d_x[[1, 1, 0]], 17.0);
}
