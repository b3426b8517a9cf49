//! VGG16 and AlexNet as the paper's baselines: torchvision's layers with the
//! last classifier layer replaced by a grid head. For each cell of an S x S
//! grid over the input the head predicts a corner-presence logit, the
//! corner's offset within the cell (two logits, squashed to 0..1) and its
//! box size (log of width and height over the cell side).
//!
//! The head is convolutional by default (`GridHead::Conv`, one output pixel
//! per cell on the stride-16 features); `GridHead::Fc` keeps torchvision's
//! classifier and replaces only its last layer, the literal baseline.

use burn::config::Config;
use burn::nn::PaddingConfig2d;
use burn::nn::conv::{Conv2d, Conv2dConfig};
use burn::nn::pool::{AdaptiveAvgPool2d, AdaptiveAvgPool2dConfig};
use burn::nn::{Dropout, DropoutConfig, Initializer, Linear, LinearConfig, Relu};
use burn::prelude::*;

use crate::kernels::conv_op::{conv2d, conv2d_relu};
use crate::trunk::{Architecture, Trunk, TrunkConfig, replace_value};
use serde::{Deserialize, Serialize};

/// Values per grid cell: presence, offset x, offset y, log width, log height.
pub const CELL_VALUES: usize = 5;

/// Expected share of cells holding a corner, used to start the presence
/// logits there (RetinaNet's prior trick): a zero logit would claim half the
/// cells and the optimizer would spend its first thousand steps undoing it.
pub const PRESENCE_PRIOR: f64 = 0.03;

/// Zero bias except the presence logit of every cell, set to the prior
/// (cell-major order: the 5 values of cell 0, then of cell 1, ...).
fn prior_bias(cells: usize, device: &Device) -> Tensor<1> {
    let logit = -((1.0 - PRESENCE_PRIOR) / PRESENCE_PRIOR).ln() as f32;
    let values: Vec<f32> = (0..cells * CELL_VALUES).map(|i| if i % CELL_VALUES == 0 { logit } else { 0.0 }).collect();
    let n = values.len();
    Tensor::<1>::from_data(TensorData::new(values, [n]), device)
}

/// How the grid networks turn trunk features into cells.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "kebab-case")]
pub enum GridHead {
    /// A 3x3 and a 1x1 convolution on the stride-16 features, one output
    /// pixel per cell: the same weights judge every cell, so 200 images are
    /// enough to learn what a corner looks like wherever it is.
    #[default]
    Conv,
    /// torchvision's classifier with its last layer replaced: two hidden
    /// fully connected layers on the 7x7 (6x6) pooled features, then one
    /// layer with all cells' outputs. Every cell has its own weights; on
    /// 200 images it memorises the training set and stays at the prior on
    /// new images.
    Fc,
}

#[derive(Config, Debug)]
pub struct GridNetConfig {
    /// VGG16 or AlexNet.
    pub trunk: TrunkConfig,
    pub head: GridHead,
    /// Cells along each side of the grid.
    pub cells: usize,
    /// Width of the fc head's two hidden layers (unused by the conv head).
    pub hidden: usize,
}

impl GridNetConfig {
    pub fn init(&self, device: &Device) -> GridNet {
        let trunk = self.trunk.init(device);
        let channels = self.trunk.out_channels();
        let s = self.cells;
        let head_init = Initializer::Normal { mean: 0.0, std: 0.01 };
        let head = match self.head {
            GridHead::Fc => {
                // torchvision's classifier takes 7x7 (VGG16) or 6x6 (AlexNet) pooled features.
                let spatial = match self.trunk.architecture {
                    Architecture::Vgg16 => 7,
                    Architecture::Alexnet => 6,
                };
                let h = self.hidden;
                // PyTorch's default init for the hidden layers: torchvision's N(0, 0.01)
                // for VGG suits 4096-wide layers but starves the narrow ones of signal.
                let linear = |i: usize, o: usize| LinearConfig::new(i, o).init(device);
                let hidden = [linear(channels * spatial * spatial, h), linear(h, h)];
                let mut cells = LinearConfig::new(h, s * s * CELL_VALUES).with_initializer(head_init).init(device);
                cells.bias = cells.bias.map(|b| b.map(|old| replace_value(&old, prior_bias(s * s, device))));
                let [first, second] = hidden;
                GridHeadLayers::Fc(FcGridHead {
                    classifier: vec![first, second, cells],
                    avgpool: AdaptiveAvgPool2dConfig::new([spatial, spatial]).init(),
                    dropout: DropoutConfig::new(0.5).init(),
                    act: Relu::new(),
                    architecture: self.trunk.architecture,
                    cells: s,
                })
            }
            GridHead::Conv => {
                let hidden = Conv2dConfig::new([channels, channels], [3, 3])
                    .with_padding(PaddingConfig2d::Explicit(1, 1, 1, 1))
                    .init(device);
                let mut cells =
                    Conv2dConfig::new([channels, CELL_VALUES], [1, 1]).with_initializer(head_init).init(device);
                cells.bias = cells.bias.map(|b| b.map(|old| replace_value(&old, prior_bias(1, device))));
                GridHeadLayers::Conv(ConvGridHead {
                    hidden,
                    cells,
                    avgpool: AdaptiveAvgPool2dConfig::new([s, s]).init(),
                    act: Relu::new(),
                })
            }
        };
        GridNet { trunk, head }
    }
}

