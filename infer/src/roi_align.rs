//! RoIAlign (torchvision's `roi_align` with `aligned=True` and a fixed
//! sampling ratio). On flex it runs the native kernel of `roi_align_native`;
//! elsewhere (a GPU) it is built from `grid_sample_2d`, so that autodiff gives
//! its gradient with respect to the feature map on any device. Both follow
//! torchvision at the border: a sample within one pixel outside the map is
//! moved onto its edge, one farther out reads zero.

use burn::nn::pool::AvgPool2dConfig;
use burn::prelude::*;
use burn::tensor::DType;
use burn::tensor::ops::{GridSampleOptions, GridSamplePaddingMode, InterpolateMode};

use crate::boxes::BBox;
use crate::kernels::{cpu_kernels, roi_align_native};

/// Pools each of `rois` (in feature-map pixels) from one feature map
/// `[1, C, H, W]` to `[K, C, output, output]`. Each output bin averages
/// `sampling x sampling` bilinear samples.
pub fn roi_align(features: Tensor<4>, rois: &[BBox], output: usize, sampling: usize) -> Tensor<4> {
    let native = cpu_kernels::enabled() && cpu_kernels::is_flex(&features.device());
    if native && features.dtype() == DType::F32 && !rois.is_empty() {
        return roi_align_native::roi_align_flex(features, rois, output, sampling);
    }
    roi_align_grid_sample(features, rois, output, sampling)
}

/// RoIAlign as a `grid_sample_2d` composition (any device, differentiable).
pub fn roi_align_grid_sample(features: Tensor<4>, rois: &[BBox], output: usize, sampling: usize) -> Tensor<4> {
    let [_, c, h, w] = features.dims();
    let device = features.device();
    let k = rois.len();
    let s = output * sampling;
    let mut grid = Vec::with_capacity(k * s * s * 2);
    for r in rois {
        // aligned=True: pixel centres sit at half-integers, hence the -0.5 shift.
        let (x1, y1) = (r.x1 - 0.5, r.y1 - 0.5);
        let (bw, bh) = ((r.x2 - r.x1) / s as f32, (r.y2 - r.y1) / s as f32);
        for iy in 0..s {
            for ix in 0..s {
                let (x, y) = (x1 + (ix as f32 + 0.5) * bw, y1 + (iy as f32 + 0.5) * bh);
                match (torchvision_sample(x, w), torchvision_sample(y, h)) {
                    // grid_sample's normalised coordinates with align_corners = false.
                    (Some(x), Some(y)) => {
                        grid.push((x + 0.5) / w as f32 * 2.0 - 1.0);
                        grid.push((y + 0.5) / h as f32 * 2.0 - 1.0);
                    }
                    // Far outside the map: zero padding gives zero.
                    _ => grid.extend([-4.0, -4.0]),
                }
            }
        }
    }
    let grid = Tensor::<4>::from_data(TensorData::new(grid, [1, k * s, s, 2]), &device);
    let options = GridSampleOptions::new(InterpolateMode::Bilinear)
        .with_padding_mode(GridSamplePaddingMode::Zeros)
        .with_align_corners(false);
    // [1, C, K*s, s] -> [K, C, s, s]
    let sampled = features.grid_sample_2d(grid, options).reshape([c, k, s, s]).swap_dims(0, 1);
    AvgPool2dConfig::new([sampling, sampling]).with_strides([sampling, sampling]).init().forward(sampled)
}

/// torchvision's treatment of a sample coordinate on an axis of `n` pixels:
/// none beyond one pixel outside, clamped onto the edge pixel within it.
fn torchvision_sample(v: f32, n: usize) -> Option<f32> {
    (-1.0..=n as f32).contains(&v).then(|| v.clamp(0.0, n as f32 - 1.0))
}
