//! The CPU backend: today's kernels, rayon-parallel and deterministic (SPEC.md §7-§10). It is the
//! reference every other backend is checked against (`tests/parity.rs`).

use ndarray::{s, Array3, ArrayView3};

use std::sync::Arc;

use super::{Backend, HostVolume, LayerOp, PreparedLayer, ResidentVolume, Tensor, VolumeBuilder};
use crate::costvolume::{winner_take_all_costs, CostVolume, CostVolumeImpl, WtaDepth};
use crate::dtam::{DtamProblem, DtamReport, DtamResult};
use crate::error::{Error, Result};
use crate::geometry::{InverseDepthBins, PinholeCamera, Pose};
use crate::ops::conv2d::{OutputLayout, WinogradKernel};
use crate::ops::LayerParams;
use crate::ops::{
    add, concat_channels_into, conv2d_concat_prepared_into, conv2d_prepared_into, deconv2d_prepared_into,
    downsample2x_at, expect_shape, Activation, Conv2dGeometry, Conv2dImpl, Deconv2dImpl, NetworkConfig,
    NetworkImpl, PreparedConv, PreparedDeconv,
};
use crate::ops::{concat_conv_geometry, conv_geometry, deconv_geometry};
use crate::runtime::CpuFeatureLevel;
use crate::util::alloc::zeroed_vec;

/// Kernel choices of the CPU backend. [`CpuBackend::default`] is the fast one; tests build others
/// (for example [`NetworkImpl::REFERENCE`]) to compare implementations.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct CpuBackend {
    /// Network kernels. With `conv: Direct` each layer runs [`Conv2dImpl::fastest_for`] its geometry.
    pub network: NetworkImpl,
    /// Cost-volume kernel.
    pub volume: CostVolumeImpl,
    /// The SIMD level this backend's kernels are handed (issue 33 item 3): the process's
    /// [`CpuFeatureLevel::get`] by default; a lower one forces the portable or AVX2 builds (the same
    /// bits), a higher one than the CPU's runs no instruction the CPU lacks.
    pub level: CpuFeatureLevel,
}

impl Default for CpuBackend {
    fn default() -> Self {
        Self { network: NetworkImpl::FAST, volume: CostVolumeImpl::Fast, level: CpuFeatureLevel::get() }
    }
}

impl CpuBackend {
    /// The fast volume with the given network kernels.
    pub fn with_network(network: NetworkImpl) -> Self {
        Self { network, ..Self::default() }
    }

    /// The convolution implementation this backend runs for `geom`: with `network.conv =
    /// Direct` (the product's choice) [`Conv2dImpl::fastest_for`] the layer (Winograd, Direct or
    /// im2col, SPEC.md §7.11), otherwise `network.conv` itself.
    pub fn conv_impl_for(&self, geom: &crate::ops::Conv2dGeometry) -> Conv2dImpl {
        match self.network.conv {
            Conv2dImpl::Direct => Conv2dImpl::fastest_for_at(geom, self.level),
            other => other,
        }
    }

    /// The transposed-convolution implementation this backend runs for `geom`: with `network.deconv
    /// = Direct` (the product's choice) [`Deconv2dImpl::fastest_for`] the layer (Winograd or Direct,
    /// SPEC.md §7.3), otherwise `network.deconv` itself.
    pub fn deconv_impl_for(&self, geom: &crate::ops::Deconv2dGeometry) -> Deconv2dImpl {
        match self.network.deconv {
            Deconv2dImpl::Direct => Deconv2dImpl::fastest_for_at(geom, self.level),
            other => other,
        }
    }

