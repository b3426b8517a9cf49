//! The convolutional trunks in torchvision's layer shapes (scaled by the
//! width), one input channel by default. Layers are kept in `features`
//! vectors so that torchvision's `features.N` names map onto them.

use std::ops::Range;

use burn::nn::conv::{Conv2d, Conv2dConfig};
use burn::nn::pool::{MaxPool2d, MaxPool2dConfig};
use burn::nn::{Initializer, PaddingConfig2d, Relu};
use burn::prelude::*;

use crate::conv_op::conv2d;
use crate::max_pool_native::max_pool2d;

/// torchvision's VGG initialisation: He normal over the fan-out, zero bias.
/// (PyTorch's default init leaves a 13-layer VGG without batch norm nearly
/// untrainable from scratch.)
pub fn he_fan_out() -> Initializer {
    Initializer::KaimingNormal { gain: std::f64::consts::SQRT_2, fan_out_only: true }
}

pub fn zero_bias(mut conv: Conv2d) -> Conv2d {
    conv.bias = conv.bias.map(|b| b.map(|t| replace_value(&t, t.zeros_like())));
    conv
}

/// A new value for a parameter tensor that keeps it trainable: a tensor made
/// from scratch is not tracked by autodiff until told so.
pub fn replace_value<const D: usize>(old: &Tensor<D>, new: Tensor<D>) -> Tensor<D> {
    new.set_require_grad(old.is_require_grad())
}

use crate::config::DetectorConfig;

/// VGG16's 13 convolutions; max pooling follows convolutions 2, 4, 7, 10, 13.
pub const VGG16_CHANNELS: [usize; 13] = [64, 64, 128, 128, 256, 256, 256, 512, 512, 512, 512, 512, 512];
const VGG16_POOL_AFTER: [usize; 5] = [1, 3, 6, 9, 12];

pub fn vgg16_convs(config: &DetectorConfig, device: &Device) -> Vec<Conv2d> {
    let mut input = config.in_channels;
    VGG16_CHANNELS
        .iter()
        .map(|&c| {
            let out = config.channels(c);
            let conv = Conv2dConfig::new([input, out], [3, 3])
                .with_padding(PaddingConfig2d::Explicit(1, 1, 1, 1))
                .with_initializer(he_fan_out())
                .init(device);
            input = out;
            zero_bias(conv)
        })
        .collect()
}

/// Runs VGG16's convolutions on `x` [B, C, H, W]; with `last_pool` the output
/// has stride 32 (the classifier's input), without it stride 16 (Faster
/// R-CNN's trunk).
pub fn vgg16_forward(convs: &[Conv2d], pool: &MaxPool2d, act: &Relu, x: Tensor<4>, last_pool: bool) -> Tensor<4> {
    vgg16_forward_range(convs, pool, act, x, 0..convs.len(), last_pool)
}

/// Runs convolutions `layers` only (each with its ReLU and the pooling that
/// follows it): a frozen prefix is run once and its output cached, the rest
/// on every step.
pub fn vgg16_forward_range(
    convs: &[Conv2d],
    pool: &MaxPool2d,
    act: &Relu,
    mut x: Tensor<4>,
    layers: Range<usize>,
    last_pool: bool,
) -> Tensor<4> {
    for i in layers {
        x = act.forward(conv2d(&convs[i], x));
        if VGG16_POOL_AFTER.contains(&i) && (last_pool || i != 12) {
            x = max_pool2d(pool, x);
        }
    }
    x
}

pub fn vgg16_out_channels(config: &DetectorConfig) -> usize {
    config.channels(512)
}

pub fn max_pool_2x2() -> MaxPool2d {
    MaxPool2dConfig::new([2, 2]).with_strides([2, 2]).init()
}

/// AlexNet's five convolutions: 11x11 stride 4, 5x5, then three 3x3; 3x3
/// stride-2 max pooling after the first, second and fifth.
pub const ALEXNET_CHANNELS: [usize; 5] = [64, 192, 384, 256, 256];

pub fn alexnet_convs(config: &DetectorConfig, device: &Device) -> Vec<Conv2d> {
    let shapes = [(11, 4, 2), (5, 1, 2), (3, 1, 1), (3, 1, 1), (3, 1, 1)];
    let mut input = config.in_channels;
    ALEXNET_CHANNELS
        .iter()
        .zip(shapes)
        .map(|(&c, (k, s, p))| {
            let out = config.channels(c);
            let conv = Conv2dConfig::new([input, out], [k, k])
                .with_stride([s, s])
                .with_padding(PaddingConfig2d::Explicit(p, p, p, p))
                .init(device);
            input = out;
            conv
        })
        .collect()
}

pub fn alexnet_pool() -> MaxPool2d {
    MaxPool2dConfig::new([3, 3]).with_strides([2, 2]).init()
}

pub fn alexnet_forward(convs: &[Conv2d], pool: &MaxPool2d, act: &Relu, x: Tensor<4>) -> Tensor<4> {
    alexnet_forward_range(convs, pool, act, x, 0..convs.len(), true)
}

pub fn alexnet_forward_range(
    convs: &[Conv2d],
    pool: &MaxPool2d,
    act: &Relu,
    mut x: Tensor<4>,
    layers: Range<usize>,
    last_pool: bool,
) -> Tensor<4> {
    for i in layers {
        x = act.forward(conv2d(&convs[i], x));
        if matches!(i, 0 | 1) || (i == 4 && last_pool) {
            x = max_pool2d(pool, x);
        }
    }
    x
}
