//! RoIAlign as torchvision computes it (`aligned=True`, a fixed sampling
//! ratio), forward and backward, on host memory; plugged into the flex
//! backend (with and without autodiff) as a Burn backend extension.
//!
//! Why: the `grid_sample_2d` composition in `roi_align` is exact for boxes
//! inside the map but its backward runs as single-threaded scatter-adds and
//! layout copies, about a quarter of a Faster R-CNN training step on the CPU.
//! Here the forward runs in parallel over boxes on a channels-last copy of
//! the map, the backward over channel planes, and boxes at the border
//! follow torchvision's clamping.

use burn::backend::autodiff::Autodiff;
use burn::backend::autodiff::checkpoint::base::Checkpointer;
use burn::backend::autodiff::checkpoint::strategy::CheckpointStrategy;
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops, OpsKind};
use burn::backend::ops::FloatTensorOps;
use burn::backend::tensor::FloatTensor;
use burn::backend::{Backend, Dispatch, Flex, TensorMetadata, backend_extension};
use burn::prelude::*;
use burn::tensor::DType;
use rayon::prelude::*;

use crate::boxes::BBox;
use crate::kernels::cpu_kernels::with_values;

/// The sizes of one RoIAlign call: a feature map [C, H, W] pooled to
/// `output x output` bins of `sampling x sampling` samples each.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RoiShape {
    pub channels: usize,
    pub height: usize,
    pub width: usize,
    pub output: usize,
    pub sampling: usize,
}

/// One bilinear sample: four taps (flat index into a [H, W] plane, weight),
/// or none when the sample lies more than a pixel outside the map.
type Taps = Option<[(usize, f32); 4]>;

/// torchvision's `bilinear_interpolate`: samples within one pixel outside
/// the map are clamped onto its edge, samples farther out read zero.
fn taps(y: f32, x: f32, height: usize, width: usize) -> Taps {
    if y < -1.0 || y > height as f32 || x < -1.0 || x > width as f32 {
        return None;
    }
    let (y_low, y_high, ly) = axis_taps(y, height);
    let (x_low, x_high, lx) = axis_taps(x, width);
    let (hy, hx) = (1.0 - ly, 1.0 - lx);
    Some([
        (y_low * width + x_low, hy * hx),
        (y_low * width + x_high, hy * lx),
        (y_high * width + x_low, ly * hx),
        (y_high * width + x_high, ly * lx),
    ])
}

/// Along one axis of `size` pixels: the two neighbouring pixels of `v` and
/// the weight of the upper one; at or past the last pixel both are that
/// pixel, with no fraction.
fn axis_taps(v: f32, size: usize) -> (usize, usize, f32) {
    let v = v.max(0.0);
    let low = v as usize;
    if low >= size - 1 { (size - 1, size - 1, 0.0) } else { (low, low + 1, v - low as f32) }
}

/// The samples of every bin of one box, bin by bin (row-major), each bin's
/// `sampling^2` samples together. Boxes are in feature-map pixels.
fn box_samples(roi: &BBox, shape: &RoiShape) -> Vec<Taps> {
    let (out, s) = (shape.output, shape.sampling);
    // aligned=True: pixel centres sit at half-integers.
    let (x0, y0) = (roi.x1 - 0.5, roi.y1 - 0.5);
    let (bin_w, bin_h) = ((roi.x2 - roi.x1) / out as f32, (roi.y2 - roi.y1) / out as f32);
    let mut samples = Vec::with_capacity(out * out * s * s);
    for ph in 0..out {
        for pw in 0..out {
            for iy in 0..s {
                let y = y0 + ph as f32 * bin_h + (iy as f32 + 0.5) * bin_h / s as f32;
                for ix in 0..s {
                    let x = x0 + pw as f32 * bin_w + (ix as f32 + 0.5) * bin_w / s as f32;
                    samples.push(taps(y, x, shape.height, shape.width));
                }
            }
        }
    }
    samples
}

/// Pools `features` [C, H, W] over `rois` to [K, C, output, output].
///
/// A bilinear tap's weight is the same for every channel, so the map is
/// first laid out channels-last: each tap then adds a weighted run of C
/// contiguous values, which the compiler vectorises. Boxes run in parallel.
pub fn forward(features: &[f32], rois: &[BBox], shape: &RoiShape) -> Vec<f32> {
    let (channels, plane) = (shape.channels, shape.height * shape.width);
    assert_eq!(features.len(), channels * plane, "feature map length");
    let bins = shape.output * shape.output;
    let per_bin = shape.sampling * shape.sampling;
    let scale = 1.0 / per_bin.max(1) as f32;
    let mut channels_last = vec![0.0f32; features.len()];
    for (c, map) in features.chunks(plane.max(1)).enumerate() {
        for (i, &v) in map.iter().enumerate() {
            channels_last[i * channels + c] = v;
        }
    }
    let mut out = vec![0.0f32; rois.len() * channels * bins];
    out.par_chunks_mut((channels * bins).max(1)).zip(rois.par_iter()).for_each(|(pooled, roi)| {
        let samples = box_samples(roi, shape);
        let mut sum = vec![0.0f32; channels];
        for bin in 0..bins {
            sum.fill(0.0);
            for taps in samples[bin * per_bin..][..per_bin].iter().flatten() {
                for &(i, w) in taps {
                    for (s, &v) in sum.iter_mut().zip(&channels_last[i * channels..][..channels]) {
                        *s += w * v;
                    }
                }
            }
            for (c, &s) in sum.iter().enumerate() {
                pooled[c * bins + bin] = s * scale;
            }
        }
    });
    out
}