    /// What this backend runs, on this CPU, for each layer kind of `config`'s network on an `h x w`
    /// image: `(layer kind, "implementation (kernel)")`, in the profile's names (`densefeat bench
    /// forward` prints it), e.g. `("conv s1 32->32", "WinogradF4 (winograd-avx512f-14x32)")`.
    ///
    /// # Errors
    /// [`Error::InvalidArgument`] for an invalid configuration or an empty image.
    pub fn network_kernels(
        &self,
        config: &NetworkConfig,
        h: usize,
        w: usize,
    ) -> Result<Vec<(String, String)>> {
        config.validate()?;
        let c = config.channels;
        let (ph, pw) = config.padded_size(h, w);
        let mut kinds = Vec::new();
        let mut conv = |name: String, g: Conv2dGeometry| {
            let imp = self.conv_impl_for(&g);
            let kernel = match imp {
                Conv2dImpl::WinogradF2 | Conv2dImpl::WinogradF4 => {
                    WinogradKernel::select_for_at(&g, OutputLayout::Conv, self.level).name()
                }
                Conv2dImpl::Direct => crate::ops::conv2d::DirectKernel::select_at(&g, self.level).name(),
                Conv2dImpl::Im2colGemm => "matrixmultiply sgemm",
                _ => "f64 loops",
            };
            kinds.push((name, format!("{imp:?} ({kernel})")));
        };
        let s = config.b1_stride;
        let (h1, w1) = NetworkConfig::level_size(ph, pw, config.block_level(0));
        conv(format!("conv s{s} 3->{c}"), Conv2dGeometry::new(ph, pw, 3, c, s)?);
        conv(format!("conv s1 {c}->{c}"), Conv2dGeometry::new(h1, w1, c, c, 1)?);
        if config.blocks > 1 {
            let ci = config.block_in_channels(1);
            conv(format!("concat + conv s2 {ci}->{c}"), Conv2dGeometry::new(h1, w1, ci, c, 2)?);
            let g = crate::ops::Deconv2dGeometry::new(h1.div_ceil(2), w1.div_ceil(2), c, c)?;
            let imp = self.deconv_impl_for(&g);
            let kernel = match imp {
                Deconv2dImpl::WinogradF2 | Deconv2dImpl::WinogradF4 => {
                    let e = crate::ops::deconv2d::winograd::equivalent_geometry(&g)?;
                    WinogradKernel::select_for_at(&e, OutputLayout::Deconv, self.level).name()
                }
                Deconv2dImpl::Direct if crate::ops::deconv2d::direct::supported_at(&g, self.level) => {
                    crate::ops::deconv2d::direct::select_at(&g, self.level).name()
                }
                Deconv2dImpl::Direct | Deconv2dImpl::ParityGemm => "parity GEMMs, matrixmultiply",
                _ => "f64 loops",
            };
            kinds.push(("deconv 5x5 s2 + add".into(), format!("{imp:?} ({kernel})")));
        }
        Ok(kinds)
    }

    /// The f64 reference kernels everywhere (single-threaded and slow: the oracle).
    pub fn reference() -> Self {
        Self {
            network: NetworkImpl::REFERENCE,
            volume: CostVolumeImpl::Reference,
            level: CpuFeatureLevel::Portable,
        }
    }
}

/// A `shape` array for an op's output: `spare`'s storage when it is a host map with a single
/// handle and room for the new length (truncated, or grown inside its capacity; the op overwrites
/// every value), else a new zeroed one (`calloc`: fresh pages come zeroed from the OS, no memset; large ones
/// advised onto huge pages, `nn::alloc`).
fn output_array(shape: [usize; 3], spare: Option<Tensor>) -> Array3<f32> {
    let n = shape.iter().product();
    let reused = match spare.map(Tensor::into_unique_host) {
        Some(Ok(a)) => match a.into_raw_vec_and_offset() {
            (mut v, Some(0) | None) if v.capacity() >= n => {
                v.resize(n, 0.0);
                Some(v)
            }
            _ => None,
        },
        _ => None,
    };
    let v = reused.unwrap_or_else(|| zeroed_vec(n));
    let Ok(a) = Array3::from_shape_vec(shape, v) else { unreachable!("length is the shape's product") };
    a
}

/// The first `h` rows of `a`: its own storage, truncated, when it is standard-layout (row-major, so
/// the rows are a prefix of its data), else a copy.
fn first_rows(a: Array3<f32>, h: usize) -> Array3<f32> {
    if !a.is_standard_layout() {
        return a.slice_move(s![..h, .., ..]).as_standard_layout().into_owned();
    }
    let (_, w, c) = a.dim();
    let (mut v, offset) = a.into_raw_vec_and_offset();
    v.drain(..offset.unwrap_or(0));
    v.truncate(h * w * c);
    let Ok(a) = Array3::from_shape_vec((h, w, c), v) else { unreachable!("h rows of w·c values") };
    a
}

/// The host array of a tensor, or [`Error::Unsupported`] naming where it lives.
pub(crate) fn host<'a>(backend: &str, x: &'a Tensor) -> Result<&'a Array3<f32>> {
    x.as_host().ok_or_else(|| Error::Unsupported {
        backend: backend.into(),
        what: format!("a tensor on `{}`: download it first", x.location()),
    })
}

impl Backend for CpuBackend {
    fn cpu_level(&self) -> CpuFeatureLevel {
        self.level
    }

