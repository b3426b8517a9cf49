//! Max pooling without padding or dilation (VGG's 2x2 stride 2, AlexNet's
//! 3x3 stride 2), forward and backward, on host memory; plugged into the
//! flex backend (with and without autodiff) as a Burn backend extension.
//!
//! Why: Burn's flex pooling is one generic 3-D kernel that works out each
//! window's bounds per output and keeps i64 indices; on a VGG16 trunk it
//! took as long as a fifth of the convolutions. Here each plane is one tight
//! loop over its windows, planes in parallel, indices as u32 offsets.
//! Ties keep the first maximum in row-major window order and the last NaN
//! wins, as PyTorch and Burn do, so the gradient goes where theirs goes.

use burn::backend::autodiff::Autodiff;
use burn::backend::autodiff::checkpoint::base::Checkpointer;
use burn::backend::autodiff::checkpoint::strategy::CheckpointStrategy;
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops, OpsKind};
use burn::backend::ops::FloatTensorOps;
use burn::backend::tensor::FloatTensor;
use burn::backend::{Backend, Dispatch, Flex, TensorMetadata, backend_extension};
use burn::nn::PaddingConfig2d;
use burn::nn::pool::MaxPool2d;
use burn::prelude::*;
use burn::tensor::DType;
use rayon::prelude::*;

use crate::kernels::cpu_kernels::{self, with_values};

/// The sizes of one pooling call: `planes` maps (batch x channels) of
/// `height x width`, a square `kernel` moved by `stride`, no padding.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PoolShape {
    pub planes: usize,
    pub height: usize,
    pub width: usize,
    pub kernel: usize,
    pub stride: usize,
}

impl PoolShape {
    /// Output rows and columns (floor mode, as `ceil_mode = false`).
    pub fn output(&self) -> (usize, usize) {
        let out = |size: usize| if size < self.kernel { 0 } else { (size - self.kernel) / self.stride + 1 };
        (out(self.height), out(self.width))
    }
}

/// Planes per parallel task: enough work (about 64 k inputs) to pay for the task.
fn planes_per_task(shape: &PoolShape) -> usize {
    (65_536 / (shape.height * shape.width).max(1)).max(1)
}

/// Pools `x` [planes, H, W]; returns the output [planes, OH, OW] and, for
/// each output, the offset of its maximum within its input plane.
pub fn forward(x: &[f32], shape: &PoolShape) -> (Vec<f32>, Vec<u32>) {
    let plane = shape.height * shape.width;
    assert_eq!(x.len(), shape.planes * plane, "input length");
    assert!(plane <= u32::MAX as usize, "a plane too large for u32 offsets");
    let (oh, ow) = shape.output();
    let out_plane = oh * ow;
    let mut out = vec![0.0f32; shape.planes * out_plane];
    let mut arg = vec![0u32; shape.planes * out_plane];
    if out_plane == 0 {
        return (out, arg);
    }
    let chunk = planes_per_task(shape);
    out.par_chunks_mut(out_plane * chunk).zip(arg.par_chunks_mut(out_plane * chunk)).enumerate().for_each(
        |(task, (out, arg))| {
            for (p, (out, arg)) in out.chunks_mut(out_plane).zip(arg.chunks_mut(out_plane)).enumerate() {
                let map = &x[(task * chunk + p) * plane..][..plane];
                pool_plane(map, shape, out, arg);
            }
        },
    );
    (out, arg)
}

/// Replaces the running maximum when `v` beats it (the first maximum
/// wins; a NaN wins, the last one).
#[inline(always)]
fn challenge(best: &mut (f32, u32), v: f32, at: usize) {
    if v > best.0 || v.is_nan() {
        *best = (v, at as u32);
    }
}