/// The gradient with respect to the feature map [C, H, W] of the pooled
/// output, given the gradient `grad` [K, C, output, output].
pub fn backward(grad: &[f32], rois: &[BBox], shape: &RoiShape) -> Vec<f32> {
    let plane = shape.height * shape.width;
    let bins = shape.output * shape.output;
    assert_eq!(grad.len(), rois.len() * shape.channels * bins, "output gradient length");
    let per_bin = shape.sampling * shape.sampling;
    let scale = 1.0 / per_bin.max(1) as f32;
    let samples: Vec<Vec<Taps>> = rois.iter().map(|r| box_samples(r, shape)).collect();
    let mut dx = vec![0.0f32; shape.channels * plane];
    // One channel plane per task: no two tasks write the same memory.
    dx.par_chunks_mut(plane.max(1)).enumerate().for_each(|(c, map)| {
        for (k, box_samples) in samples.iter().enumerate() {
            let g = &grad[(k * shape.channels + c) * bins..][..bins];
            for (bin, &gb) in g.iter().enumerate() {
                let gb = gb * scale;
                for taps in box_samples[bin * per_bin..][..per_bin].iter().flatten() {
                    for &(i, w) in taps {
                        map[i] += w * gb;
                    }
                }
            }
        }
    });
    dx
}

#[backend_extension(Flex, Autodiff)]
pub trait RoiAlignBackend: Backend {
    /// RoIAlign of one feature map [1, C, H, W] to [K, C, output, output].
    fn roi_align_native(
        features: FloatTensor<Self>,
        rois: Vec<BBox>,
        output: usize,
        sampling: usize,
    ) -> FloatTensor<Self>;
}

/// RoIAlign on a flex device (autodiff or not) through the native kernel.
pub fn roi_align_flex(features: Tensor<4>, rois: &[BBox], output: usize, sampling: usize) -> Tensor<4> {
    Tensor::from_dispatch(<Dispatch as RoiAlignBackend>::roi_align_native(
        features.into_dispatch(),
        rois.to_vec(),
        output,
        sampling,
    ))
}

fn shape_of(features: &FloatTensor<Flex>, output: usize, sampling: usize) -> RoiShape {
    let s = features.shape();
    assert_eq!(s[0], 1, "RoIAlign takes one feature map at a time");
    RoiShape { channels: s[1], height: s[2], width: s[3], output, sampling }
}

impl RoiAlignBackend for Flex {
    fn roi_align_native(
        features: FloatTensor<Self>,
        rois: Vec<BBox>,
        output: usize,
        sampling: usize,
    ) -> FloatTensor<Self> {
        assert_eq!(features.dtype(), DType::F32, "the native RoIAlign takes f32 maps");
        let shape = shape_of(&features, output, sampling);
        let out = with_values(&features, |f| forward(f, &rois, &shape));
        let dims = [rois.len(), shape.channels, output, output];
        Flex::float_from_data(TensorData::new(out, dims), &Default::default())
    }
}

#[derive(Debug)]
struct RoiAlignBackward;

impl Backward<Flex, 1> for RoiAlignBackward {
    type State = (RoiShape, Vec<BBox>);

    fn backward(self, ops: Ops<Self::State, 1>, grads: &mut Gradients, _checkpointer: &mut Checkpointer) {
        let [node_features] = ops.parents;
        let grad = grads.consume::<Flex>(&ops.node);
        let (shape, rois) = ops.state;
        if let Some(node) = node_features {
            let dx = with_values(&grad, |g| backward(g, &rois, &shape));
            let dims = [1, shape.channels, shape.height, shape.width];
            grads.register::<Flex>(node.id, Flex::float_from_data(TensorData::new(dx, dims), &Default::default()));
        }
    }
}

impl<C: CheckpointStrategy> RoiAlignBackend for Autodiff<Flex, C> {
    fn roi_align_native(
        features: FloatTensor<Self>,
        rois: Vec<BBox>,
        output: usize,
        sampling: usize,
    ) -> FloatTensor<Self> {
        match RoiAlignBackward.prepare::<C>([features.node()]).compute_bound().stateful() {
            OpsKind::Tracked(prep) => {
                let shape = shape_of(features.primitive(), output, sampling);
                let out = Flex::roi_align_native(features.into_primitive(), rois.clone(), output, sampling);
                prep.finish((shape, rois), out)
            }
            OpsKind::UnTracked(prep) => {
                prep.finish(Flex::roi_align_native(features.into_primitive(), rois, output, sampling))
            }
        }
    }
}
