//! The one seam between the algorithms and the hardware (SPEC.md §15). Everything the product runs
//! per pixel is an op of [`Backend`]; the network's forward pass ([`crate::nn::network::run_network`]),
//! the keyframe mapper ([`crate::mapping`]) and the benches call ops on a backend value and never
//! choose kernels themselves.
//!
//! # The op list
//! | op | CPU implementation | SPEC |
//! |---|---|---|
//! | [`Backend::upload`] / [`Backend::download`] | host arrays | §15.2 |
//! | [`Backend::prepare_layer`]: a layer's weights made ready, owned by the caller | [`crate::ops::PreparedConv`], [`crate::ops::PreparedDeconv`] | §15.1, §7.9 |
//! | [`Backend::conv3x3`]: 3x3 conv, stride 1/2, bias, fused ReLU | [`crate::ops::conv2d()`] | §7.2 |
//! | [`Backend::deconv5x5s2`]: 5x5 stride-2 transposed conv | [`crate::ops::deconv2d()`] | §7.3 |
//! | [`Backend::downsample2x`]: 2x tent | [`crate::ops::downsample2x`] | §7.4 |
//! | [`Backend::concat`], [`Backend::add`], [`Backend::crop`] | [`crate::ops::concat_channels`], [`crate::ops::add`] | §7.4 |
//! | [`Backend::image_pyramid`] | [`crate::ops::image_pyramid`] | §8.2 |
//! | [`Backend::cost_volume`]: `add_frame` (bilinear epipolar sampling, L1, counts), finalisation | [`crate::costvolume::CostVolume`] | §9 |
//! | [`Backend::winner_take_all`] with sub-bin refinement | [`crate::costvolume::winner_take_all_costs`] | §9.5 |
//! | [`Backend::dtam_solve`]: primal-dual steps, a-search, energy, to convergence | [`crate::dtam::solve`] | §10 |
//! | [`VolumeBuilder::finish_resident`] -> [`ResidentVolume`]: evidence filter, confidence and cost scale, winner-take-all, border taper, DTAM on the volume where it is | [`HostVolume`] | §15.6 |
//!
//! Tensors ([`Tensor`]) are `[H, W, C]` f32 maps that live where their backend put them: the CPU
//! backend keeps host arrays, a device backend keeps its own buffers, and crossing is explicit
//! ([`Backend::upload`], [`Backend::download`]). An op a backend cannot run returns
//! [`Error::Unsupported`]; nothing falls back to another backend silently.
//!
//! # Adding a backend
//! Implement [`Backend`] (ops on your [`DeviceBuffer`] type), add a name to [`by_name`] and
//! [`NAMES`], and register it in `tests/parity.rs`'s backend list; CONTRIBUTING.md walks through it.

mod cpu;
#[cfg(feature = "gpu")]
mod gpu;
mod observed;
mod patch;
mod resident;
mod tensor;

use std::fmt::Debug;
use std::sync::Arc;

use ndarray::{Array3, ArrayView3};

use crate::costvolume::{CostVolume, WtaDepth};
use crate::dtam::{DtamProblem, DtamReport, DtamResult};
use crate::error::{Error, Result};
use crate::geometry::{InverseDepthBins, PinholeCamera, Pose};
use crate::ops::LayerParams;
use crate::ops::{Activation, NetworkConfig};

pub use cpu::CpuBackend;
#[cfg(feature = "gpu")]
pub use gpu::{DtamTimings, GpuBackend, GpuBuffer};
pub use observed::{NetworkOp, Observed, Observer};
pub use resident::{HostVolume, ResidentVolume};
pub use tensor::{DeviceBuffer, Tensor};

/// A backend's bus traffic so far ([`Backend::traffic`]), in bytes.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Traffic {
    /// Host to device (uploads, constants, weights).
    pub uploaded: u64,
    /// Device to host (downloads, read-backs).
    pub downloaded: u64,
}

/// The ops a layer is prepared for ([`Backend::prepare_layer`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LayerOp {
    /// [`Backend::conv3x3`] (and its concatenating and reusing forms): weight `[c_out, c_in, 3, 3]`.
    Conv3x3,
    /// [`Backend::deconv5x5s2`] (and the fused U-Net sum): weight `[c_in, c_out, 5, 5]`.
    Deconv5x5s2,
}

/// A layer prepared by one backend ([`Backend::prepare_layer`]): its parameters and what that
/// backend made of them (packed weights, a device buffer). Cloning shares both.
#[derive(Clone)]
pub struct PreparedLayer {
    params: Arc<LayerParams>,
    op: LayerOp,
    backend: &'static str,
    data: Arc<dyn std::any::Any + Send + Sync>,
}

