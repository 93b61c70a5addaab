//! The wgpu backend (cargo feature `gpu`, SPEC.md §15.5): the network ops as WGSL compute kernels
//! on whatever adapter wgpu finds (Vulkan, Metal, DX12, GL; in CI Mesa's software Vulkan driver,
//! lavapipe). Tensors live in device storage buffers ([`GpuBuffer`]) between ops; `upload` and
//! `download` are the only crossings, and an op given a host tensor returns
//! [`Error::Unsupported`] ("upload it first"). The mapping ops run here too: the cost volume keeps
//! its sums and counts on the device between frames ([`volume`]), winner-take-all ([`wta`]) and the
//! DTAM solve ([`dtam`]) keep their state on the device and only scalars cross per iteration; a
//! finished volume can stay there for every step up to DTAM ([`resident`], SPEC.md §15.6). They
//! need shader f64 (the CPU's f64 geometry and solver arithmetic) and return
//! [`Error::Unsupported`] on an adapter without it.

mod dtam;
mod kernels;
mod resident;
mod volume;
mod wta;

pub use dtam::DtamTimings;

use std::any::Any;
use std::collections::HashMap;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex, OnceLock, Weak};

use ndarray::{Array3, ArrayView3};
use wgpu::util::DeviceExt;

use super::{Backend, DeviceBuffer, LayerOp, PreparedLayer, Tensor, Traffic, VolumeBuilder};
use crate::costvolume::WtaDepth;
use crate::dtam::{DtamProblem, DtamReport, DtamResult};
use crate::error::{Error, Result};
use crate::geometry::{InverseDepthBins, PinholeCamera};
use crate::ops::geometry::DownsampleGeometry;
use crate::ops::Activation;
use crate::ops::LayerParams;
use crate::ops::{conv_geometry, deconv_geometry};

const NAME: &str = "gpu";
/// Invocations per workgroup (every kernel's `@workgroup_size`).
const WORKGROUP: u32 = 64;
/// Workgroups along x before a dispatch wraps to the next y row (under WebGPU's 65 535).
const MAX_GROUPS_X: u32 = 32_768;

fn unsupported(what: impl Into<String>) -> Error {
    Error::Unsupported { backend: NAME.into(), what: what.into() }
}

/// A device storage buffer holding an `[H, W, C]` f32 map in standard (C) order.
#[derive(Debug)]
pub struct GpuBuffer {
    buffer: wgpu::Buffer,
    /// f32 elements (the buffer itself is at least 4 bytes: wgpu binds no empty buffers).
    len: usize,
}

impl DeviceBuffer for GpuBuffer {
    fn as_any(&self) -> &dyn Any {
        self
    }
}

/// The wgpu backend: one device and queue, and its compiled pipelines. Layer weights live in the
/// prepared layers its callers own ([`Backend::prepare_layer`]).
pub struct GpuBackend {
    /// This backend itself (it lives in an `Arc`), for the cost-volume builders that outlive a call.
    me: Weak<GpuBackend>,
    device: wgpu::Device,
    queue: wgpu::Queue,
    info: wgpu::AdapterInfo,
    /// `Features::SHADER_F64` is on (the bit-exact downsampling needs it).
    f64: bool,
    max_binding: u64,
    pipelines: Mutex<HashMap<(&'static str, &'static str), wgpu::ComputePipeline>>,
    /// Bytes written into new device buffers and read back so far ([`Backend::traffic`]).
    uploaded: AtomicU64,
    downloaded: AtomicU64,
}

impl std::fmt::Debug for GpuBackend {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("GpuBackend").field("adapter", &self.info.name).field("f64", &self.f64).finish()
    }
}

static SHARED: OnceLock<std::result::Result<Arc<GpuBackend>, String>> = OnceLock::new();

/// Buffer usages of every storage buffer here (bound, copied from and to).
const STORAGE: wgpu::BufferUsages =
    wgpu::BufferUsages::STORAGE.union(wgpu::BufferUsages::COPY_SRC).union(wgpu::BufferUsages::COPY_DST);

impl GpuBackend {
    /// The process's GPU backend (created on first use, then shared: one device per process).
    ///
    /// # Errors
    /// [`Error::Unsupported`] when wgpu finds no adapter or the device cannot be created.
    pub fn shared() -> Result<Arc<GpuBackend>> {
        SHARED.get_or_init(Self::new).clone().map_err(unsupported)
    }

