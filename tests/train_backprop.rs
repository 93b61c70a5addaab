//! Backpropagation through the whole network (SPEC.md §13.2): directional finite differences of
//! the forward pass, thread-count determinism of the gradients, and the backward passes of the
//! downsampling and concatenation helpers.

use densefeat::backend::CpuBackend;
use densefeat::nn::{FeatureNet, NetworkWeights};
use densefeat::ops::NetworkConfig;
use densefeat::ops::{concat_channels, concat_channels_backward, downsample2x, downsample2x_backward};
use densefeat::train::backprop::{backward, forward_with_tape};
use ndarray::{Array3, ArrayView3};

fn rng(seed: u64) -> impl FnMut() -> f64 {
    let mut r = densefeat::util::rng::SplitMix64::new(seed);
    move || r.range(-1.0, 1.0)
}

fn tiny(b1_stride: usize, blocks: usize) -> NetworkWeights {
    let cfg = NetworkConfig { blocks, channels: 4, b1_stride, input_mean: [109.0, 110.0, 111.0] };
    let mut w = NetworkWeights::xavier_uniform(&cfg, 5).unwrap();
    // Non-zero biases so every bias gradient is exercised.
    let mut r = rng(9);
    for l in w.layers_mut() {
        l.bias.mapv_inplace(|_| 0.1 * r() as f32);
    }
    w
}

fn image(h: usize, w: usize, seed: u64) -> Array3<f32> {
    let mut r = rng(seed);
    // Small deviations from the mean keep activations O(1), so a finite step rarely crosses a
    // ReLU kink.
    Array3::from_shape_fn((h, w, 3), |_| (110.0 + 2.0 * r()) as f32)
}

/// L = Σ_k <R_k, blocks[k]> + <R_a, features> for fixed random R.
struct Probe {
    r_blocks: Vec<Array3<f32>>,
    r_feat: Array3<f32>,
}

impl Probe {
    fn new(cfg: &NetworkConfig, h: usize, w: usize) -> Self {
        let mut r = rng(77);
        let shapes = cfg.output_shapes(h, w);
        let mk = |r: &mut dyn FnMut() -> f64, s: [usize; 3]| Array3::from_shape_fn(s, |_| r() as f32);
        let r_blocks = shapes.iter().map(|&s| mk(&mut r, s)).collect();
        let r_feat = mk(&mut r, shapes[0]);
        Probe { r_blocks, r_feat }
    }
    fn loss(&self, weights: &NetworkWeights, img: ArrayView3<f32>) -> f64 {
        let out = FeatureNet::new(weights.clone()).unwrap().forward(img, &CpuBackend::reference()).unwrap();
        let dot = |a: &Array3<f32>, b: &Array3<f32>| {
            a.iter().zip(b).map(|(x, y)| f64::from(*x) * f64::from(*y)).sum::<f64>()
        };
        let mut l = dot(&out.aggregated[0], &self.r_feat);
        for (b, r) in out.blocks.iter().zip(&self.r_blocks) {
            l += dot(b, r);
        }
        l
    }
    fn grads(&self, weights: &NetworkWeights, img: ArrayView3<f32>, cpu: &CpuBackend) -> NetworkWeights {
        let (_, tape) = forward_with_tape(weights, img, cpu).unwrap();
        let mut g = weights.zeros_like();
        let d_blocks: Vec<_> = self.r_blocks.iter().map(|r| Some(r.view())).collect();
        backward(weights, &tape, &d_blocks, Some(self.r_feat.view()), &mut g).unwrap();
        g
    }
}

#[test]
fn tape_forward_is_the_network_forward() {
    let w = tiny(2, 3);
    let img = image(13, 11, 1);
    let (out, _) = forward_with_tape(&w, img.view(), &CpuBackend::default()).unwrap();
    let want = FeatureNet::new(w).unwrap().forward(img.view(), &CpuBackend::default()).unwrap();
    for (a, b) in out.aggregated.iter().chain(&out.blocks).zip(want.aggregated.iter().chain(&want.blocks)) {
        assert_eq!(a, b);
    }
}