fn pool_plane(map: &[f32], shape: &PoolShape, out: &mut [f32], arg: &mut [u32]) {
    let (oh, ow) = shape.output();
    let (k, s, w) = (shape.kernel, shape.stride, shape.width);
    if (k, s) == (2, 2) {
        // VGG's pooling, the common case: two rows, pairs of columns.
        for y in 0..oh {
            let top = 2 * y * w;
            let (upper, lower) = (&map[top..][..2 * ow], &map[top + w..][..2 * ow]);
            let outputs = out[y * ow..][..ow].iter_mut().zip(&mut arg[y * ow..][..ow]);
            for (x, ((u, l), (o, a))) in upper.chunks_exact(2).zip(lower.chunks_exact(2)).zip(outputs).enumerate() {
                let at = top + 2 * x;
                let mut best = (u[0], at as u32);
                challenge(&mut best, u[1], at + 1);
                challenge(&mut best, l[0], at + w);
                challenge(&mut best, l[1], at + w + 1);
                (*o, *a) = best;
            }
        }
        return;
    }
    for y in 0..oh {
        let (out, arg) = (&mut out[y * ow..][..ow], &mut arg[y * ow..][..ow]);
        // The window's first row, then each further row, compared column by column.
        let top = y * s * w;
        for (x, (o, a)) in out.iter_mut().zip(arg.iter_mut()).enumerate() {
            (*o, *a) = (map[top + x * s], (top + x * s) as u32);
        }
        for ky in 0..k {
            let row = top + ky * w;
            let cells = &map[row..row + (ow - 1) * s + k];
            for (x, (o, a)) in out.iter_mut().zip(arg.iter_mut()).enumerate() {
                let mut best = (*o, *a);
                for (kx, &v) in cells[x * s..x * s + k].iter().enumerate() {
                    challenge(&mut best, v, row + x * s + kx);
                }
                (*o, *a) = best;
            }
        }
    }
}

/// The gradient with respect to the input [planes, H, W] of the output
/// gradient `grad` [planes, OH, OW], given the forward's `arg`.
pub fn backward(grad: &[f32], arg: &[u32], shape: &PoolShape) -> Vec<f32> {
    let plane = shape.height * shape.width;
    let (oh, ow) = shape.output();
    let out_plane = oh * ow;
    assert_eq!(grad.len(), shape.planes * out_plane, "output gradient length");
    assert_eq!(arg.len(), grad.len(), "one index per output");
    let mut dx = vec![0.0f32; shape.planes * plane];
    if out_plane == 0 {
        return dx;
    }
    let chunk = planes_per_task(shape);
    dx.par_chunks_mut(plane * chunk).enumerate().for_each(|(task, dx)| {
        for (p, map) in dx.chunks_mut(plane).enumerate() {
            let at = (task * chunk + p) * out_plane;
            // Overlapping windows (stride < kernel) may share a maximum: add.
            for (&g, &i) in grad[at..at + out_plane].iter().zip(&arg[at..at + out_plane]) {
                map[i as usize] += g;
            }
        }
    });
    dx
}

/// `pool.forward(x)` through the native kernel where it applies (a flex
/// device, f32, a square kernel and stride, no padding, dilation or ceil
/// mode, and the project's kernels on), Burn's own path elsewhere.
pub fn max_pool2d(pool: &MaxPool2d, x: Tensor<4>) -> Tensor<4> {
    let [k, kw] = pool.kernel_size;
    let [s, sw] = pool.stride;
    let plain = k == kw
        && s == sw
        && s > 0
        && matches!(pool.padding, PaddingConfig2d::Valid | PaddingConfig2d::Explicit(0, 0, 0, 0))
        && pool.dilation == [1, 1]
        && !pool.ceil_mode;
    if !plain || !cpu_kernels::enabled() || !cpu_kernels::is_flex(&x.device()) || x.dtype() != DType::F32 {
        return pool.forward(x);
    }
    Tensor::from_dispatch(<Dispatch as MaxPoolBackend>::max_pool2d_native(x.into_dispatch(), k, s))
}

#[backend_extension(Flex, Autodiff)]
pub trait MaxPoolBackend: Backend {
    /// Max pooling of `x` [B, C, H, W] with a square kernel and stride, no padding.
    fn max_pool2d_native(x: FloatTensor<Self>, kernel: usize, stride: usize) -> FloatTensor<Self>;
}

fn shape_of(x: &FloatTensor<Flex>, kernel: usize, stride: usize) -> ([usize; 4], PoolShape) {
    let s = x.shape();
    let dims = [s[0], s[1], s[2], s[3]];
    (dims, PoolShape { planes: s[0] * s[1], height: s[2], width: s[3], kernel, stride })
}