impl PreparedLayer {
    /// What `backend` (its [`Backend::name`]) prepared for `op` from `params`.
    pub fn new(
        backend: &'static str,
        op: LayerOp,
        params: Arc<LayerParams>,
        data: Arc<dyn std::any::Any + Send + Sync>,
    ) -> Self {
        PreparedLayer { params, op, backend, data }
    }

    /// The layer's weight and bias.
    pub fn params(&self) -> &LayerParams {
        &self.params
    }

    /// The op it was prepared for.
    pub fn op(&self) -> LayerOp {
        self.op
    }

    /// The backend that prepared it.
    pub fn backend(&self) -> &'static str {
        self.backend
    }

    /// The prepared data of `backend` for `op`.
    ///
    /// # Errors
    /// [`Error::Unsupported`] for a layer another backend (or another op) prepared.
    pub fn data<T: 'static>(&self, backend: &'static str, op: LayerOp) -> Result<&T> {
        match self.data.downcast_ref::<T>() {
            Some(d) if self.backend == backend && self.op == op => Ok(d),
            _ => Err(Error::Unsupported {
                backend: backend.into(),
                what: format!(
                    "a layer prepared by backend {} for {:?}, used for {op:?}: prepare it with this backend",
                    self.backend, self.op
                ),
            }),
        }
    }
}

impl Debug for PreparedLayer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("PreparedLayer")
            .field("backend", &self.backend)
            .field("op", &self.op)
            .field("weight", &self.params.weight.shape())
            .finish()
    }
}

/// Every op the product runs, on one kind of hardware. See the module documentation for the list
/// and the SPEC sections that define each op's maths; backends agree within SPEC.md §15.3's budgets.
pub trait Backend: Send + Sync + Debug {
    /// The name `--backend` takes (`cpu`, `gpu`).
    fn name(&self) -> &'static str;
    /// What it runs on, for logs and bench output (CPU features, adapter name).
    fn device(&self) -> String;
    /// The SIMD level of the CPU kernels this backend runs and of the host-side work around its ops
    /// (the feature maps' resampling in `mapping`): one value, handed to every kernel (issue 33
    /// item 3). The default is the process's [`crate::runtime::CpuFeatureLevel::get`].
    fn cpu_level(&self) -> crate::runtime::CpuFeatureLevel {
        crate::runtime::CpuFeatureLevel::get()
    }

    /// Copy a host map `[H, W, C]` to where this backend computes.
    ///
    /// # Errors
    /// Device allocation failures.
    fn upload(&self, x: ArrayView3<f32>) -> Result<Tensor>;
    /// [`Backend::upload`] of an owned map (the CPU backend wraps it without a copy).
    ///
    /// # Errors
    /// As [`Backend::upload`].
    fn upload_owned(&self, x: Array3<f32>) -> Result<Tensor> {
        self.upload(x.view())
    }
    /// Copy a map back to the host.
    ///
    /// # Errors
    /// [`Error::Unsupported`] for another backend's tensor; device read-back failures.
    fn download(&self, x: &Tensor) -> Result<Array3<f32>>;
    /// Wait until every op submitted so far has finished (a device backend's ops only submit work;
    /// benches stop the clock after this). The CPU backend's ops finish before they return.
    ///
    /// # Errors
    /// Device failures.
    fn synchronize(&self) -> Result<()> {
        Ok(())
    }
    /// Bytes copied to and from the device so far by this backend (its bus traffic, SPEC.md §15.6);
    /// a host backend moves none.
    fn traffic(&self) -> Traffic {
        Traffic::default()
    }

    /// A layer made ready for this backend's `op` (SPEC.md §15.1): the CPU packs its weights for
    /// the fast kernels (packed on first use, §7.9), a device backend uploads them. The caller
    /// owns the result and passes it to every call of that layer (the network prepares its layers
    /// once, `nn::PreparedNetwork`); no backend keeps a cache of weights.
    ///
    /// # Errors
    /// A weight that is not 4-d; device allocation failures.
    fn prepare_layer(&self, layer: Arc<LayerParams>, op: LayerOp) -> Result<PreparedLayer>;

