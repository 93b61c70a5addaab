//! A network's layers prepared by one backend ([`Backend::prepare_layer`], SPEC.md §15.1): built
//! once per network and backend (by [`crate::nn::FeatureNet`] on its first pass on that backend,
//! by training once per step), owned by its maker and dropped with it. The forward pass
//! ([`crate::nn::network::run_network`]) runs on it, so no layer is packed or uploaded per call.

use std::sync::Arc;

use crate::backend::{Backend, LayerOp, PreparedLayer};
use crate::error::Result;
use crate::nn::weights::NetworkWeights;
use crate::ops::config::NetworkConfig;

/// The layers of one [`NetworkWeights`], prepared by one backend.
#[derive(Clone, Debug)]
pub struct PreparedNetwork {
    config: NetworkConfig,
    backend: &'static str,
    /// `blocks[k]`: block `k`'s three convolutions.
    pub(crate) blocks: Vec<[PreparedLayer; 3]>,
    /// `deconvs[i]`: the transposed convolution onto block `i`'s grid.
    pub(crate) deconvs: Vec<PreparedLayer>,
}

impl PreparedNetwork {
    /// `weights`' layers prepared by `backend`.
    ///
    /// # Errors
    /// [`crate::Error::InvalidArgument`] for weights that do not match their configuration; the
    /// backend's preparation errors.
    pub fn new(weights: &NetworkWeights, backend: &dyn Backend) -> Result<Self> {
        weights.validate()?;
        let conv = |l: &crate::ops::LayerParams| backend.prepare_layer(Arc::new(l.clone()), LayerOp::Conv3x3);
        let blocks = weights
            .blocks
            .iter()
            .map(|b| Ok([conv(&b.conv1)?, conv(&b.conv2)?, conv(&b.conv3)?]))
            .collect::<Result<Vec<_>>>()?;
        let deconvs = weights
            .deconvs
            .iter()
            .map(|l| backend.prepare_layer(Arc::new(l.clone()), LayerOp::Deconv5x5s2))
            .collect::<Result<Vec<_>>>()?;
        Ok(PreparedNetwork { config: weights.config, backend: backend.name(), blocks, deconvs })
    }

    /// The configuration.
    pub fn config(&self) -> &NetworkConfig {
        &self.config
    }

    /// The name of the backend that prepared it.
    pub fn backend(&self) -> &'static str {
        self.backend
    }
}
