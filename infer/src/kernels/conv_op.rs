//! The project's 2-D convolution: Burn's `Conv2d` parameters, with the
//! forward pass and the gradients computed by `conv_kernels` on the flex
//! backend (with and without autodiff). Every other device, and bias-free or
//! non-f32 convolutions, take Burn's own path, so the model code stays
//! generic and a GPU device runs the standard kernels.
//!
//! Plugged in without forking Burn: a backend extension trait implemented
//! for `Flex`, and for `Autodiff<Flex>` with a hand-written backward step.

use burn::backend::autodiff::checkpoint::base::Checkpointer;
use burn::backend::autodiff::checkpoint::strategy::CheckpointStrategy;
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops, OpsKind};
use burn::backend::autodiff::{Autodiff, NodeId};
use burn::backend::ops::{ActivationOps, ConvOptions, FloatTensorOps, ModuleOps};
use burn::backend::tensor::FloatTensor;
use burn::backend::{Backend, Dispatch, Flex, TensorMetadata, backend_extension};
use burn::nn::PaddingConfig2d;
use burn::nn::conv::Conv2d;
use burn::prelude::*;
use burn::tensor::DType;

use crate::kernels::conv_kernels::{self, ConvGeometry};
use crate::kernels::cpu_kernels::{self, with_values};

/// `conv.forward(x)`: through the GEMM kernels unless the project's kernels
/// are turned off (`cpu_kernels::set_enabled`).
pub fn conv2d(conv: &Conv2d, x: Tensor<4>) -> Tensor<4> {
    if cpu_kernels::enabled() { gemm_conv2d(conv, x) } else { conv.forward(x) }
}

/// `conv.forward(x)` through the GEMM kernels where they apply (a flex
/// device, f32, a bias, explicit padding), Burn's own path elsewhere.
pub fn gemm_conv2d(conv: &Conv2d, x: Tensor<4>) -> Tensor<4> {
    let Some(bias) = conv.bias.as_ref() else { return conv.forward(x) };
    if !cpu_kernels::is_flex(&x.device()) || x.dtype() != DType::F32 {
        return conv.forward(x);
    }
    let Some(options) = conv_options(conv) else { return conv.forward(x) };
    Tensor::from_dispatch(<Dispatch as GemmConvBackend>::conv2d_gemm(
        x.into_dispatch(),
        conv.weight.val().into_dispatch(),
        bias.val().into_dispatch(),
        options,
    ))
}

/// `relu(conv.forward(x))`, the bias and ReLU fused into the GEMM
/// kernels' forward pass (and the ReLU's mask into their backward pass)
/// unless the project's kernels are turned off.
pub fn conv2d_relu(conv: &Conv2d, x: Tensor<4>) -> Tensor<4> {
    if cpu_kernels::enabled() { gemm_conv2d_relu(conv, x) } else { burn::tensor::activation::relu(conv.forward(x)) }
}

/// `relu(conv.forward(x))` through the fused GEMM kernels where they apply,
/// Burn's convolution and ReLU elsewhere.
pub fn gemm_conv2d_relu(conv: &Conv2d, x: Tensor<4>) -> Tensor<4> {
    let burn_path = |x: Tensor<4>| burn::tensor::activation::relu(conv.forward(x));
    let Some(bias) = conv.bias.as_ref() else { return burn_path(x) };
    if !cpu_kernels::is_flex(&x.device()) || x.dtype() != DType::F32 {
        return burn_path(x);
    }
    let Some(options) = conv_options(conv) else { return burn_path(x) };
    Tensor::from_dispatch(<Dispatch as GemmConvBackend>::conv2d_relu_gemm(
        x.into_dispatch(),
        conv.weight.val().into_dispatch(),
        bias.val().into_dispatch(),
        options,
    ))
}