    /// A new device on the first adapter wgpu offers (any backend; `WGPU_BACKEND` narrows it).
    fn new() -> std::result::Result<Arc<Self>, String> {
        let instance = wgpu::Instance::new(wgpu::InstanceDescriptor::new_without_display_handle_from_env());
        let adapter = pollster::block_on(instance.request_adapter(&wgpu::RequestAdapterOptions {
            power_preference: wgpu::PowerPreference::HighPerformance,
            ..Default::default()
        }))
        .map_err(|e| {
            format!(
                "no GPU adapter ({e}); install a Vulkan driver (e.g. Mesa's lavapipe: \
                 apt-get install mesa-vulkan-drivers libvulkan1) or use --backend cpu"
            )
        })?;
        let info = adapter.get_info();
        let f64 = adapter.features().contains(wgpu::Features::SHADER_F64);
        let limits = adapter.limits();
        let max_binding = limits.max_storage_buffer_binding_size.min(limits.max_buffer_size);
        let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("densefeat"),
            required_features: if f64 { wgpu::Features::SHADER_F64 } else { wgpu::Features::empty() },
            required_limits: limits,
            ..Default::default()
        }))
        .map_err(|e| format!("adapter {} refused a device: {e}", info.name))?;
        Ok(Arc::new_cyclic(|me| Self {
            me: me.clone(),
            device,
            queue,
            info,
            f64,
            max_binding,
            pipelines: Mutex::new(HashMap::new()),
            uploaded: AtomicU64::new(0),
            downloaded: AtomicU64::new(0),
        }))
    }

    /// [`Backend::dtam_solve`] with the time of its parts: uploads, iterations (with the read-backs
    /// of the stopping rule) and the final download (`densefeat bench tv --backend gpu`).
    ///
    /// # Errors
    /// As [`Backend::dtam_solve`].
    pub fn dtam_solve_timed(&self, problem: &DtamProblem) -> Result<(DtamResult, DtamReport, DtamTimings)> {
        dtam::solve_timed(self, problem)
    }

    /// A shared handle to this backend.
    fn arc(&self) -> Result<Arc<GpuBackend>> {
        self.me.upgrade().ok_or_else(|| unsupported("the GPU backend was dropped"))
    }

    /// [`Error::Unsupported`] for `op` unless the device has shader f64.
    fn require_f64(&self, op: &str, why: &str) -> Result<()> {
        if self.f64 {
            Ok(())
        } else {
            Err(unsupported(format!(
                "{op} needs shader f64 ({why}), which adapter {} lacks; use --backend cpu",
                self.info.name
            )))
        }
    }

    /// The buffer of a tensor of this backend, or [`Error::Unsupported`] naming where it lives.
    fn buffer<'a>(&self, x: &'a Tensor) -> Result<&'a GpuBuffer> {
        x.device_buffer(NAME).and_then(|b| b.as_any().downcast_ref::<GpuBuffer>()).ok_or_else(|| {
            unsupported(format!(
                "a tensor on `{}`: upload it to the GPU first (Backend::upload)",
                x.location()
            ))
        })
    }

    fn check_size(&self, elements: usize) -> Result<u64> {
        let bytes = (elements.max(1) as u64) * 4;
        if bytes > self.max_binding || elements > u32::MAX as usize {
            return Err(unsupported(format!(
                "a map of {elements} f32 exceeds the adapter's largest storage binding ({} bytes)",
                self.max_binding
            )));
        }
        Ok(bytes)
    }

    /// An uninitialised output map.
    fn alloc(&self, dim: (usize, usize, usize)) -> Result<Tensor> {
        let len = dim.0 * dim.1 * dim.2;
        let size = self.check_size(len)?;
        let buffer = self.device.create_buffer(&wgpu::BufferDescriptor {
            label: None,
            size,
            usage: STORAGE,
            mapped_at_creation: false,
        });
        Ok(Tensor::device(NAME, dim, Arc::new(GpuBuffer { buffer, len })))
    }

    fn storage_init(&self, data: &[f32]) -> wgpu::Buffer {
        self.storage_bytes(bytemuck::cast_slice(data))
    }

    /// A storage buffer holding `contents` (at least 8 bytes: wgpu binds no empty buffer, and an
    /// f64 array needs one element).
    fn storage_bytes(&self, contents: &[u8]) -> wgpu::Buffer {
        let mut padded;
        let contents = if contents.len() < 8 {
            padded = contents.to_vec();
            padded.resize(8, 0);
            &padded[..]
        } else {
            contents
        };
        self.uploaded.fetch_add(contents.len() as u64, Ordering::Relaxed);
        self.device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: None,
            contents,
            usage: STORAGE,
        })
    }

    /// A zero-filled storage buffer of `bytes` bytes (at least 8), after checking it fits a binding.
    fn storage_zeroed(&self, bytes: u64) -> Result<wgpu::Buffer> {
        if bytes > self.max_binding {
            return Err(unsupported(format!(
                "a buffer of {bytes} bytes exceeds the adapter's largest storage binding ({} bytes)",
                self.max_binding
            )));
        }
        // wgpu zero-initialises new buffers.
        Ok(self.device.create_buffer(&wgpu::BufferDescriptor {
            label: None,
            size: bytes.max(8).next_multiple_of(4),
            usage: STORAGE,
            mapped_at_creation: false,
        }))
    }

    /// The compiled pipeline `name` (compiled once per backend).
    fn pipeline(&self, name: &'static str, body: &str) -> Result<wgpu::ComputePipeline> {
        self.pipeline_entry(name, "main", || kernels::source(body))
    }

    /// The compiled pipeline of entry point `entry` of module `module` (compiled once per backend;
    /// `source` is only called the first time).
    ///
    /// # Errors
    /// [`Error::Unsupported`] with the compiler's message when the device rejects the kernel.
    fn pipeline_entry(
        &self,
        module: &'static str,
        entry: &'static str,
        source: impl FnOnce() -> String,
    ) -> Result<wgpu::ComputePipeline> {
        let mut cache = self.pipelines.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(p) = cache.get(&(module, entry)) {
            return Ok(p.clone());
        }
        let scope = self.device.push_error_scope(wgpu::ErrorFilter::Validation);
        let m = self.device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some(module),
            source: wgpu::ShaderSource::Wgsl(source().into()),
        });
        let pipeline = self.device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
            label: Some(entry),
            layout: None,
            module: &m,
            entry_point: Some(entry),
            compilation_options: Default::default(),
            cache: None,
        });
        if let Some(e) = pollster::block_on(scope.pop()) {
            return Err(unsupported(format!(
                "kernel {module}::{entry} does not compile on adapter {}: {e}",
                self.info.name
            )));
        }
        cache.insert((module, entry), pipeline.clone());
        Ok(pipeline)
    }

    /// A bind group of `pipeline`'s group 0 with `(binding, buffer)` entries.
    fn bind(&self, pipeline: &wgpu::ComputePipeline, entries: &[(u32, &wgpu::Buffer)]) -> wgpu::BindGroup {
        let entries: Vec<wgpu::BindGroupEntry> = entries
            .iter()
            .map(|(binding, b)| wgpu::BindGroupEntry { binding: *binding, resource: b.as_entire_binding() })
            .collect();
        self.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: None,
            layout: &pipeline.get_bind_group_layout(0),
            entries: &entries,
        })
    }

    /// Waits until every submitted command has finished.
    fn wait(&self) -> Result<()> {
        self.device
            .poll(wgpu::PollType::wait_indefinitely())
            .map(|_| ())
            .map_err(|e| unsupported(format!("device poll failed: {e}")))
    }

    /// `size` bytes of `src` from `offset`, copied back to the host (waits for the device).
    fn read_back(&self, src: &wgpu::Buffer, offset: u64, size: u64) -> Result<Vec<u8>> {
        if size == 0 {
            return Ok(Vec::new());
        }
        self.downloaded.fetch_add(size, Ordering::Relaxed);
        let staging = self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("download"),
            size,
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let mut encoder =
            self.device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("download") });
        encoder.copy_buffer_to_buffer(src, offset, &staging, 0, size);
        self.queue.submit([encoder.finish()]);
        let (tx, rx) = std::sync::mpsc::channel();
        staging.slice(..).map_async(wgpu::MapMode::Read, move |r| {
            let _ = tx.send(r);
        });
        self.wait()?;
        rx.recv()
            .map_err(|_| unsupported("download: the map callback never ran"))?
            .map_err(|e| unsupported(format!("download: mapping failed: {e}")))?;
        let data = {
            let view = staging
                .slice(..)
                .get_mapped_range()
                .map_err(|e| unsupported(format!("download: mapped range: {e}")))?;
            view[..].to_vec()
        };
        staging.unmap();
        Ok(data)
    }

    /// Runs kernel `name` over `params[0]` outputs: binding 0 the parameters, then `inputs`, then
    /// `out`. Submitted, not waited for (a download waits).
    fn dispatch(
        &self,
        name: &'static str,
        body: &str,
        params: &[u32],
        inputs: &[&wgpu::Buffer],
        out: &Tensor,
    ) -> Result<()> {
        let n = params[0];
        if n == 0 {
            return Ok(());
        }
        let out = &self.buffer(out)?.buffer;
        let pipeline = self.pipeline(name, body)?;
        let params = self.device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: None,
            contents: bytemuck::cast_slice(params),
            usage: wgpu::BufferUsages::STORAGE,
        });
        let mut entries = vec![wgpu::BindGroupEntry { binding: 0, resource: params.as_entire_binding() }];
        for (k, b) in inputs.iter().chain(std::iter::once(&out)).enumerate() {
            entries.push(wgpu::BindGroupEntry { binding: k as u32 + 1, resource: b.as_entire_binding() });
        }
        let group = self.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some(name),
            layout: &pipeline.get_bind_group_layout(0),
            entries: &entries,
        });
        let groups = n.div_ceil(WORKGROUP);
        let gx = groups.min(MAX_GROUPS_X);
        let gy = groups.div_ceil(gx);
        let mut encoder =
            self.device.create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some(name) });
        {
            let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some(name),
                timestamp_writes: None,
            });
            pass.set_pipeline(&pipeline);
            pass.set_bind_group(0, &group, &[]);
            pass.dispatch_workgroups(gx, gy, 1);
        }
        self.queue.submit([encoder.finish()]);
        Ok(())
    }
}

