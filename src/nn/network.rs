//! The feature network of the paper's §3.1 (SPEC.md §8): an encoder of `blocks` blocks of three
//! 3x3 convolutions, each block after the first seeing the previous block's output concatenated
//! with the image at that resolution, and a decoder that sums every block's output with the
//! upsampled (5x5 stride-2 transposed convolution) aggregate of the coarser blocks.
//!
//! ```text
//!  image ──pad──(-mean)──► B1 ─► out_1 ─────────────────────────► a_1 = out_1 + up_1(a_2) = features
//!     │ downsample2x*        │ concat(out_1, image at out_1's level)          ▲
//!     └──────────────────────┴► B2 ─► out_2 ────────────► a_2 = out_2 + up_2(a_3)
//!                                        ...                      ▲
//!                                     B_n ─► out_n ────────────► a_n = out_n
//! ```
//!
//! Every op runs on a [`Backend`] value, so this one function is the network on any backend, and,
//! on [`crate::backend::Observed`] around the CPU backend, the training forward pass that records
//! the tape (`crate::train::backprop`), the per-op profiler ([`crate::nn::profile`]) and the
//! per-layer error check of [`crate::nn::budget`].

use std::sync::Mutex;

use ndarray::{Array3, ArrayView3};

use crate::backend::{Backend, PreparedLayer, Tensor};
use crate::error::Result;
use crate::nn::prepared::PreparedNetwork;
use crate::nn::weights::NetworkWeights;
use crate::ops::config::NetworkConfig;
use crate::ops::geometry::DECONV_KERNEL;
use crate::ops::{concat_conv_geometry, conv_geometry, Activation};

/// Everything a forward pass computes, cropped to the input's size (SPEC.md §8.2).
#[derive(Clone, Debug)]
pub struct ForwardOutput<M = Array3<f32>> {
    /// `blocks[k]`: block `k`'s output (0-based), `[ceil(H / 2^l), ceil(W / 2^l), channels]` with
    /// `l = config.block_level(k)`.
    pub blocks: Vec<M>,
    /// `aggregated[k] = blocks[k] + deconv_k(aggregated[k + 1])`, the last equal to the last block.
    pub aggregated: Vec<M>,
}

impl<M> ForwardOutput<M> {
    /// The features, `aggregated[0]`.
    ///
    /// # Panics
    /// Never for an output of [`FeatureNet::forward`], which has at least one block.
    pub fn features(&self) -> &M {
        &self.aggregated[0]
    }
}

/// Maps a forward pass no longer needs (a block's first two convolutions' outputs, the decoder's
/// used inputs), handed to later convolutions, concatenations and decoder steps as output storage
/// ([`Backend::conv3x3_reusing`]), so a pass allocates (and the OS zero-fills) far fewer fresh maps
/// (SPEC.md §8.9). [`FeatureNet`] keeps one between its passes ([`Arena::into_spares`]).
#[derive(Debug, Default)]
pub struct Arena {
    spare: Vec<Tensor>,
}

impl Arena {
    /// An empty arena.
    pub fn new() -> Self {
        Self::default()
    }

    /// An arena that starts with `spares` (from [`Arena::into_spares`]).
    pub fn with_spares(spares: Vec<Tensor>) -> Self {
        Self { spare: spares }
    }

    /// The maps left in the arena (host maps only), to seed another pass's arena.
    pub fn into_spares(self) -> Vec<Tensor> {
        self.spare.into_iter().filter(|t| t.as_host().is_some()).collect()
    }

    /// A spare map for an output of `len` values, taken out of the arena: the smallest holding at
    /// least `len` values, else the largest (a map whose storage was truncated by an earlier reuse
    /// may still have the room; the backend checks and allocates if not).
    fn take(&mut self, len: usize) -> Option<Tensor> {
        let size = |t: &Tensor| {
            let (h, w, c) = t.dim();
            h * w * c
        };
        let fits = (0..self.spare.len())
            .filter(|&i| size(&self.spare[i]) >= len)
            .min_by_key(|&i| size(&self.spare[i]));
        let best = fits.or_else(|| (0..self.spare.len()).max_by_key(|&i| size(&self.spare[i])))?;
        Some(self.spare.swap_remove(best))
    }

    /// Hands back a map the pass no longer needs.
    fn give(&mut self, map: Tensor) {
        self.spare.push(map);
    }
}

/// One pass's backend and arena: the network's ops with their output storage from the arena.
struct Pass<'a> {
    backend: &'a dyn Backend,
    arena: &'a mut Arena,
}

