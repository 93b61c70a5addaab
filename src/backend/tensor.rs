//! [`Tensor`]: an `[H, W, C]` f32 map on the host or on a backend's device.

use std::any::Any;
use std::fmt::Debug;
use std::sync::Arc;

use ndarray::Array3;

/// A backend's own buffer type behind a [`Tensor`] (for example a wgpu buffer).
pub trait DeviceBuffer: Any + Send + Sync + Debug {
    /// For the owning backend to downcast.
    fn as_any(&self) -> &dyn Any;
}

#[derive(Clone, Debug)]
enum Storage {
    Host(Arc<Array3<f32>>),
    Device { backend: &'static str, buffer: Arc<dyn DeviceBuffer> },
}

/// An `[H, W, C]` f32 map (channels last, SPEC.md §2.2). Cloning is cheap (shared storage); ops
/// never write into their inputs.
#[derive(Clone, Debug)]
pub struct Tensor {
    dim: (usize, usize, usize),
    storage: Storage,
}

impl Tensor {
    /// A host map (the CPU backend's tensors). A standard-layout array is moved in, not copied.
    pub fn host(a: Array3<f32>) -> Self {
        let a = if a.is_standard_layout() { a } else { a.as_standard_layout().into_owned() };
        Self { dim: a.dim(), storage: Storage::Host(Arc::new(a)) }
    }

    /// A device map owned by backend `backend` (its [`super::Backend::name`]).
    pub fn device(backend: &'static str, dim: (usize, usize, usize), buffer: Arc<dyn DeviceBuffer>) -> Self {
        Self { dim, storage: Storage::Device { backend, buffer } }
    }

    /// `(H, W, C)`.
    pub fn dim(&self) -> (usize, usize, usize) {
        self.dim
    }

    /// The host array, or `None` for a device tensor.
    pub fn as_host(&self) -> Option<&Array3<f32>> {
        match &self.storage {
            Storage::Host(a) => Some(a),
            Storage::Device { .. } => None,
        }
    }

    /// The host array, moved out when this is its only handle (else copied); `None` for a device
    /// tensor.
    pub fn into_host(self) -> Option<Array3<f32>> {
        match self.storage {
            Storage::Host(a) => Some(Arc::try_unwrap(a).unwrap_or_else(|a| (*a).clone())),
            Storage::Device { .. } => None,
        }
    }

    /// The host array moved out when this is its only handle, for reusing its storage; otherwise
    /// (shared, or a device tensor) the tensor itself, unchanged.
    ///
    /// # Errors
    /// Returns `self` when it is not a host map with a single handle.
    pub fn into_unique_host(self) -> std::result::Result<Array3<f32>, Tensor> {
        match self.storage {
            Storage::Host(a) => {
                Arc::try_unwrap(a).map_err(|a| Tensor { dim: self.dim, storage: Storage::Host(a) })
            }
            storage @ Storage::Device { .. } => Err(Tensor { dim: self.dim, storage }),
        }
    }

    /// The device buffer if it belongs to backend `backend`.
    pub fn device_buffer(&self, backend: &str) -> Option<&Arc<dyn DeviceBuffer>> {
        match &self.storage {
            Storage::Device { backend: b, buffer } if *b == backend => Some(buffer),
            _ => None,
        }
    }

    /// Where it lives: `host` or the owning backend's name.
    pub fn location(&self) -> &'static str {
        match &self.storage {
            Storage::Host(_) => "host",
            Storage::Device { backend, .. } => backend,
        }
    }
}