/// A layer prepared by the GPU backend: its weights `[c_out, ky, kx, c_in]` followed by the bias,
/// on the device, and where the bias starts.
#[derive(Debug)]
struct GpuLayer {
    weights: wgpu::Buffer,
    bias_offset: usize,
}

/// `u32` kernel parameters from sizes (callers checked the element count fits).
fn params<const N: usize>(v: [usize; N]) -> [u32; N] {
    v.map(|x| u32::try_from(x).expect("sizes were checked against u32"))
}

impl Backend for GpuBackend {
    fn name(&self) -> &'static str {
        NAME
    }

    fn device(&self) -> String {
        format!(
            "{} ({:?}, {:?}, driver {} {}; f64 {})",
            self.info.name,
            self.info.device_type,
            self.info.backend,
            self.info.driver,
            self.info.driver_info,
            if self.f64 { "yes" } else { "no" }
        )
    }

    fn upload(&self, x: ArrayView3<f32>) -> Result<Tensor> {
        let x = x.as_standard_layout();
        let data = x.as_slice().expect("standard layout is contiguous");
        self.check_size(data.len())?;
        let buffer = self.storage_init(data);
        Ok(Tensor::device(NAME, x.dim(), Arc::new(GpuBuffer { buffer, len: data.len() })))
    }

    fn download(&self, x: &Tensor) -> Result<Array3<f32>> {
        let src = self.buffer(x)?;
        if src.len == 0 {
            return Ok(Array3::zeros(x.dim()));
        }
        let bytes = self.read_back(&src.buffer, 0, src.len as u64 * 4)?;
        let data = f32s(&bytes);
        Array3::from_shape_vec(x.dim(), data).map_err(|e| unsupported(format!("download: {e}")))
    }

    fn synchronize(&self) -> Result<()> {
        self.wait()
    }

    fn traffic(&self) -> Traffic {
        Traffic {
            uploaded: self.uploaded.load(Ordering::Relaxed),
            downloaded: self.downloaded.load(Ordering::Relaxed),
        }
    }

    fn prepare_layer(&self, layer: Arc<LayerParams>, op: LayerOp) -> Result<PreparedLayer> {
        let l = &*layer;
        if l.weight.ndim() != 4 || l.bias.ndim() != 1 {
            return Err(Error::invalid_argument("layer", "expected a 4-d weight and a 1-d bias"));
        }
        // Weights `[c_out, ky, kx, c_in]` with the bias appended (SPEC.md §15.2).
        let (c_out, c_in, k) = match op {
            LayerOp::Conv3x3 => (l.weight.shape()[0], l.weight.shape()[1], 3),
            LayerOp::Deconv5x5s2 => (l.weight.shape()[1], l.weight.shape()[0], 5),
        };
        let mut packed = Vec::with_capacity(c_out * k * k * c_in + c_out);
        for o in 0..c_out {
            for ky in 0..k {
                for kx in 0..k {
                    packed.extend((0..c_in).map(|c| match op {
                        LayerOp::Conv3x3 => l.weight[[o, c, ky, kx]],
                        LayerOp::Deconv5x5s2 => l.weight[[c, o, ky, kx]],
                    }));
                }
            }
        }
        packed.extend(l.bias.iter());
        self.check_size(packed.len())?;
        let buffer = GpuLayer { weights: self.storage_init(&packed), bias_offset: c_out * k * k * c_in };
        Ok(PreparedLayer::new(NAME, op, layer, Arc::new(buffer)))
    }

    fn conv3x3(&self, x: &Tensor, l: &PreparedLayer, stride: usize, act: Activation) -> Result<Tensor> {
        let xb = self.buffer(x)?;
        let wt: &GpuLayer = l.data(NAME, LayerOp::Conv3x3)?;
        let g = conv_geometry(x.dim(), l.params(), stride)?;
        let (h, w, c_in) = x.dim();
        let [h_out, w_out, c_out] = g.output_shape();
        let out = self.alloc((h_out, w_out, c_out))?;
        let relu = usize::from(matches!(act, Activation::Relu));
        let p = params([h_out * w_out * c_out, h, w, c_in, w_out, c_out, stride, relu, wt.bias_offset]);
        self.dispatch("conv3x3", kernels::CONV3X3, &p, &[&xb.buffer, &wt.weights], &out)?;
        Ok(out)
    }

    fn deconv5x5s2(&self, x: &Tensor, l: &PreparedLayer) -> Result<Tensor> {
        let xb = self.buffer(x)?;
        let wt: &GpuLayer = l.data(NAME, LayerOp::Deconv5x5s2)?;
        let g = deconv_geometry(x.dim(), l.params())?;
        let (h, w, c_in) = x.dim();
        let [h_out, w_out, c_out] = g.output_shape();
        let out = self.alloc((h_out, w_out, c_out))?;
        let p = params([h_out * w_out * c_out, h, w, c_in, c_out, wt.bias_offset]);
        self.dispatch("deconv5x5s2", kernels::DECONV5X5S2, &p, &[&xb.buffer, &wt.weights], &out)?;
        Ok(out)
    }

    fn downsample2x(&self, x: &Tensor) -> Result<Tensor> {
        let xb = self.buffer(x)?;
        if !self.f64 {
            return Err(unsupported(format!(
                "downsample2x needs shader f64 (SPEC.md §7.4 sums in f64), which adapter {} lacks",
                self.info.name
            )));
        }
        let (h, w, c) = x.dim();
        let [h_out, w_out, _] = DownsampleGeometry::new(h, w, c)?.output_shape();
        let out = self.alloc((h_out, w_out, c))?;
        let p = params([h_out * w_out * c, h, w, c, w_out]);
        self.dispatch("downsample2x", kernels::DOWNSAMPLE_F64, &p, &[&xb.buffer], &out)?;
        Ok(out)
    }

    fn concat(&self, a: &Tensor, b: &Tensor) -> Result<Tensor> {
        let (ab, bb) = (self.buffer(a)?, self.buffer(b)?);
        let ((h, w, ca), (hb, wb, cb)) = (a.dim(), b.dim());
        if (h, w) != (hb, wb) {
            return Err(Error::invalid_argument(
                "concat_channels",
                format!("spatial sizes differ: {:?} and {:?}", a.dim(), b.dim()),
            ));
        }
        let out = self.alloc((h, w, ca + cb))?;
        let p = params([h * w * (ca + cb), ca, cb]);
        self.dispatch("concat", kernels::CONCAT, &p, &[&ab.buffer, &bb.buffer], &out)?;
        Ok(out)
    }

    fn add(&self, a: &Tensor, b: &Tensor) -> Result<Tensor> {
        let (ab, bb) = (self.buffer(a)?, self.buffer(b)?);
        if a.dim() != b.dim() {
            return Err(Error::invalid_argument(
                "add",
                format!("shapes differ: {:?} and {:?}", a.dim(), b.dim()),
            ));
        }
        let out = self.alloc(a.dim())?;
        self.dispatch("add", kernels::ADD, &params([ab.len]), &[&ab.buffer, &bb.buffer], &out)?;
        Ok(out)
    }

    fn crop(&self, x: Tensor, h: usize, w: usize) -> Result<Tensor> {
        let xb = self.buffer(&x)?;
        let (hx, wx, c) = x.dim();
        if (hx, wx) == (h, w) {
            return Ok(x);
        }
        if h > hx || w > wx {
            return Err(Error::invalid_argument("crop", format!("{h}x{w} window of a {hx}x{wx} map")));
        }
        let out = self.alloc((h, w, c))?;
        self.dispatch("crop", kernels::CROP, &params([h * w * c, wx, w, c]), &[&xb.buffer], &out)?;
        Ok(out)
    }

    fn cost_volume(
        &self,
        reference: &Tensor,
        camera: PinholeCamera,
        bins: InverseDepthBins,
        truncation: f32,
    ) -> Result<Box<dyn VolumeBuilder>> {
        Ok(Box::new(volume::GpuVolume::new(self.arc()?, reference, camera, bins, truncation)?))
    }

    fn winner_take_all(&self, costs: ArrayView3<f32>, bins: &InverseDepthBins) -> Result<WtaDepth> {
        wta::winner_take_all(self, costs, bins)
    }

    fn dtam_solve(&self, problem: &DtamProblem) -> Result<(DtamResult, DtamReport)> {
        dtam::solve(self, problem)
    }
}