/// Per layer: the directional derivative along a random direction of that layer's weights and
/// bias, analytic against a central difference of the forward pass, for both block-1 strides and a
/// size that needs padding and cropping.
#[test]
fn network_gradients_match_directional_finite_differences() {
    for (b1, blocks, h, w) in [(2, 3, 13, 11), (1, 2, 9, 10)] {
        let weights = tiny(b1, blocks);
        let img = image(h, w, 2);
        let probe = Probe::new(&weights.config, h, w);
        let g = probe.grads(&weights, img.view(), &CpuBackend::default());
        let n_layers = weights.layers().len();
        let mut r = rng(31);
        for li in 0..n_layers {
            let dir_w = weights.layers()[li].weight.mapv(|_| r() as f32);
            let dir_b = weights.layers()[li].bias.mapv(|_| r() as f32);
            let gl = g.layers()[li];
            let analytic: f64 =
                gl.weight.iter().zip(&dir_w).map(|(a, b)| f64::from(*a) * f64::from(*b)).sum::<f64>()
                    + gl.bias.iter().zip(&dir_b).map(|(a, b)| f64::from(*a) * f64::from(*b)).sum::<f64>();
            let eps = 2e-4f32;
            let shifted = |sign: f32| {
                let mut w2 = weights.clone();
                let l = &mut w2.layers_mut()[li];
                l.weight.zip_mut_with(&dir_w, |a, d| *a += sign * eps * d);
                l.bias.zip_mut_with(&dir_b, |a, d| *a += sign * eps * d);
                probe.loss(&w2, img.view())
            };
            let fd = (shifted(1.0) - shifted(-1.0)) / (2.0 * f64::from(eps));
            let err = (fd - analytic).abs() / analytic.abs().max(fd.abs()).max(1.0);
            assert!(err < 2e-3, "b1 stride {b1}, layer {li}: analytic {analytic}, fd {fd}, rel err {err}");
        }
    }
}

#[test]
fn network_gradients_are_bit_identical_for_any_thread_count() {
    let weights = tiny(2, 3);
    let img = image(24, 20, 3);
    let probe = Probe::new(&weights.config, 24, 20);
    let run = |n: usize| {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(n).build().unwrap();
        pool.install(|| probe.grads(&weights, img.view(), &CpuBackend::default()))
    };
    let base = run(1);
    for n in [2, 3, 8] {
        let g = run(n);
        for (a, b) in g.layers().iter().zip(base.layers()) {
            assert!(a.weight.iter().zip(&b.weight).all(|(x, y)| x.to_bits() == y.to_bits()), "{n} threads");
            assert!(a.bias.iter().zip(&b.bias).all(|(x, y)| x.to_bits() == y.to_bits()), "{n} threads");
        }
    }
}

/// Linear maps: the backward pass is the adjoint, `<D x, y> = <x, Dᵀ y>` (to f32 rounding), which
/// is what a finite difference of a linear map measures.
#[test]
fn downsample_and_concat_backward_are_adjoints() {
    for (h, w) in [(7, 5), (8, 8), (1, 3)] {
        let mut r = rng(h as u64 * 31 + w as u64);
        let x = Array3::from_shape_fn((h, w, 2), |_| r() as f32);
        let dx = downsample2x(x.view()).unwrap();
        let y = Array3::from_shape_fn(dx.raw_dim(), |_| r() as f32);
        let dty = downsample2x_backward(y.view(), h, w).unwrap();
        let lhs: f64 = dx.iter().zip(&y).map(|(a, b)| f64::from(*a) * f64::from(*b)).sum();
        let rhs: f64 = x.iter().zip(&dty).map(|(a, b)| f64::from(*a) * f64::from(*b)).sum();
        assert!((lhs - rhs).abs() < 1e-5 * lhs.abs().max(1.0), "{h}x{w}: {lhs} vs {rhs}");
        // Mass is conserved: the tent sums to 1 and edge taps fold onto the edge.
        let ones = Array3::<f32>::ones(dx.raw_dim());
        let back = downsample2x_backward(ones.view(), h, w).unwrap();
        assert!((back.sum() - dx.len() as f32).abs() < 1e-4);
    }
    assert!(downsample2x_backward(Array3::<f32>::zeros((2, 2, 1)).view(), 5, 5).is_err());
    let a = Array3::from_shape_fn((3, 4, 2), |(i, j, k)| (i * 8 + j * 2 + k) as f32);
    let b = Array3::from_shape_fn((3, 4, 3), |(i, j, k)| -((i * 12 + j * 3 + k) as f32));
    let cat = concat_channels(a.view(), b.view()).unwrap();
    let (da, db) = concat_channels_backward(cat.view(), 2).unwrap();
    assert_eq!((da, db), (a, b));
    assert!(concat_channels_backward(cat.view(), 6).is_err());
}
