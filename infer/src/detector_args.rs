//! The flags of every command that runs a detector, defined once: which
//! checkpoint, and on which backend.

use std::path::PathBuf;

use burn::prelude::Device;

use crate::backend::{BackendError, ComputeBackend};

/// The detector that ships with the project, relative to the repository.
pub const SHIPPED_CHECKPOINT: &str = "checkpoints/faster-rcnn";

#[derive(Debug, Clone, clap::Args)]
pub struct DetectorArgs {
    /// The detector checkpoint folder (config.json, model.bpk, meta.json).
    #[arg(long, default_value = SHIPPED_CHECKPOINT)]
    pub checkpoint: PathBuf,
    #[command(flatten)]
    pub backend: BackendArg,
}

#[derive(Debug, Clone, Copy, clap::Args)]
pub struct BackendArg {
    /// Where the networks run: flex (the CPU), ndarray, or wgpu (a GPU,
    /// when built with the `wgpu` feature).
    #[arg(long = "backend", value_name = "BACKEND", value_enum, default_value_t)]
    pub kind: ComputeBackend,
}

impl BackendArg {
    pub fn device(self) -> Result<Device, BackendError> {
        self.kind.device()
    }
}

impl DetectorArgs {
    pub fn device(&self) -> Result<Device, BackendError> {
        self.backend.device()
    }
}