/// The options of `conv` (its padding resolved); `None` for `Same` padding,
/// which depends on the input size and keeps Burn's path.
pub fn conv_options(conv: &Conv2d) -> Option<ConvOptions<2>> {
    let (top, left, bottom, right) = match conv.padding {
        PaddingConfig2d::Valid => (0, 0, 0, 0),
        PaddingConfig2d::Explicit(top, left, bottom, right) => (top, left, bottom, right),
        PaddingConfig2d::Same => return None,
    };
    Some(ConvOptions::new_with_padding(conv.stride, [(top, bottom), (left, right)], conv.dilation, conv.groups))
}

#[backend_extension(Flex, Autodiff)]
pub trait GemmConvBackend: Backend {
    /// A biased 2-D convolution (Burn's layouts and options).
    fn conv2d_gemm(
        x: FloatTensor<Self>,
        weight: FloatTensor<Self>,
        bias: FloatTensor<Self>,
        options: ConvOptions<2>,
    ) -> FloatTensor<Self>;

    /// `relu` of `conv2d_gemm`, in one pass.
    fn conv2d_relu_gemm(
        x: FloatTensor<Self>,
        weight: FloatTensor<Self>,
        bias: FloatTensor<Self>,
        options: ConvOptions<2>,
    ) -> FloatTensor<Self>;
}

fn dims4(t: &FloatTensor<Flex>) -> [usize; 4] {
    let shape = t.shape();
    [shape[0], shape[1], shape[2], shape[3]]
}

fn geometry(x: &FloatTensor<Flex>, weight: &FloatTensor<Flex>, options: &ConvOptions<2>) -> Option<ConvGeometry> {
    if x.dtype() != DType::F32 || weight.dtype() != DType::F32 {
        return None;
    }
    ConvGeometry::new(dims4(x), dims4(weight), options.stride, options.padding, options.dilation, options.groups)
}

fn flex_tensor(values: Vec<f32>, shape: [usize; 4]) -> FloatTensor<Flex> {
    Flex::float_from_data(TensorData::new(values, shape), &Default::default())
}

/// The forward pass on flex tensors: the GEMM kernel, or Burn's where the
/// kernel does not apply.
pub fn flex_forward(
    x: FloatTensor<Flex>,
    weight: FloatTensor<Flex>,
    bias: FloatTensor<Flex>,
    options: ConvOptions<2>,
) -> FloatTensor<Flex> {
    forward_then(x, weight, bias, options, false)
}

/// `relu` of `flex_forward`.
pub fn flex_forward_relu(
    x: FloatTensor<Flex>,
    weight: FloatTensor<Flex>,
    bias: FloatTensor<Flex>,
    options: ConvOptions<2>,
) -> FloatTensor<Flex> {
    forward_then(x, weight, bias, options, true)
}

fn forward_then(
    x: FloatTensor<Flex>,
    weight: FloatTensor<Flex>,
    bias: FloatTensor<Flex>,
    options: ConvOptions<2>,
    relu: bool,
) -> FloatTensor<Flex> {
    let Some(geo) = geometry(&x, &weight, &options).filter(|_| bias.dtype() == DType::F32) else {
        let out = Flex::conv2d(x, weight, Some(bias), options);
        return if relu { Flex::relu(out) } else { out };
    };
    let kernel = if relu { conv_kernels::forward_relu } else { conv_kernels::forward };
    let out = with_values(&x, |x| with_values(&weight, |w| with_values(&bias, |b| kernel(x, w, Some(b), &geo))));
    flex_tensor(out, [geo.batch, geo.out_channels, geo.out_hw[0], geo.out_hw[1]])
}

/// The ReLU's backward pass from its output; in place where `grad` is a
/// contiguous f32 tensor of its own.
fn flex_relu_grad(out: &FloatTensor<Flex>, mut grad: FloatTensor<Flex>) -> FloatTensor<Flex> {
    if out.dtype() != DType::F32 || grad.dtype() != DType::F32 || out.shape() != grad.shape() {
        return Flex::relu_backward(out.clone(), grad);
    }
    let span = grad.layout().contiguous_offsets();
    if let (Some((start, end)), true) = (span, grad.is_unique()) {
        let values = &mut grad.storage_mut::<f32>()[start..end];
        with_values(out, |o| conv_kernels::relu_grad(o, values));
        return grad;
    }
    let mut masked = with_values(&grad, <[f32]>::to_vec);
    with_values(out, |o| conv_kernels::relu_grad(o, &mut masked));
    flex_tensor(masked, dims4(&grad))
}