impl Pass<'_> {
    fn conv(&mut self, x: &Tensor, l: &PreparedLayer, stride: usize, act: Activation) -> Result<Tensor> {
        let [h, w, c] = conv_geometry(x.dim(), l.params(), stride)?.output_shape();
        let spare = self.arena.take(h * w * c);
        self.backend.conv3x3_reusing(x, l, stride, act, spare)
    }

    fn concat_conv(
        &mut self,
        a: &Tensor,
        b: &Tensor,
        l: &PreparedLayer,
        stride: usize,
        act: Activation,
    ) -> Result<Tensor> {
        let [h, w, c] = concat_conv_geometry(a.dim(), b.dim(), l.params(), stride)?.output_shape();
        let spare = self.arena.take(h * w * c);
        self.backend.conv3x3_concat(a, b, l, stride, act, spare)
    }

    fn deconv_add(&mut self, x: &Tensor, l: &PreparedLayer, skip: &Tensor) -> Result<Tensor> {
        let (h, w, c) = skip.dim();
        let spare = self.arena.take(h * w * c);
        self.backend.deconv5x5s2_add_reusing(x, l, skip, spare)
    }
}

/// The encoder of the forward pass (SPEC.md §8.1-8.2): every block's output, uncropped (on the
/// padded input's grid).
fn run_blocks(pass: &mut Pass<'_>, net: &PreparedNetwork, image: ArrayView3<f32>) -> Result<Vec<Tensor>> {
    run_first_blocks(pass, net, image, net.config().blocks)
}

/// The first `count` blocks of the encoder (`1..=blocks`), uncropped. The input is padded to the
/// whole network's multiple (SPEC.md §8.2) whatever `count` is, so block `k`'s output has the bits
/// of the full pass's; the image pyramid stops at the last level these blocks read.
fn run_first_blocks(
    pass: &mut Pass<'_>,
    net: &PreparedNetwork,
    image: ArrayView3<f32>,
    count: usize,
) -> Result<Vec<Tensor>> {
    let config = net.config();
    let count = count.clamp(1, config.blocks);
    // Block k > 0 needs the image at block k-1's level; the deepest is the next-to-last block's.
    let max_level = if count > 1 { config.block_level(count - 2) } else { 0 };
    let pyramid = pass.backend.image_pyramid(config, image, max_level)?;
    let mut outs: Vec<Tensor> = Vec::with_capacity(count);
    for (k, [conv1, conv2, conv3]) in net.blocks.iter().take(count).enumerate() {
        let (stride, act) = (config.block_stride(k), Activation::Relu);
        let x1 = match outs.last() {
            None => pass.conv(&pyramid[0], conv1, stride, act)?,
            Some(prev) => pass.concat_conv(prev, &pyramid[config.block_level(k - 1)], conv1, stride, act)?,
        };
        let x2 = pass.conv(&x1, conv2, 1, Activation::Relu)?;
        pass.arena.give(x1);
        let out = pass.conv(&x2, conv3, 1, Activation::None)?;
        pass.arena.give(x2);
        outs.push(out);
    }
    Ok(outs)
}

/// The forward pass (SPEC.md §8.1-8.2) on `backend`, output storage from `arena`: every block's
/// output and every aggregated map, cropped (what training's deep supervision needs). The one
/// forward pass: inference runs it on a backend, training on [`crate::backend::Observed`] with the
/// tape as observer, the profiler and the per-layer error check likewise.
///
/// # Errors
/// [`crate::Error::InvalidArgument`] for a malformed image; the backend's errors (a layer
/// prepared by another backend).
pub fn run_network(
    backend: &dyn Backend,
    arena: &mut Arena,
    net: &PreparedNetwork,
    image: ArrayView3<f32>,
) -> Result<ForwardOutput<Tensor>> {
    let pass = &mut Pass { backend, arena };
    let outs = run_blocks(pass, net, image)?;
    let config = net.config();
    // Decoder, coarse to fine: a_k = out_k + deconv_k(a_{k+1}).
    let mut aggregated: Vec<Tensor> = Vec::with_capacity(config.blocks);
    for k in (0..config.blocks).rev() {
        let a = match aggregated.last() {
            None => outs[k].clone(),
            Some(coarser) => pass.deconv_add(coarser, &net.deconvs[k], &outs[k])?,
        };
        aggregated.push(a);
    }
    aggregated.reverse();
    let (h, w, _) = image.dim();
    let shapes = config.output_shapes(h, w);
    // Maps are moved through the crop: at sizes that need no cropping nothing is copied.
    let crop_all = |maps: Vec<Tensor>| -> Result<Vec<Tensor>> {
        maps.into_iter().zip(&shapes).map(|(m, &[hl, wl, _])| backend.crop(m, hl, wl)).collect()
    };
    let blocks = crop_all(outs)?;
    let aggregated = crop_all(aggregated)?;
    Ok(ForwardOutput { blocks, aggregated })
}