/// A trunk and a grid head.
#[derive(Module, Debug)]
pub struct GridNet {
    pub trunk: Trunk,
    pub head: GridHeadLayers,
}

/// The layers of the [`GridHead`] the config chose.
// One head lives per network; boxing the larger variant would buy nothing.
#[allow(clippy::large_enum_variant)]
#[derive(Module, Debug)]
pub enum GridHeadLayers {
    Fc(FcGridHead),
    Conv(ConvGridHead),
}

/// torchvision's classifier with the last layer replaced by the grid: the
/// trunk's output after its last pooling, average-pooled to 7x7 (6x6).
#[derive(Module, Debug)]
pub struct FcGridHead {
    /// Two hidden layers and the grid layer (`classifier.N` in torchvision,
    /// renumbered 0, 1, 2).
    pub classifier: Vec<Linear>,
    avgpool: AdaptiveAvgPool2d,
    dropout: Dropout,
    act: Relu,
    #[module(skip)]
    architecture: Architecture,
    #[module(skip)]
    cells: usize,
}

/// A 3x3 convolution and a 1x1 convolution to the cell values on the
/// stride-16 features (no last pooling), average-pooled to S x S.
#[derive(Module, Debug)]
pub struct ConvGridHead {
    pub hidden: Conv2d,
    pub cells: Conv2d,
    avgpool: AdaptiveAvgPool2d,
    act: Relu,
}

/// The grid head's raw output, `[B, S, S, 5]`.
#[derive(Debug, Clone)]
pub struct GridOutput {
    pub cells: Tensor<4>,
}

impl GridNet {
    /// The convolutional features: `[B, C, 7, 7]` (VGG16) or `[B, C, 6, 6]`
    /// (AlexNet) for the fc head; `[B, C, S, S]` for the conv head (the
    /// stride-16 features without the last max pooling, resampled to the grid).
    pub fn trunk(&self, x: Tensor<4>) -> Tensor<4> {
        self.trunk_from(x, 0)
    }

    /// The trunk from convolution `start` on, for inputs that are the
    /// output of the first `start` convolutions (cached frozen features).
    pub fn trunk_from(&self, x: Tensor<4>, start: usize) -> Tensor<4> {
        let x = self.convs(x, start..self.trunk.features.len());
        match &self.head {
            GridHeadLayers::Fc(head) => head.avgpool.forward(x),
            GridHeadLayers::Conv(head) => head.avgpool.forward(x),
        }
    }

    /// The first `end` convolutions only.
    pub fn trunk_until(&self, x: Tensor<4>, end: usize) -> Tensor<4> {
        self.convs(x, 0..end)
    }

    fn convs(&self, x: Tensor<4>, layers: std::ops::Range<usize>) -> Tensor<4> {
        // The fc head reads the features after the last pooling, as torchvision's classifier.
        let last_pool = matches!(self.head, GridHeadLayers::Fc(_));
        self.trunk.forward(x, layers, last_pool)
    }

    /// The head on trunk features.
    pub fn head(&self, features: Tensor<4>) -> GridOutput {
        let cells = match &self.head {
            GridHeadLayers::Fc(head) => head.forward(features),
            GridHeadLayers::Conv(head) => head.forward(features),
        };
        GridOutput { cells }
    }

    /// The output of the fc head's two hidden layers (the input of the
    /// layer that torchvision's 1000 classes and our grid head share);
    /// `None` with the conv head.
    pub fn hidden(&self, features: Tensor<4>) -> Option<Tensor<2>> {
        match &self.head {
            GridHeadLayers::Fc(head) => Some(head.hidden(features)),
            GridHeadLayers::Conv(_) => None,
        }
    }

    /// The fc head's two hidden layers (what pretrained classifiers fill).
    pub fn hidden_layers(&self) -> Vec<&Linear> {
        match &self.head {
            GridHeadLayers::Fc(head) => head.classifier.iter().take(2).collect(),
            GridHeadLayers::Conv(_) => Vec::new(),
        }
    }

    pub fn forward(&self, x: Tensor<4>) -> GridOutput {
        self.head(self.trunk(x))
    }
}

impl FcGridHead {
    /// `features`: `[B, C, 7, 7]` (`[B, C, 6, 6]`) -> `[B, S, S, 5]`.
    pub fn forward(&self, features: Tensor<4>) -> Tensor<4> {
        let [b, ..] = features.dims();
        let out = self.classifier[2].forward(self.hidden(features));
        out.reshape([b, self.cells, self.cells, CELL_VALUES])
    }

    fn hidden(&self, features: Tensor<4>) -> Tensor<2> {
        let x: Tensor<2> = features.flatten(1, 3);
        // torchvision: VGG applies dropout after each hidden layer, AlexNet before.
        match self.architecture {
            Architecture::Alexnet => {
                let x = self.act.forward(self.classifier[0].forward(self.dropout.forward(x)));
                self.act.forward(self.classifier[1].forward(self.dropout.forward(x)))
            }
            Architecture::Vgg16 => {
                let x = self.dropout.forward(self.act.forward(self.classifier[0].forward(x)));
                self.dropout.forward(self.act.forward(self.classifier[1].forward(x)))
            }
        }
    }
}

impl ConvGridHead {
    /// `features`: `[B, C, S, S]` -> `[B, S, S, 5]`.
    pub fn forward(&self, features: Tensor<4>) -> Tensor<4> {
        let x = conv2d_relu(&self.hidden, features);
        conv2d(&self.cells, x).permute([0, 2, 3, 1])
    }
}
