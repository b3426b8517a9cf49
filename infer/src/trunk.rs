//! The convolutional trunks in torchvision's layer shapes (scaled by the
//! width), one input channel by default: `TrunkConfig` -> `init` -> `Trunk`
//! -> `forward`. The convolutions are kept in a `features` vector so that
//! torchvision's `features.N` names map onto them.

use std::ops::Range;

use burn::config::Config;
use burn::nn::conv::{Conv2d, Conv2dConfig};
use burn::nn::pool::{MaxPool2d, MaxPool2dConfig};
use burn::nn::{Initializer, PaddingConfig2d, Relu};
use burn::prelude::*;
use serde::{Deserialize, Serialize};

use crate::kernels::conv_op::conv2d_relu;
use crate::kernels::max_pool_native::max_pool2d;

/// Which of torchvision's two trunks.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum Architecture {
    /// 13 3x3 convolutions; 2x2 max pooling after convolutions 2, 4, 7, 10, 13.
    Vgg16,
    /// 11x11 stride 4, 5x5, then three 3x3 convolutions; 3x3 stride-2 max
    /// pooling after the first, second and fifth.
    Alexnet,
}

/// VGG16's output channels per convolution.
pub const VGG16_CHANNELS: [usize; 13] = [64, 64, 128, 128, 256, 256, 256, 512, 512, 512, 512, 512, 512];
const VGG16_POOL_AFTER: [usize; 5] = [1, 3, 6, 9, 12];
/// AlexNet's output channels per convolution.
pub const ALEXNET_CHANNELS: [usize; 5] = [64, 192, 384, 256, 256];
/// AlexNet's (kernel, stride, padding) per convolution.
const ALEXNET_SHAPES: [(usize, usize, usize); 5] = [(11, 4, 2), (5, 1, 2), (3, 1, 1), (3, 1, 1), (3, 1, 1)];

#[derive(Config, Debug)]
pub struct TrunkConfig {
    pub architecture: Architecture,
    /// Channels of the input image (1 for the edge images).
    #[config(default = 1)]
    pub in_channels: usize,
    /// Scale of every layer's channel count against torchvision's.
    #[config(default = 1.0)]
    pub width: f32,
}

impl TrunkConfig {
    /// A channel count of torchvision's network scaled by the width.
    pub fn channels(&self, torchvision: usize) -> usize {
        ((torchvision as f32 * self.width).round() as usize).max(4)
    }

    fn torchvision_channels(&self) -> &'static [usize] {
        match self.architecture {
            Architecture::Vgg16 => &VGG16_CHANNELS,
            Architecture::Alexnet => &ALEXNET_CHANNELS,
        }
    }

    /// Channels of the last convolution's output.
    pub fn out_channels(&self) -> usize {
        self.channels(*self.torchvision_channels().last().expect("a trunk has convolutions"))
    }

    pub fn init(&self, device: &Device) -> Trunk {
        let mut input = self.in_channels;
        let features = self
            .torchvision_channels()
            .iter()
            .enumerate()
            .map(|(i, &c)| {
                let out = self.channels(c);
                let conv = match self.architecture {
                    // torchvision initialises VGG with He normal over the
                    // fan-out and zero bias; PyTorch's default leaves a
                    // 13-layer VGG without batch norm nearly untrainable.
                    Architecture::Vgg16 => zero_bias(
                        Conv2dConfig::new([input, out], [3, 3])
                            .with_padding(PaddingConfig2d::Explicit(1, 1, 1, 1))
                            .with_initializer(he_fan_out())
                            .init(device),
                    ),
                    Architecture::Alexnet => {
                        let (k, s, p) = ALEXNET_SHAPES[i];
                        Conv2dConfig::new([input, out], [k, k])
                            .with_stride([s, s])
                            .with_padding(PaddingConfig2d::Explicit(p, p, p, p))
                            .init(device)
                    }
                };
                input = out;
                conv
            })
            .collect();
        let pool = match self.architecture {
            Architecture::Vgg16 => MaxPool2dConfig::new([2, 2]).with_strides([2, 2]).init(),
            Architecture::Alexnet => MaxPool2dConfig::new([3, 3]).with_strides([2, 2]).init(),
        };
        Trunk { features, pool, act: Relu::new(), architecture: self.architecture }
    }
}

#[derive(Module, Debug)]
pub struct Trunk {
    /// The convolutions (torchvision's `features.N`, renumbered 0, 1, 2, ...).
    pub features: Vec<Conv2d>,
    pool: MaxPool2d,
    act: Relu,
    #[module(skip)]
    architecture: Architecture,
}

impl Trunk {
    /// Runs convolutions `layers` of `x` `[B, C, H, W]`, each with its ReLU
    /// and the pooling that follows it; `last_pool` keeps the pooling after
    /// the last convolution (VGG16: stride 32, the classifier's input;
    /// without it stride 16, Faster R-CNN's trunk). A frozen prefix is run
    /// once and cached, the rest on every step: hence the range.
    pub fn forward(&self, mut x: Tensor<4>, layers: Range<usize>, last_pool: bool) -> Tensor<4> {
        let last = self.features.len() - 1;
        for i in layers {
            x = conv2d_relu(&self.features[i], x);
            let pool_after = match self.architecture {
                Architecture::Vgg16 => VGG16_POOL_AFTER.contains(&i),
                Architecture::Alexnet => matches!(i, 0 | 1 | 4),
            };
            if pool_after && (last_pool || i != last) {
                x = max_pool2d(&self.pool, x);
            }
        }
        x
    }

    /// All the convolutions.
    pub fn forward_all(&self, x: Tensor<4>, last_pool: bool) -> Tensor<4> {
        self.forward(x, 0..self.features.len(), last_pool)
    }

    /// The 2x2 or 3x3 max pooling between the convolutions.
    pub fn pool(&self) -> &MaxPool2d {
        &self.pool
    }
}

/// He normal over the fan-out (torchvision's VGG initialisation).
fn he_fan_out() -> Initializer {
    Initializer::KaimingNormal { gain: std::f64::consts::SQRT_2, fan_out_only: true }
}

fn zero_bias(mut conv: Conv2d) -> Conv2d {
    conv.bias = conv.bias.map(|b| b.map(|t| replace_value(&t, t.zeros_like())));
    conv
}

/// Filters `[out, have, kh, kw]` (flat, `kernel_area` = kh * kw) as filters
/// of `channels` >= `have` input channels, the added ones at zero weight.
pub fn widen_filters(weight: &[f32], out: usize, kernel_area: usize, channels: usize) -> Vec<f32> {
    let wide_len = channels * kernel_area;
    let mut wide = vec![0.0f32; out * wide_len];
    for (filter, dst) in weight.chunks_exact(weight.len() / out).zip(wide.chunks_exact_mut(wide_len)) {
        dst[..filter.len()].copy_from_slice(filter);
    }
    wide
}

/// A new value for a parameter tensor that keeps it trainable: a tensor made
/// from scratch is not tracked by autodiff until told so.
pub fn replace_value<const D: usize>(old: &Tensor<D>, new: Tensor<D>) -> Tensor<D> {
    new.set_require_grad(old.is_require_grad())
}