    fn name(&self) -> &'static str {
        "cpu"
    }

    fn device(&self) -> String {
        format!(
            "CPU, {} rayon threads, {} kernels",
            rayon::current_num_threads(),
            crate::costvolume::fast_kernel_name()
        )
    }

    fn upload(&self, x: ArrayView3<f32>) -> Result<Tensor> {
        Ok(Tensor::host(x.to_owned()))
    }

    fn upload_owned(&self, x: Array3<f32>) -> Result<Tensor> {
        Ok(Tensor::host(x))
    }

    fn download(&self, x: &Tensor) -> Result<Array3<f32>> {
        Ok(host(self.name(), x)?.clone())
    }

    fn prepare_layer(&self, layer: Arc<LayerParams>, op: LayerOp) -> Result<PreparedLayer> {
        if layer.weight.ndim() != 4 || layer.bias.ndim() != 1 {
            return Err(Error::invalid_argument("layer", "expected a 4-d weight and a 1-d bias"));
        }
        let data: Arc<dyn std::any::Any + Send + Sync> = match op {
            LayerOp::Conv3x3 => Arc::new(PreparedConv::new(layer.clone())),
            LayerOp::Deconv5x5s2 => Arc::new(PreparedDeconv::new(layer.clone())),
        };
        Ok(PreparedLayer::new(self.name(), op, layer, data))
    }

    fn conv3x3(&self, x: &Tensor, l: &PreparedLayer, stride: usize, act: Activation) -> Result<Tensor> {
        self.conv3x3_reusing(x, l, stride, act, None)
    }

    fn conv3x3_reusing(
        &self,
        x: &Tensor,
        l: &PreparedLayer,
        stride: usize,
        act: Activation,
        spare: Option<Tensor>,
    ) -> Result<Tensor> {
        let x = host(self.name(), x)?;
        let p: &PreparedConv = l.data(self.name(), LayerOp::Conv3x3)?;
        let g = conv_geometry(x.dim(), l.params(), stride)?;
        let imp = self.conv_impl_for(&g);
        let mut out = output_array(g.output_shape(), spare);
        let Some(o) = out.as_slice_mut() else { unreachable!("output arrays are contiguous") };
        conv2d_prepared_into(imp, &g, x.view(), p, act, o, self.level)?;
        Ok(Tensor::host(out))
    }

    fn conv3x3_concat(
        &self,
        a: &Tensor,
        b: &Tensor,
        l: &PreparedLayer,
        stride: usize,
        act: Activation,
        spare: Option<Tensor>,
    ) -> Result<Tensor> {
        let (a, b) = (host(self.name(), a)?, host(self.name(), b)?);
        let p: &PreparedConv = l.data(self.name(), LayerOp::Conv3x3)?;
        crate::ops::downsample::check_same_spatial(a.shape(), b.shape())?;
        let g = concat_conv_geometry(a.dim(), b.dim(), l.params(), stride)?;
        let imp = self.conv_impl_for(&g);
        let mut out = output_array(g.output_shape(), spare);
        let Some(o) = out.as_slice_mut() else { unreachable!("output arrays are contiguous") };
        conv2d_concat_prepared_into(imp, &g, a.view(), b.view(), p, act, o, self.level)?;
        Ok(Tensor::host(out))
    }

    fn deconv5x5s2(&self, x: &Tensor, l: &PreparedLayer) -> Result<Tensor> {
        let x = host(self.name(), x)?;
        let p: &PreparedDeconv = l.data(self.name(), LayerOp::Deconv5x5s2)?;
        let g = deconv_geometry(x.dim(), l.params())?;
        let mut out = output_array(g.output_shape(), None);
        let Some(o) = out.as_slice_mut() else { unreachable!("output arrays are contiguous") };
        deconv2d_prepared_into(self.deconv_impl_for(&g), &g, x.view(), p, None, o, self.level)?;
        Ok(Tensor::host(out))
    }

    fn deconv5x5s2_add(&self, x: &Tensor, l: &PreparedLayer, skip: &Tensor) -> Result<Tensor> {
        self.deconv5x5s2_add_reusing(x, l, skip, None)
    }

    fn deconv5x5s2_add_reusing(
        &self,
        x: &Tensor,
        l: &PreparedLayer,
        skip: &Tensor,
        spare: Option<Tensor>,
    ) -> Result<Tensor> {
        let (x, skip) = (host(self.name(), x)?, host(self.name(), skip)?);
        let p: &PreparedDeconv = l.data(self.name(), LayerOp::Deconv5x5s2)?;
        let g = deconv_geometry(x.dim(), l.params())?;
        expect_shape("U-Net skip map", skip.shape(), &g.output_shape())?;
        let skip = skip.as_standard_layout();
        let Some(ss) = skip.as_slice() else { unreachable!("standard-layout arrays are contiguous") };
        let mut out = output_array(g.output_shape(), spare);
        let Some(o) = out.as_slice_mut() else { unreachable!("output arrays are contiguous") };
        // Direct and Winograd fuse the sum into their store; the others add in a second pass (same
        // bits).
        deconv2d_prepared_into(self.deconv_impl_for(&g), &g, x.view(), p, Some(ss), o, self.level)?;
        Ok(Tensor::host(out))
    }

    fn downsample2x(&self, x: &Tensor) -> Result<Tensor> {
        Ok(Tensor::host(downsample2x_at(host(self.name(), x)?.view(), self.level)?))
    }

    fn concat(&self, a: &Tensor, b: &Tensor) -> Result<Tensor> {
        self.concat_reusing(a, b, None)
    }

    fn concat_reusing(&self, a: &Tensor, b: &Tensor, spare: Option<Tensor>) -> Result<Tensor> {
        let (a, b) = (host(self.name(), a)?, host(self.name(), b)?);
        crate::ops::downsample::check_same_spatial(a.shape(), b.shape())?;
        let ((h, w, ca), (_, _, cb)) = (a.dim(), b.dim());
        let mut out = output_array([h, w, ca + cb], spare);
        let Some(o) = out.as_slice_mut() else { unreachable!("output arrays are contiguous") };
        concat_channels_into(a.view(), b.view(), o)?;
        Ok(Tensor::host(out))
    }

    fn add(&self, a: &Tensor, b: &Tensor) -> Result<Tensor> {
        Ok(Tensor::host(add(host(self.name(), a)?.view(), host(self.name(), b)?.view())?))
    }

    fn crop(&self, x: Tensor, h: usize, w: usize) -> Result<Tensor> {
        let (hx, wx, _) = x.dim();
        if (hx, wx) == (h, w) {
            return Ok(x);
        }
        if h > hx || w > wx {
            return Err(Error::invalid_argument("crop", format!("{h}x{w} window of a {hx}x{wx} map")));
        }
        let x = if w == wx {
            // Only rows go: a uniquely owned map keeps its storage, truncated (nothing copied).
            match x.into_unique_host() {
                Ok(a) => return Ok(Tensor::host(first_rows(a, h))),
                Err(shared) => shared,
            }
        } else {
            x
        };
        Ok(Tensor::host(host(self.name(), &x)?.slice(s![..h, ..w, ..]).to_owned()))
    }

    fn cost_volume(
        &self,
        reference: &Tensor,
        camera: PinholeCamera,
        bins: InverseDepthBins,
        truncation: f32,
    ) -> Result<Box<dyn VolumeBuilder>> {
        let r = host(self.name(), reference)?.clone();
        Ok(Box::new(CpuVolume(
            CostVolume::with_impl(r, camera, bins, self.volume)?
                .with_level(self.level)
                .with_truncation(truncation)?,
            self.level,
        )))
    }

    fn winner_take_all(&self, costs: ArrayView3<f32>, bins: &InverseDepthBins) -> Result<WtaDepth> {
        Ok(winner_take_all_costs(costs, bins))
    }

    fn dtam_solve(&self, problem: &DtamProblem) -> Result<(DtamResult, DtamReport)> {
        crate::dtam::solve_with(problem, self.level)
    }
}