/// The features alone, `aggregated[0]` of [`run_network`] (the same bits): the decoder releases
/// each block output and coarser aggregate as soon as it is used, and only the features are
/// cropped. What inference (`features`, the mapper, `bench forward`) runs.
///
/// # Errors
/// As [`run_network`].
pub fn run_features(
    backend: &dyn Backend,
    arena: &mut Arena,
    net: &PreparedNetwork,
    image: ArrayView3<f32>,
) -> Result<Tensor> {
    let pass = &mut Pass { backend, arena };
    let mut outs = run_blocks(pass, net, image)?;
    let Some(mut a) = outs.pop() else { unreachable!("validated weights have at least one block") };
    // `outs.pop()` is block k's output, k = blocks - 2 down to 0.
    while let Some(skip) = outs.pop() {
        let next = pass.deconv_add(&a, &net.deconvs[outs.len()], &skip)?;
        pass.arena.give(a);
        pass.arena.give(skip);
        a = next;
    }
    let (h, w, _) = image.dim();
    let [h0, w0, _] = net.config().output_shapes(h, w)[0];
    backend.crop(a, h0, w0)
}

/// Block 1's output alone, `run_network(..).blocks[0]` (the same bits): the paper's "B1 only"
/// baseline (§3.1: "one can choose to remove Blocks B2-B5 and simply use features from Block B1").
/// Only the first block runs; the input is padded as for the whole network (SPEC.md §8.2), then the
/// output is cropped to `config.output_shapes(h, w)[0]`.
///
/// # Errors
/// As [`run_network`].
pub fn run_block1(
    backend: &dyn Backend,
    arena: &mut Arena,
    net: &PreparedNetwork,
    image: ArrayView3<f32>,
) -> Result<Tensor> {
    let mut outs = run_first_blocks(&mut Pass { backend, arena }, net, image, 1)?;
    let Some(out) = outs.pop() else { unreachable!("one block was run") };
    let (h, w, _) = image.dim();
    let [h0, w0, _] = net.config().output_shapes(h, w)[0];
    backend.crop(out, h0, w0)
}

/// `t`'s host array: moved out when it is on the host, else downloaded from `backend`.
fn to_host(t: Tensor, backend: &dyn Backend) -> Result<Array3<f32>> {
    match t.as_host() {
        Some(_) => Ok(t.into_host().expect("host tensor")),
        None => backend.download(&t),
    }
}

/// The feature network with its weights.
#[derive(Debug)]
pub struct FeatureNet {
    weights: NetworkWeights,
    /// The layers prepared by each backend this network has run on (one per backend name; the
    /// weights never change, so they never go stale).
    prepared: Mutex<Vec<std::sync::Arc<PreparedNetwork>>>,
    /// Host buffers left over by the last forward pass, reused by the next one (SPEC.md §8.9): at
    /// most the few intermediates of one pass, never the maps a pass returns.
    spares: Mutex<Vec<Tensor>>,
}

impl Clone for FeatureNet {
    /// The same weights, with an empty buffer arena.
    fn clone(&self) -> Self {
        FeatureNet {
            weights: self.weights.clone(),
            prepared: Mutex::new(Vec::new()),
            spares: Mutex::new(Vec::new()),
        }
    }
}

impl FeatureNet {
    /// Wraps validated weights.
    ///
    /// # Errors
    /// [`crate::Error::InvalidArgument`] if a tensor's shape disagrees with the configuration.
    pub fn new(weights: NetworkWeights) -> Result<Self> {
        weights.validate()?;
        Ok(FeatureNet { weights, prepared: Mutex::new(Vec::new()), spares: Mutex::new(Vec::new()) })
    }

    /// The layers prepared by `backend` (on its first use with this network; then shared).
    ///
    /// # Errors
    /// The backend's preparation errors.
    pub fn prepared(&self, backend: &dyn Backend) -> Result<std::sync::Arc<PreparedNetwork>> {
        let mut all = self.prepared.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(p) = all.iter().find(|p| p.backend() == backend.name()) {
            return Ok(p.clone());
        }
        let p = std::sync::Arc::new(PreparedNetwork::new(&self.weights, backend)?);
        all.push(p.clone());
        Ok(p)
    }

    /// The configuration.
    pub fn config(&self) -> &NetworkConfig {
        &self.weights.config
    }

    /// The weights.
    pub fn weights(&self) -> &NetworkWeights {
        &self.weights
    }