    /// 3x3 convolution, padding 1, stride 1 or 2, bias, optional fused ReLU (SPEC.md §7.2); the
    /// layer's weight is `[c_out, c_in, 3, 3]` (PyTorch layout), prepared by this backend.
    ///
    /// # Errors
    /// Shape errors; [`Error::Unsupported`].
    fn conv3x3(&self, x: &Tensor, layer: &PreparedLayer, stride: usize, act: Activation) -> Result<Tensor>;
    /// [`Backend::conv3x3`] that may write its output into `spare`'s storage: a map of any shape
    /// the caller no longer needs (its values are overwritten; a shared or foreign one is dropped).
    /// The network's forward pass recycles its dead maps so (SPEC.md §8.9). The default drops
    /// `spare`.
    ///
    /// # Errors
    /// As [`Backend::conv3x3`].
    fn conv3x3_reusing(
        &self,
        x: &Tensor,
        layer: &PreparedLayer,
        stride: usize,
        act: Activation,
        spare: Option<Tensor>,
    ) -> Result<Tensor> {
        drop(spare);
        self.conv3x3(x, layer, stride, act)
    }
    /// [`Backend::conv3x3_reusing`] on `concat(a, b)` (`a`'s channels first): the first convolution
    /// of every block after the first (SPEC.md §8.1). The default concatenates, then convolves; the
    /// CPU backend convolves without forming the concatenation (SPEC.md §7.10), with the same bits.
    ///
    /// # Errors
    /// As [`Backend::concat`] and [`Backend::conv3x3`].
    fn conv3x3_concat(
        &self,
        a: &Tensor,
        b: &Tensor,
        layer: &PreparedLayer,
        stride: usize,
        act: Activation,
        spare: Option<Tensor>,
    ) -> Result<Tensor> {
        let x = self.concat(a, b)?;
        self.conv3x3_reusing(&x, layer, stride, act, spare)
    }
    /// 5x5 stride-2 transposed convolution (padding 2, output padding 1; SPEC.md §7.3); weight
    /// `[c_in, c_out, 5, 5]`.
    ///
    /// # Errors
    /// Shape errors; [`Error::Unsupported`].
    fn deconv5x5s2(&self, x: &Tensor, layer: &PreparedLayer) -> Result<Tensor>;
    /// The decoder's U-Net step `skip + deconv5x5s2(x)` (SPEC.md §8.3). The default runs the two
    /// ops; a backend may fuse them, with the same bits (the sum is one f32 addition per value).
    ///
    /// # Errors
    /// Shape errors; [`Error::Unsupported`].
    fn deconv5x5s2_add(&self, x: &Tensor, layer: &PreparedLayer, skip: &Tensor) -> Result<Tensor> {
        let up = self.deconv5x5s2(x, layer)?;
        self.add(skip, &up)
    }
    /// [`Backend::deconv5x5s2_add`] that may write into `spare`'s storage, as
    /// [`Backend::conv3x3_reusing`]. The default drops `spare`.
    ///
    /// # Errors
    /// As [`Backend::deconv5x5s2_add`].
    fn deconv5x5s2_add_reusing(
        &self,
        x: &Tensor,
        layer: &PreparedLayer,
        skip: &Tensor,
        spare: Option<Tensor>,
    ) -> Result<Tensor> {
        drop(spare);
        self.deconv5x5s2_add(x, layer, skip)
    }
    /// The 2x tent downsampling of SPEC.md §7.4.
    ///
    /// # Errors
    /// Shape errors; [`Error::Unsupported`].
    fn downsample2x(&self, x: &Tensor) -> Result<Tensor>;
    /// Channel concatenation, `a`'s channels first.
    ///
    /// # Errors
    /// Mismatched `H, W`; [`Error::Unsupported`].
    fn concat(&self, a: &Tensor, b: &Tensor) -> Result<Tensor>;
    /// [`Backend::concat`] that may write into `spare`'s storage, as [`Backend::conv3x3_reusing`].
    ///
    /// # Errors
    /// As [`Backend::concat`].
    fn concat_reusing(&self, a: &Tensor, b: &Tensor, spare: Option<Tensor>) -> Result<Tensor> {
        drop(spare);
        self.concat(a, b)
    }
    /// Elementwise sum.
    ///
    /// # Errors
    /// Mismatched shapes; [`Error::Unsupported`].
    fn add(&self, a: &Tensor, b: &Tensor) -> Result<Tensor>;
    /// The top-left `h x w` window (no copy when it already fits).
    ///
    /// # Errors
    /// A window larger than the map; [`Error::Unsupported`].
    fn crop(&self, x: Tensor, h: usize, w: usize) -> Result<Tensor>;

    /// The network's input pyramid (SPEC.md §8.2): the image padded to the network's multiple, its
    /// mean subtracted, then `max_level` tent downsamplings. The default runs the padding on the
    /// host and the downsamplings through [`Backend::downsample2x`].
    ///
    /// # Errors
    /// A malformed image; op errors.
    fn image_pyramid(
        &self,
        config: &NetworkConfig,
        image: ArrayView3<f32>,
        max_level: usize,
    ) -> Result<Vec<Tensor>> {
        let level0 = crate::ops::padded_input(config, image)?;
        let mut levels = vec![self.upload_owned(level0)?];
        for l in 0..max_level {
            let next = self.downsample2x(&levels[l])?;
            levels.push(next);
        }
        Ok(levels)
    }