/// [`CostVolume`] as a [`VolumeBuilder`], with the backend's SIMD level for the resident volume's
/// DTAM solve.
struct CpuVolume(CostVolume, CpuFeatureLevel);

impl VolumeBuilder for CpuVolume {
    fn add_frame_seen_by(&mut self, live: &Tensor, camera: &PinholeCamera, t_nr: &Pose) -> Result<()> {
        self.0.add_frame_seen_by(host("cpu", live)?.view(), camera, t_nr)
    }

    fn camera(&self) -> &PinholeCamera {
        self.0.camera()
    }

    fn frames(&self) -> usize {
        self.0.frames()
    }

    fn snapshot(&self) -> Result<CostVolume> {
        Ok(self.0.clone())
    }

    fn finish(self: Box<Self>) -> Result<CostVolume> {
        Ok(self.0)
    }

    fn finish_resident(self: Box<Self>) -> Result<Box<dyn ResidentVolume>> {
        Ok(Box::new(HostVolume::new(self.0, self.1)))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `first_rows` keeps the top rows bit for bit whatever the storage: from offset 0, from an
    /// array whose data starts past the allocation's start (rows sliced off the top), and from a
    /// non-standard layout (transposed).
    #[test]
    fn first_rows_are_the_top_window_for_every_storage() {
        let full = Array3::from_shape_fn((6, 4, 3), |(y, x, c)| (100 * y + 10 * x + c) as f32);
        let want = |a: &Array3<f32>, h: usize| a.slice(s![..h, .., ..]).to_owned();
        assert_eq!(first_rows(full.clone(), 4), want(&full, 4));
        let offset = full.clone().slice_move(s![2.., .., ..]);
        assert!(offset.is_standard_layout());
        assert_eq!(first_rows(offset.clone(), 3), want(&offset, 3));
        let transposed = full.clone().permuted_axes([1, 0, 2]);
        assert!(!transposed.is_standard_layout());
        assert_eq!(first_rows(transposed.clone(), 2), want(&transposed, 2));
        assert_eq!(first_rows(full.clone(), 0).dim(), (0, 4, 3));
    }
}
