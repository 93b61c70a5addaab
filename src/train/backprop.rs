//! Backpropagation through the feature network (SPEC.md §13.2): a forward pass that keeps what the
//! backward pass needs (the tape), and the backward pass from gradients on any block output and on
//! the aggregated features to the gradients of every weight and bias.
//!
//! ```text
//! decoder:  dA_0 = d_features;  d_out_k += dA_k;  dA_{k+1} = deconv_kᵀ(dA_k);  dW_deconv_k from (a_{k+1}, dA_k)
//! encoder:  (k = n-1 .. 0)  conv3ᵀ → ReLU mask(x2) → conv2ᵀ → ReLU mask(x1) → conv1ᵀ → split(concat):
//!           the first C channels go to d_out_{k-1}; the image channels are dropped (images are not learned)
//! ```
//!
//! Every kernel is deterministic, and gradients are accumulated in a fixed order (the caller's
//! order of images and scales), so the gradients are bit-identical for any thread count.

use ndarray::{s, Array3, ArrayView3};

use crate::backend::{CpuBackend, LayerOp, NetworkOp, Observed, Observer, Tensor};
use crate::error::{Error, Result};
use crate::nn::network::{run_network, Arena};
use crate::nn::{ForwardOutput, NetworkWeights, PreparedNetwork};
use crate::ops::concat_channels;
use crate::ops::conv2d::backward_fast::conv2d_backward_input_prepared;
use crate::ops::conv2d::{conv2d_backward_weight, relu_backward, Conv2dImpl};
use crate::ops::deconv2d::{deconv2d_backward_input, deconv2d_backward_weight};
use crate::ops::LayerParams;
use crate::ops::PreparedConv;
use crate::ops::{conv_geometry, deconv_geometry};

/// What one block's backward pass needs, at padded size.
#[derive(Clone, Debug)]
struct BlockTape {
    /// The block's input (the image, or the previous output concatenated with the image).
    input: Array3<f32>,
    /// After conv1 + ReLU.
    x1: Array3<f32>,
    /// After conv2 + ReLU.
    x2: Array3<f32>,
}

/// Activations of one forward pass, kept for [`backward`].
#[derive(Clone, Debug)]
pub struct Tape {
    blocks: Vec<BlockTape>,
    /// `aggregated[k]` at padded size (the input of deconv `k - 1`).
    aggregated: Vec<Array3<f32>>,
}

/// The observer that records the tape while the forward pass runs on the CPU backend: (shared
/// handles to, no copies of) the input of every convolution (for a block's first convolution, the
/// two maps it concatenates) and every map before its crop.
#[derive(Default)]
struct TapeRecorder {
    conv_inputs: Vec<ConvInput>,
    uncropped: Vec<Tensor>,
}

/// A convolution's input as the forward pass saw it.
enum ConvInput {
    Map(Tensor),
    /// `concat(a, b)`, `a`'s channels first, which the backend convolves without forming.
    Concat(Tensor, Tensor),
}

impl Observer for TapeRecorder {
    fn observe(&mut self, op: NetworkOp<'_>, _seconds: f64) {
        match op {
            NetworkOp::Conv { input, .. } => self.conv_inputs.push(ConvInput::Map(input.clone())),
            NetworkOp::ConcatConv { a, b, .. } => {
                self.conv_inputs.push(ConvInput::Concat(a.clone(), b.clone()))
            }
            NetworkOp::Crop { input, .. } => self.uncropped.push(input.clone()),
            _ => {}
        }
    }
}

impl ConvInput {
    /// The input as a host map (the concatenation formed now by `concat_channels`, the CPU's op).
    fn into_host(self) -> Array3<f32> {
        match self {
            ConvInput::Map(t) => host(t),
            ConvInput::Concat(a, b) => {
                let (a, b) = (host(a), host(b));
                concat_channels(a.view(), b.view()).expect("the forward pass concatenated maps of one size")
            }
        }
    }
}

/// A host tensor's array, moved out when this is its last handle.
fn host(t: Tensor) -> Array3<f32> {
    t.into_host().expect("the CPU backend returns host tensors")
}