    /// Runs the network on an RGB image `[H, W, 3]` (0-255, SPEC.md §2.2) on `backend`, returning
    /// host maps. On the CPU backend each kernel is parallel inside (rayon's current pool) and the
    /// result is bit-identical for any thread count.
    ///
    /// # Errors
    /// [`crate::Error::InvalidArgument`] if the image is not `[H >= 1, W >= 1, 3]`.
    pub fn forward(&self, image: ArrayView3<f32>, backend: &dyn Backend) -> Result<ForwardOutput> {
        let out = self.forward_tensors(image, backend)?;
        let down = |maps: Vec<Tensor>| -> Result<Vec<Array3<f32>>> {
            maps.into_iter().map(|t| to_host(t, backend)).collect()
        };
        Ok(ForwardOutput { blocks: down(out.blocks)?, aggregated: down(out.aggregated)? })
    }

    /// [`FeatureNet::forward`] leaving every map where `backend` computed it.
    ///
    /// # Errors
    /// As [`FeatureNet::forward`]; [`crate::Error::Unsupported`] from the backend.
    pub fn forward_tensors(
        &self,
        image: ArrayView3<f32>,
        backend: &dyn Backend,
    ) -> Result<ForwardOutput<Tensor>> {
        let net = self.prepared(backend)?;
        self.with_arena(|arena| run_network(backend, arena, &net, image))
    }

    /// The features alone (`forward(..).aggregated[0]`, the same bits) as a host map: what
    /// inference needs, with less memory and work than [`FeatureNet::forward`] (SPEC.md §8.9).
    ///
    /// # Errors
    /// As [`FeatureNet::forward`].
    pub fn features(&self, image: ArrayView3<f32>, backend: &dyn Backend) -> Result<Array3<f32>> {
        to_host(self.features_tensor(image, backend)?, backend)
    }

    /// [`FeatureNet::features`] leaving the map where `backend` computed it.
    ///
    /// # Errors
    /// As [`FeatureNet::forward`].
    pub fn features_tensor(&self, image: ArrayView3<f32>, backend: &dyn Backend) -> Result<Tensor> {
        let net = self.prepared(backend)?;
        self.with_arena(|arena| run_features(backend, arena, &net, image))
    }

    /// Block 1's output alone (`forward(..).blocks[0]`, the same bits) as a host map, without
    /// running the coarser blocks or the decoder: `[ceil(H / 2^l), ceil(W / 2^l), channels]` with
    /// `l = config.block_level(0)` (SPEC.md §9a.1).
    ///
    /// # Errors
    /// As [`FeatureNet::forward`].
    pub fn block1(&self, image: ArrayView3<f32>, backend: &dyn Backend) -> Result<Array3<f32>> {
        let net = self.prepared(backend)?;
        let t = self.with_arena(|arena| run_block1(backend, arena, &net, image))?;
        to_host(t, backend)
    }

    /// Runs `pass` with an [`Arena`] that starts with the last pass's leftovers (a concurrent pass
    /// on the same network simply starts with an empty one) and hands its own leftovers back.
    fn with_arena<T>(&self, pass: impl FnOnce(&mut Arena) -> Result<T>) -> Result<T> {
        let spares = std::mem::take(&mut *self.spares.lock().unwrap_or_else(|e| e.into_inner()));
        let mut arena = Arena::with_spares(spares);
        let out = pass(&mut arena)?;
        *self.spares.lock().unwrap_or_else(|e| e.into_inner()) = arena.into_spares();
        Ok(out)
    }

    /// Floating-point operations of one forward pass on an `h x w` image (multiply and add each
    /// count one), as run: on the padded input, convolutions `2 · 9 c_in · h_out w_out c_out`,
    /// transposed convolutions `2 · 25 c_in c_out` per input pixel (the parity GEMMs' work,
    /// including border taps). Bias, ReLU, additions and downsampling are not counted.
    pub fn flops(&self, h: usize, w: usize) -> f64 {
        let config = &self.weights.config;
        let (hp, wp) = config.padded_size(h, w);
        let c = config.channels as f64;
        let mut total = 0.0;
        for k in 0..config.blocks {
            let (hl, wl) = NetworkConfig::level_size(hp, wp, config.block_level(k));
            let pixels = (hl * wl) as f64;
            total += 2.0 * 9.0 * pixels * c * (config.block_in_channels(k) as f64 + 2.0 * c);
            if k > 0 {
                total += 2.0 * (DECONV_KERNEL * DECONV_KERNEL) as f64 * pixels * c * c;
            }
        }
        total
    }
}