/// The gradient with respect to the input.
pub fn flex_input_grad(
    x: &FloatTensor<Flex>,
    weight: &FloatTensor<Flex>,
    grad: &FloatTensor<Flex>,
    options: ConvOptions<2>,
) -> FloatTensor<Flex> {
    match geometry(x, weight, &options).filter(|_| grad.dtype() == DType::F32) {
        Some(geo) => {
            let dx = with_values(weight, |w| with_values(grad, |g| conv_kernels::input_grad(w, g, &geo)));
            flex_tensor(dx, dims4(x))
        }
        None => Flex::conv2d_x_backward(x.clone(), weight.clone(), grad.clone(), options),
    }
}

/// The gradient with respect to the weight.
pub fn flex_weight_grad(
    x: &FloatTensor<Flex>,
    weight: &FloatTensor<Flex>,
    grad: &FloatTensor<Flex>,
    options: ConvOptions<2>,
) -> FloatTensor<Flex> {
    match geometry(x, weight, &options).filter(|_| grad.dtype() == DType::F32) {
        Some(geo) => {
            let dw = with_values(x, |x| with_values(grad, |g| conv_kernels::weight_grad(x, g, &geo)));
            flex_tensor(dw, dims4(weight))
        }
        None => Flex::conv2d_weight_backward(x.clone(), weight.clone(), grad.clone(), options),
    }
}

/// The gradient with respect to the bias: `grad` summed over all but the
/// channel axis.
pub fn flex_bias_grad(grad: &FloatTensor<Flex>) -> FloatTensor<Flex> {
    let [n, o, h, w] = dims4(grad);
    if grad.dtype() == DType::F32 {
        let db = with_values(grad, |g| conv_kernels::bias_grad(g, n, o));
        return Flex::float_from_data(TensorData::new(db, [o]), &Default::default());
    }
    let rows = Flex::float_reshape(Flex::float_swap_dims(grad.clone(), 0, 1), [o, n * h * w].into());
    Flex::float_reshape(Flex::float_sum_dim(rows, 1), [o].into())
}

impl GemmConvBackend for Flex {
    fn conv2d_gemm(
        x: FloatTensor<Self>,
        weight: FloatTensor<Self>,
        bias: FloatTensor<Self>,
        options: ConvOptions<2>,
    ) -> FloatTensor<Self> {
        flex_forward(x, weight, bias, options)
    }

    fn conv2d_relu_gemm(
        x: FloatTensor<Self>,
        weight: FloatTensor<Self>,
        bias: FloatTensor<Self>,
        options: ConvOptions<2>,
    ) -> FloatTensor<Self> {
        flex_forward_relu(x, weight, bias, options)
    }
}

/// The backward step: input, weight and bias gradients from `conv_kernels`.
#[derive(Debug)]
struct Conv2dGemmBackward;

impl Backward<Flex, 3> for Conv2dGemmBackward {
    type State = (NodeId, NodeId, ConvOptions<2>);

    fn backward(self, ops: Ops<Self::State, 3>, grads: &mut Gradients, checkpointer: &mut Checkpointer) {
        let grad = grads.consume::<Flex>(&ops.node);
        let (x_state, weight_state, options) = ops.state;
        let x = checkpointer.retrieve_node_output::<FloatTensor<Flex>>(x_state);
        let weight = checkpointer.retrieve_node_output::<FloatTensor<Flex>>(weight_state);
        register_conv_grads(ops.parents.map(|p| p.map(|node| node.id)), &x, &weight, &grad, options, grads);
    }
}