/// The forward pass ([`run_network`], the one the product runs) on the CPU backend `cpu`, also
/// returning the tape: the same ops, hence the same bits, as [`crate::nn::FeatureNet::forward`].
///
/// # Errors
/// [`Error::InvalidArgument`] for a malformed image or weights.
pub fn forward_with_tape(
    weights: &NetworkWeights,
    image: ArrayView3<f32>,
    cpu: &CpuBackend,
) -> Result<(ForwardOutput, Tape)> {
    forward_with_tape_prepared(&PreparedNetwork::new(weights, cpu)?, image, cpu)
}

/// [`forward_with_tape`] on layers already prepared by the CPU backend (a training step prepares
/// its weights once for all its images).
///
/// # Errors
/// As [`forward_with_tape`]; [`Error::Unsupported`] for layers another backend prepared.
pub fn forward_with_tape_prepared(
    net: &PreparedNetwork,
    image: ArrayView3<f32>,
    cpu: &CpuBackend,
) -> Result<(ForwardOutput, Tape)> {
    let observed = Observed::new(cpu, TapeRecorder::default());
    let out = run_network(&observed, &mut Arena::new(), net, image)?;
    let mut tape = observed.into_observer();
    let n = net.config().blocks;
    // run_network runs conv1, conv2, conv3 of each block in order, then crops the n block outputs
    // and the n aggregated maps.
    assert_eq!((tape.conv_inputs.len(), tape.uncropped.len()), (3 * n, 2 * n), "tape of {n} blocks");
    let aggregated = tape.uncropped.split_off(n).into_iter().map(host).collect();
    let mut inputs = tape.conv_inputs.into_iter();
    let blocks = (0..n)
        .map(|_| {
            let mut next = || inputs.next().expect("three convolutions per block").into_host();
            BlockTape { input: next(), x1: next(), x2: next() }
        })
        .collect();
    drop(tape.uncropped);
    let out = ForwardOutput {
        blocks: out.blocks.into_iter().map(host).collect(),
        aggregated: out.aggregated.into_iter().map(host).collect(),
    };
    Ok((out, Tape { blocks, aggregated }))
}

/// `target += update`, elementwise.
fn accumulate(target: &mut LayerParams, d_w: &ndarray::Array4<f32>, d_b: &ndarray::Array1<f32>) {
    target.weight += d_w;
    target.bias += d_b;
}

/// A gradient on a cropped map, zero-padded (bottom/right) to the padded map's shape.
fn pad_gradient(d: Option<ArrayView3<f32>>, like: &Array3<f32>, name: &str) -> Result<Array3<f32>> {
    let mut out = Array3::zeros(like.raw_dim());
    if let Some(d) = d {
        let (h, w, c) = d.dim();
        let (hp, wp, cp) = like.dim();
        if h > hp || w > wp || c != cp {
            return Err(Error::invalid_argument(
                name,
                format!("gradient shape {:?} does not fit {:?}", d.shape(), like.shape()),
            ));
        }
        out.slice_mut(s![..h, ..w, ..]).assign(&d);
    }
    Ok(out)
}

/// Backward pass: adds to `grads` (same shapes as `weights`) the gradient of a loss whose
/// gradients with respect to the (cropped) block outputs are `d_blocks[k]` and with respect to
/// the (cropped) features is `d_features`. `None` means zero.
///
/// # Errors
/// [`Error::InvalidArgument`] if a gradient's shape does not match the forward pass.
pub fn backward(
    weights: &NetworkWeights,
    tape: &Tape,
    d_blocks: &[Option<ArrayView3<f32>>],
    d_features: Option<ArrayView3<f32>>,
    grads: &mut NetworkWeights,
) -> Result<()> {
    let net = PreparedNetwork::new(weights, &CpuBackend::default())?;
    backward_prepared(&net, weights, tape, d_blocks, d_features, grads)
}

