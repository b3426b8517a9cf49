//! The backends the project can run on, chosen with `--backend`. `flex` is the
//! default because it measured fastest on the CPU (see the backend
//! table of docs/speed.md) and the project's own CPU kernels are written for it; `ndarray`
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
    /// A GPU through wgpu on Vulkan (Metal on macOS, DX12 after Vulkan on Windows): the
    /// adapter wgpu prefers, a discrete GPU first; `CUBECL_WGPU_DEFAULT_DEVICE` picks another.
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
}

#[cfg(not(feature = "wgpu"))]
fn wgpu_device() -> Result<Device, BackendError> {
    Err(BackendError::NotBuilt)
}

#[cfg(feature = "wgpu")]
fn wgpu_device() -> Result<Device, BackendError> {
    use burn::tensor::wgpu::WgpuBackend;
    // The graphics APIs the networks' kernels compile on. Not OpenGL: where no
    // Vulkan driver is found wgpu falls back to it, and its shader validation
    // rejects the matrix product's kernels.
    const APIS: &[WgpuBackend] = if cfg!(target_os = "macos") || cfg!(target_os = "ios") {
        &[WgpuBackend::Auto]
    } else if cfg!(target_os = "windows") {
        &[WgpuBackend::Vulkan, WgpuBackend::Dx12]
    } else {
        &[WgpuBackend::Vulkan]
    };
    // wgpu starts once per process; later calls share that device (or its error).
    static DEVICE: std::sync::OnceLock<Result<Device, String>> = std::sync::OnceLock::new();
    DEVICE
        .get_or_init(|| {
            let mut errors = Vec::new();
            for &api in APIS {
                let started = Device::wgpu_options().graphics_api(api).init().map_err(|e| e.to_string());
                match started.and_then(|device| check_matmul(&device).map(|()| device)) {
                    Ok(device) => return Ok(device),
                    Err(e) => errors.push(format!("{api:?}: {e}")),
                }
            }
            Err(errors.join("; "))
        })
        .clone()
        .map_err(BackendError::NoAdapter)
}

/// Matrix products computed on the device, so that an adapter that starts but
/// cannot compile or run the kernels stops the run here, not at its first
/// convolution. A guard, not a proof: on OpenGL these products passed and a
/// larger kernel of the networks still failed, hence the pinned APIs above.
/// The shapes take kernels of vector widths 1, 2 and 4.
#[cfg(feature = "wgpu")]
fn check_matmul(device: &Device) -> Result<(), String> {
    for (m, k, n) in [(5usize, 5usize, 5usize), (6, 6, 6), (8, 8, 8), (130, 66, 34), (256, 72, 200)] {
        let a: Vec<f32> = (0..m * k).map(|i| (i % 7) as f32 - 3.0).collect();
        let b: Vec<f32> = (0..k * n).map(|i| (i % 5) as f32 - 2.0).collect();
        // Small integers: the product is exact in f32 in any summation order.
        let want: Vec<f32> = (0..m * n).map(|o| (0..k).map(|j| a[(o / n) * k + j] * b[j * n + o % n]).sum()).collect();
        let a = Tensor::<2>::from_data(TensorData::new(a, [m, k]), device);
        let b = Tensor::<2>::from_data(TensorData::new(b, [k, n]), device);
        let data = a.matmul(b).try_into_data().map_err(|e| {
            // The runtime's trace is long: keep the lines that say what failed.
            let text = e.to_string();
            let failed: Vec<&str> = text.lines().map(str::trim).filter(|l| l.contains("failed")).take(2).collect();
            let why =
                if failed.is_empty() { text.lines().next().unwrap_or("").to_string() } else { failed.join(" / ") };
            format!("the adapter cannot run the networks' kernels: {why}")
        })?;
        let product = data.try_to_vec::<f32>().map_err(|e| format!("{e:?}"))?;
        if product != want {
            return Err(format!("the adapter's {m} x {k} by {k} x {n} matrix product is wrong"));
        }
    }
    Ok(())
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