/// The input, weight and bias gradients of the parents that want one.
fn register_conv_grads(
    [node_x, node_weight, node_bias]: [Option<NodeId>; 3],
    x: &FloatTensor<Flex>,
    weight: &FloatTensor<Flex>,
    grad: &FloatTensor<Flex>,
    options: ConvOptions<2>,
    grads: &mut Gradients,
) {
    if let Some(id) = node_x {
        grads.register::<Flex>(id, flex_input_grad(x, weight, grad, options.clone()));
    }
    if let Some(id) = node_weight {
        grads.register::<Flex>(id, flex_weight_grad(x, weight, grad, options));
    }
    if let Some(id) = node_bias {
        grads.register::<Flex>(id, flex_bias_grad(grad));
    }
}

/// The fused ReLU convolution's backward step: the ReLU's mask from the
/// output it kept, then the convolution's gradients.
#[derive(Debug)]
struct Conv2dReluGemmBackward;

impl Backward<Flex, 3> for Conv2dReluGemmBackward {
    type State = (NodeId, NodeId, ConvOptions<2>, FloatTensor<Flex>);

    fn backward(self, ops: Ops<Self::State, 3>, grads: &mut Gradients, checkpointer: &mut Checkpointer) {
        let grad = grads.consume::<Flex>(&ops.node);
        let (x_state, weight_state, options, out) = ops.state;
        let x = checkpointer.retrieve_node_output::<FloatTensor<Flex>>(x_state);
        let weight = checkpointer.retrieve_node_output::<FloatTensor<Flex>>(weight_state);
        let grad = flex_relu_grad(&out, grad);
        drop(out);
        register_conv_grads(ops.parents.map(|p| p.map(|node| node.id)), &x, &weight, &grad, options, grads);
    }
}

impl<C: CheckpointStrategy> GemmConvBackend for Autodiff<Flex, C> {
    fn conv2d_gemm(
        x: FloatTensor<Self>,
        weight: FloatTensor<Self>,
        bias: FloatTensor<Self>,
        options: ConvOptions<2>,
    ) -> FloatTensor<Self> {
        tracked_conv::<C, _>(
            Conv2dGemmBackward,
            [x, weight, bias],
            options,
            Flex::conv2d_gemm,
            |x, weight, options, _| (x, weight, options),
        )
    }

    fn conv2d_relu_gemm(
        x: FloatTensor<Self>,
        weight: FloatTensor<Self>,
        bias: FloatTensor<Self>,
        options: ConvOptions<2>,
    ) -> FloatTensor<Self> {
        // The output is what the ReLU's backward pass masks with.
        tracked_conv::<C, _>(
            Conv2dReluGemmBackward,
            [x, weight, bias],
            options,
            Flex::conv2d_relu_gemm,
            |x, weight, options, out| (x, weight, options, out.clone()),
        )
    }
}

/// A convolution on the flex backend: input, weight, bias, options.
type FlexConv = fn(FloatTensor<Flex>, FloatTensor<Flex>, FloatTensor<Flex>, ConvOptions<2>) -> FloatTensor<Flex>;

/// A convolution on the autodiff backend: `forward` on the inner tensors,
/// recorded (when a parent is tracked) for `step`'s backward pass with the
/// state that `state` makes of the checkpointed input and weight, the
/// options and the output.
fn tracked_conv<C: CheckpointStrategy, K: Backward<Flex, 3>>(
    step: K,
    [x, weight, bias]: [FloatTensor<Autodiff<Flex, C>>; 3],
    options: ConvOptions<2>,
    forward: FlexConv,
    state: impl FnOnce(NodeId, NodeId, ConvOptions<2>, &FloatTensor<Flex>) -> K::State,
) -> FloatTensor<Autodiff<Flex, C>> {
    match step.prepare::<C>([x.node(), weight.node(), bias.node()]).compute_bound().stateful() {
        OpsKind::Tracked(mut prep) => {
            let x_state = prep.checkpoint(&x);
            let weight_state = prep.checkpoint(&weight);
            let out = forward(x.into_primitive(), weight.into_primitive(), bias.into_primitive(), options.clone());
            prep.finish(state(x_state, weight_state, options, &out), out)
        }
        OpsKind::UnTracked(prep) => {
            prep.finish(forward(x.into_primitive(), weight.into_primitive(), bias.into_primitive(), options))
        }
    }
}
