//! The feature network (SPEC.md §8), above the backend seam: [`weights`] (PyTorch names, Xavier
//! init, safetensors), [`network`] (the forward pass on a [`crate::backend::Backend`]), [`budget`] (the
//! network-level error bound), [`profile`] (per-op timing) and [`viz`] (a PCA colouring of
//! features). Its kernels live in [`crate::ops`], below the seam.

pub mod budget;
pub mod network;
pub mod prepared;
pub mod profile;
pub mod viz;
pub mod weights;

pub use crate::ops::config::NetworkConfig;
pub use network::{FeatureNet, ForwardOutput};
pub use prepared::PreparedNetwork;
pub use profile::{profile_forward, OpTotals};
pub use weights::NetworkWeights;