/// The forward on flex: the output tensor and the argmax offsets.
fn forward_flex(x: &FloatTensor<Flex>, [b, c, _, _]: [usize; 4], shape: &PoolShape) -> (FloatTensor<Flex>, Vec<u32>) {
    assert_eq!(x.dtype(), DType::F32, "the native max pooling takes f32 maps");
    let (out, arg) = with_values(x, |v| forward(v, shape));
    let (oh, ow) = shape.output();
    (Flex::float_from_data(TensorData::new(out, [b, c, oh, ow]), &Default::default()), arg)
}

impl MaxPoolBackend for Flex {
    fn max_pool2d_native(x: FloatTensor<Self>, kernel: usize, stride: usize) -> FloatTensor<Self> {
        let (dims, shape) = shape_of(&x, kernel, stride);
        forward_flex(&x, dims, &shape).0
    }
}

#[derive(Debug)]
struct MaxPoolBackward;

impl Backward<Flex, 1> for MaxPoolBackward {
    type State = (PoolShape, Vec<u32>, [usize; 4]);

    fn backward(self, ops: Ops<Self::State, 1>, grads: &mut Gradients, _checkpointer: &mut Checkpointer) {
        let [node_x] = ops.parents;
        let grad = grads.consume::<Flex>(&ops.node);
        let (shape, arg, dims) = ops.state;
        if let Some(node) = node_x {
            let dx = with_values(&grad, |g| backward(g, &arg, &shape));
            grads.register::<Flex>(node.id, Flex::float_from_data(TensorData::new(dx, dims), &Default::default()));
        }
    }
}

impl<C: CheckpointStrategy> MaxPoolBackend for Autodiff<Flex, C> {
    fn max_pool2d_native(x: FloatTensor<Self>, kernel: usize, stride: usize) -> FloatTensor<Self> {
        match MaxPoolBackward.prepare::<C>([x.node()]).compute_bound().stateful() {
            OpsKind::Tracked(prep) => {
                let (dims, shape) = shape_of(x.primitive(), kernel, stride);
                let (out, arg) = forward_flex(x.primitive(), dims, &shape);
                prep.finish((shape, arg, dims), out)
            }
            OpsKind::UnTracked(prep) => prep.finish(Flex::max_pool2d_native(x.into_primitive(), kernel, stride)),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn shape(planes: usize, height: usize, width: usize, kernel: usize, stride: usize) -> PoolShape {
        PoolShape { planes, height, width, kernel, stride }
    }

    #[test]
    fn pools_a_known_map_and_routes_the_gradient_to_each_maximum() {
        // One 4x4 plane, 2x2 windows: maxima 6, 8, 14, 16 at known offsets.
        let x: Vec<f32> = (1..=16).map(|v| v as f32).collect();
        let s = shape(1, 4, 4, 2, 2);
        let (out, arg) = forward(&x, &s);
        assert_eq!(out, vec![6.0, 8.0, 14.0, 16.0]);
        assert_eq!(arg, vec![5, 7, 13, 15]);
        let dx = backward(&[1.0, 2.0, 3.0, 4.0], &arg, &s);
        let mut want = vec![0.0; 16];
        (want[5], want[7], want[13], want[15]) = (1.0, 2.0, 3.0, 4.0);
        assert_eq!(dx, want);
    }

    #[test]
    fn ties_keep_the_first_maximum_and_nan_wins() {
        let s = shape(2, 2, 2, 2, 2);
        let (out, arg) = forward(&[0.0, 0.0, 0.0, 0.0, 1.0, f32::NAN, 3.0, f32::NAN], &s);
        assert_eq!((out[0], arg[0]), (0.0, 0));
        assert!(out[1].is_nan());
        assert_eq!(arg[1], 3);
    }

    #[test]
    fn overlapping_windows_add_their_gradients_and_odd_edges_are_dropped() {
        // 3x3 windows, stride 2 on a 5x5 plane: 2x2 outputs; the centre
        // (offset 12) is the maximum of all four windows.
        let mut x = vec![0.0f32; 25];
        x[12] = 9.0;
        let s = shape(1, 5, 5, 3, 2);
        let (out, arg) = forward(&x, &s);
        assert_eq!(out, vec![9.0; 4]);
        assert_eq!(backward(&[1.0, 1.0, 1.0, 1.0], &arg, &s)[12], 4.0);
        // A 5x5 plane under 2x2/2 pooling gives 2x2: the last row and column are dropped.
        assert_eq!(shape(1, 5, 5, 2, 2).output(), (2, 2));
    }
}