/// Host `f32`s from bytes read back (native byte order, as the device wrote them).
fn f32s(bytes: &[u8]) -> Vec<f32> {
    bytes.chunks_exact(4).map(|b| f32::from_ne_bytes([b[0], b[1], b[2], b[3]])).collect()
}

/// Host `u32`s from bytes read back.
fn u32s(bytes: &[u8]) -> Vec<u32> {
    bytes.chunks_exact(4).map(|b| u32::from_ne_bytes([b[0], b[1], b[2], b[3]])).collect()
}

/// Host `f64`s from bytes read back.
fn f64s(bytes: &[u8]) -> Vec<f64> {
    bytes
        .chunks_exact(8)
        .map(|b| f64::from_ne_bytes([b[0], b[1], b[2], b[3], b[4], b[5], b[6], b[7]]))
        .collect()
}

/// [`Error::Unsupported`] unless every cost is finite: WGSL lets a device assume no NaN or infinity
/// reaches a comparison, so the GPU's argmin over such costs would not be defined
/// (`UNSEEN_COST` itself is finite).
fn check_finite(op: &str, what: &str, values: impl IntoIterator<Item = f32>) -> Result<()> {
    match values.into_iter().find(|v| !v.is_finite()) {
        None => Ok(()),
        Some(v) => Err(unsupported(format!(
            "{op}: a non-finite {what} ({v}); the GPU kernels take finite values only \
             (unseen cells are UNSEEN_COST); use --backend cpu"
        ))),
    }
}

/// Workgroups for `n` invocations of a 64-wide kernel on the 2D grid (see [`kernels`]).
fn groups(n: u32) -> (u32, u32) {
    let groups = n.div_ceil(WORKGROUP);
    let gx = groups.clamp(1, MAX_GROUPS_X);
    (gx, groups.div_ceil(gx))
}

/// Records one dispatch of `pipeline` over `n` invocations (nothing for `n = 0`).
fn record(pass: &mut wgpu::ComputePass, pipeline: &wgpu::ComputePipeline, group: &wgpu::BindGroup, n: u32) {
    if n == 0 {
        return;
    }
    let (gx, gy) = groups(n);
    pass.set_pipeline(pipeline);
    pass.set_bind_group(0, group, &[]);
    pass.dispatch_workgroups(gx, gy, 1);
}