/// [`backward`] with `weights`' layers prepared by the CPU backend (`net`, as the forward pass
/// used them): the stride-1 input gradients take their flipped layers from it, made and packed once
/// per prepared network instead of once per call (SPEC.md §7.9). The same bits.
///
/// # Errors
/// As [`backward`]; [`Error::Unsupported`] for layers another backend prepared.
pub fn backward_prepared(
    net: &PreparedNetwork,
    weights: &NetworkWeights,
    tape: &Tape,
    d_blocks: &[Option<ArrayView3<f32>>],
    d_features: Option<ArrayView3<f32>>,
    grads: &mut NetworkWeights,
) -> Result<()> {
    let config = &weights.config;
    let cpu_layer = |k: usize, i: usize| -> Result<&PreparedConv> {
        let l = net.blocks.get(k).map(|b| &b[i]).ok_or_else(|| {
            Error::invalid_argument("backward", "the prepared network has fewer blocks than the weights")
        })?;
        l.data::<PreparedConv>("cpu", LayerOp::Conv3x3)
    };
    let n = config.blocks;
    if d_blocks.len() != n || tape.blocks.len() != n || grads.blocks.len() != n {
        return Err(Error::invalid_argument(
            "backward",
            format!("{} block gradients for {n} blocks", d_blocks.len()),
        ));
    }
    // d_out_k at padded size (the shape of aggregated[k]).
    let mut d_out: Vec<Array3<f32>> =
        (0..n).map(|k| pad_gradient(d_blocks[k], &tape.aggregated[k], "d_blocks")).collect::<Result<_>>()?;
    // Decoder.
    let mut d_a = pad_gradient(d_features, &tape.aggregated[0], "d_features")?;
    for (k, d_out_k) in d_out.iter_mut().enumerate().take(n - 1) {
        *d_out_k += &d_a;
        let layer = &weights.deconvs[k];
        let x = &tape.aggregated[k + 1];
        let g = deconv_geometry(x.dim(), layer)?;
        let (d_w, d_b) = deconv2d_backward_weight(&g, x.view(), d_a.view())?;
        accumulate(&mut grads.deconvs[k], &d_w, &d_b);
        d_a = deconv2d_backward_input(&g, d_a.view(), layer.weight.view())?;
    }
    d_out[n - 1] += &d_a;
    // Encoder, deepest block first.
    for k in (0..n).rev() {
        let t = &tape.blocks[k];
        let block = &weights.blocks[k];
        let gb = &mut grads.blocks[k];
        let g3 = conv_geometry(t.x2.dim(), &block.conv3, 1)?;
        let (d_w, d_b) = conv2d_backward_weight(&g3, t.x2.view(), d_out[k].view())?;
        accumulate(&mut gb.conv3, &d_w, &d_b);
        let d_x2 = conv2d_backward_input_prepared(
            Conv2dImpl::fastest_for(&g3),
            &g3,
            d_out[k].view(),
            cpu_layer(k, 2)?,
        )?;
        let d_x2 = relu_backward(t.x2.view(), d_x2.view())?;
        let g2 = conv_geometry(t.x1.dim(), &block.conv2, 1)?;
        let (d_w, d_b) = conv2d_backward_weight(&g2, t.x1.view(), d_x2.view())?;
        accumulate(&mut gb.conv2, &d_w, &d_b);
        let d_x1 =
            conv2d_backward_input_prepared(Conv2dImpl::fastest_for(&g2), &g2, d_x2.view(), cpu_layer(k, 1)?)?;
        let d_x1 = relu_backward(t.x1.view(), d_x1.view())?;
        let g1 = conv_geometry(t.input.dim(), &block.conv1, config.block_stride(k))?;
        let (d_w, d_b) = conv2d_backward_weight(&g1, t.input.view(), d_x1.view())?;
        accumulate(&mut gb.conv1, &d_w, &d_b);
        if k > 0 {
            let d_in = conv2d_backward_input_prepared(
                Conv2dImpl::fastest_for(&g1),
                &g1,
                d_x1.view(),
                cpu_layer(k, 0)?,
            )?;
            // The concat's backward: the first C channels belong to the previous block's output.
            let prev = d_in.slice(s![.., .., ..config.channels]);
            d_out[k - 1] += &prev;
        }
    }
    Ok(())
}
