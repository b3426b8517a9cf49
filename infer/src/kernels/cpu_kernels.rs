//! The switch for the project's own CPU kernels (GEMM convolutions, native
//! RoIAlign and max pooling), which replace Burn's on the flex backend. On by default; off,
//! every operation runs Burn's own kernels (benchmarks and tests compare the
//! two this way), and what those kernels share: telling a flex device and
//! reading a flex tensor's values.

use std::sync::atomic::{AtomicBool, Ordering};

use burn::backend::Flex;
use burn::backend::tensor::FloatTensor;
use burn::prelude::*;

static ENABLED: AtomicBool = AtomicBool::new(true);

/// Turns the project's kernels on or off for the whole process.
pub fn set_enabled(enabled: bool) {
    ENABLED.store(enabled, Ordering::Relaxed);
}

pub fn enabled() -> bool {
    ENABLED.load(Ordering::Relaxed)
}

/// Whether tensors on `device` live on flex (with or without autodiff), the
/// backend the kernels are written for.
pub fn is_flex(device: &Device) -> bool {
    device.clone().without_autodiff() == Device::flex()
}

/// Runs `f` on the tensor's values (copied to a contiguous buffer only when
/// the layout needs it).
pub fn with_values<R>(t: &FloatTensor<Flex>, f: impl FnOnce(&[f32]) -> R) -> R {
    match t.as_slice::<f32>() {
        Some(values) => f(values),
        None => f(t.to_contiguous().as_slice::<f32>().expect("a contiguous f32 tensor")),
    }
}
