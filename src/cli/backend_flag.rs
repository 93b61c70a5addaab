//! `--backend`: which [`densefeat::backend::Backend`] runs the ops (SPEC.md §15). Resolved before any
//! work, so an unavailable backend is refused up front.

use std::sync::Arc;

use clap::Args;

use densefeat::backend::{self, Backend};
use densefeat::error::Result;

/// The `--backend` flag.
#[derive(Debug, Clone, Args)]
pub struct BackendFlag {
    /// Where the ops run: `cpu`, or `gpu` (the wgpu backend, in builds with `--features gpu`: the network, cost volume, WTA and DTAM; SPEC.md §15.4).
    #[arg(long = "backend", default_value = "cpu")]
    pub name: String,
}

impl BackendFlag {
    /// The backend, or an error naming `--backend`.
    ///
    /// # Errors
    /// An unknown name, or a backend this build or machine does not have.
    pub fn resolve(&self) -> Result<Arc<dyn Backend>> {
        backend::by_name(&self.name)
    }
}