    /// An empty cost volume for `reference` features seen by `camera`, hypotheses `bins`, each
    /// frame's cost truncated at `truncation` (SPEC.md §9, §9.13;
    /// [`crate::costvolume::NO_TRUNCATION`] for the plain L1).
    ///
    /// # Errors
    /// Shape errors, a truncation that is not positive; [`Error::Unsupported`].
    fn cost_volume(
        &self,
        reference: &Tensor,
        camera: PinholeCamera,
        bins: InverseDepthBins,
        truncation: f32,
    ) -> Result<Box<dyn VolumeBuilder>>;
    /// Winner-take-all inverse depth with sub-bin parabola refinement on a finalised cost array
    /// (`[H, W, K]`, unseen cells `>=` [`crate::costvolume::UNSEEN_COST`]; SPEC.md §9.5).
    ///
    /// # Errors
    /// [`Error::Unsupported`].
    fn winner_take_all(&self, costs: ArrayView3<f32>, bins: &InverseDepthBins) -> Result<WtaDepth>;
    /// DTAM's solve to convergence (SPEC.md §10): every iteration is a primal-dual step, the
    /// exhaustive a-search and the energy; Huber-TV, or the surface-normal prior (SPEC.md §10.2)
    /// where the problem has a slope field.
    ///
    /// # Errors
    /// Bad parameters or shapes; [`Error::Unsupported`] (on `gpu`: the normal prior, not ported).
    fn dtam_solve(&self, problem: &DtamProblem) -> Result<(DtamResult, DtamReport)>;
}

/// A cost volume being accumulated by a backend, one live frame at a time.
pub trait VolumeBuilder: Send {
    /// Add one live frame's features (same shape as the reference) with `T_nr`.
    ///
    /// # Errors
    /// Shape errors, the frame limit; [`Error::Unsupported`].
    fn add_frame(&mut self, live: &Tensor, t_nr: &Pose) -> Result<()> {
        let camera = *self.camera();
        self.add_frame_seen_by(live, &camera, t_nr)
    }
    /// Add one live frame's features seen by their own `camera` (`[H', W', C]`, `H' x W'` its
    /// size) with `T_nr` (SPEC.md §9.1).
    ///
    /// # Errors
    /// Shape errors, the frame limit; [`Error::Unsupported`].
    fn add_frame_seen_by(&mut self, live: &Tensor, camera: &PinholeCamera, t_nr: &Pose) -> Result<()>;
    /// The reference camera.
    fn camera(&self) -> &PinholeCamera;
    /// Frames added so far.
    fn frames(&self) -> usize;
    /// A host copy of the volume so far (for diagnostics that look at it while it fills).
    ///
    /// # Errors
    /// Device read-back failures.
    fn snapshot(&self) -> Result<CostVolume>;
    /// The finished volume on the host (sums, counts; SPEC.md §9.3).
    ///
    /// # Errors
    /// Device read-back failures.
    fn finish(self: Box<Self>) -> Result<CostVolume>;
    /// The finished volume where this backend computes, for the steps up to DTAM (SPEC.md §15.6):
    /// a device backend keeps it on the device. The default is [`VolumeBuilder::finish`]'s host
    /// volume in a [`HostVolume`].
    ///
    /// # Errors
    /// Device failures; a non-finite mean cost on a device that takes finite values only.
    fn finish_resident(self: Box<Self>) -> Result<Box<dyn ResidentVolume>> {
        Ok(Box::new(HostVolume::new(self.finish()?, crate::runtime::CpuFeatureLevel::get())))
    }
}

/// The names `--backend` accepts, in the order `densefeat --help` lists them.
pub const NAMES: &[&str] = &["cpu", "gpu"];

/// The backend called `name`: `cpu` (always there) or `gpu` (the wgpu backend, SPEC.md §15.5).
///
/// # Errors
/// [`Error::InvalidArgument`] (flag `--backend`) for an unknown name; [`Error::Unsupported`] for
/// `gpu` in a build without the cargo feature `gpu`, or when wgpu finds no adapter.
pub fn by_name(name: &str) -> Result<Arc<dyn Backend>> {
    match name {
        "cpu" => Ok(Arc::new(CpuBackend::default())),
        "gpu" => gpu_backend(),
        other => Err(Error::invalid_argument(
            "--backend",
            format!("{other:?}: expected one of {}", NAMES.join(", ")),
        )),
    }
}

#[cfg(feature = "gpu")]
fn gpu_backend() -> Result<Arc<dyn Backend>> {
    Ok(GpuBackend::shared()?)
}

#[cfg(not(feature = "gpu"))]
fn gpu_backend() -> Result<Arc<dyn Backend>> {
    Err(Error::Unsupported {
        backend: "gpu".into(),
        what: "this build has no GPU backend (built without the cargo feature `gpu`: \
               cargo build --features gpu); use --backend cpu"
            .into(),
    })
}

/// The default backend: the CPU with its fastest kernels.
pub fn default_backend() -> Arc<dyn Backend> {
    Arc::new(CpuBackend::default())
}
