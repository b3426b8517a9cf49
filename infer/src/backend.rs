//! The backends the project can run on, chosen with `--backend`. `flex` is the
//! default because it measured fastest on the CPU (see the README's backend
//! table) and the project's own CPU kernels are written for it; `ndarray`
//! stays selectable. `wgpu` runs on a GPU through Burn's wgpu backend (Vulkan,
//! Metal or DX12) and is compiled in only with the `wgpu` feature of this crate,
//! so the default build does not pay for it.

use burn::prelude::*;
use serde::{Deserialize, Serialize};

#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "kebab-case")]
pub enum ComputeBackend {
    #[default]
    Flex,
    Ndarray,
    /// The first adapter wgpu prefers (a discrete GPU first); `CUBECL_WGPU_DEFAULT_DEVICE`
    /// overrides the choice.
    Wgpu,
}

#[derive(Debug, thiserror::Error)]
pub enum BackendError {
    #[error(
        "--backend wgpu needs a build with the `wgpu` feature: \
         cargo build --release --features infer/wgpu"
    )]
    NotBuilt,
    #[error("--backend wgpu: no usable wgpu adapter (Vulkan, Metal or DX12 driver) on this machine: {0}")]
    NoAdapter(String),
}

impl ComputeBackend {
    /// The device, checked to be usable: a GPU backend that cannot start is an
    /// error here, not a panic in the middle of a run.
    pub fn device(self) -> Result<Device, BackendError> {
        match self {
            Self::Flex => Ok(Device::flex()),
            #[allow(deprecated)]
            Self::Ndarray => Ok(Device::ndarray()),
            Self::Wgpu => wgpu_device(),
        }
    }

    /// Whether this is a CPU backend (the project's CPU kernels and its
    /// host-side fast paths apply only there).
    pub fn is_cpu(self) -> bool {
        !matches!(self, Self::Wgpu)
    }
}

#[cfg(not(feature = "wgpu"))]
fn wgpu_device() -> Result<Device, BackendError> {
    Err(BackendError::NotBuilt)
}

#[cfg(feature = "wgpu")]
fn wgpu_device() -> Result<Device, BackendError> {
    // wgpu starts once per process; later calls share that device (or its error).
    static DEVICE: std::sync::OnceLock<Result<Device, String>> = std::sync::OnceLock::new();
    DEVICE
        .get_or_init(|| Device::wgpu_options().init().map_err(|e| e.to_string()))
        .clone()
        .map_err(BackendError::NoAdapter)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cpu_backends_start_and_wgpu_names_its_feature_when_not_built() {
        for backend in [ComputeBackend::Flex, ComputeBackend::Ndarray] {
            let device = backend.device().unwrap();
            assert_eq!(Tensor::<1>::ones([3], &device).sum().into_scalar::<f32>(), 3.0);
        }
        let wgpu = ComputeBackend::Wgpu.device();
        if cfg!(feature = "wgpu") {
            // Either a device that computed the probe or an error that says why not.
            if let Err(e) = wgpu {
                assert!(matches!(e, BackendError::NoAdapter(_)), "{e}");
            }
        } else {
            let message = wgpu.expect_err("no wgpu device without the feature").to_string();
            assert!(message.contains("--features infer/wgpu"), "{message}");
        }
    }
}
