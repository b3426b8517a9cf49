//! VGG16 and AlexNet as the paper's baselines: torchvision's layers with the
//! last classifier layer replaced by a grid head. For each cell of an S x S
//! grid over the input the head predicts a corner-presence logit, the
//! corner's offset within the cell (two logits, squashed to 0..1) and its
//! box size (log of width and height over the cell side).
//!
//! The head is convolutional by default (`GridHead::Conv`, one output pixel
//! per cell on the stride-16 features); `GridHead::Fc` keeps torchvision's
//! classifier and replaces only its last layer, the literal baseline.

use burn::nn::PaddingConfig2d;
use burn::nn::conv::{Conv2d, Conv2dConfig};
use burn::nn::pool::{AdaptiveAvgPool2d, AdaptiveAvgPool2dConfig, MaxPool2d};
use burn::nn::{Dropout, DropoutConfig, Initializer, Linear, LinearConfig, Relu};
use burn::prelude::*;

use crate::conv_op::conv2d;

use crate::config::{Backbone, DetectorConfig, GridHead};
use crate::trunk;

/// Values per grid cell: presence, offset x, offset y, log width, log height.
pub const CELL_VALUES: usize = 5;

#[derive(Module, Debug)]
pub struct GridNet {
    /// Convolutions (`features.N` in torchvision).
    pub features: Vec<Conv2d>,
    /// `GridHead::Fc`: three linear layers, the last is the grid head
    /// (`classifier.N`). Empty with the conv head.
    pub classifier: Vec<Linear>,
    /// `GridHead::Conv`: a 3x3 convolution and the 1x1 grid head. Empty
    /// with the fc head.
    pub head_convs: Vec<Conv2d>,
    pool: MaxPool2d,
    /// To 7x7 (6x6) for the fc head, to the grid's S x S for the conv head.
    avgpool: AdaptiveAvgPool2d,
    dropout: Dropout,
    act: Relu,
    #[module(skip)]
    backbone: Backbone,
    #[module(skip)]
    head_kind: GridHead,
    #[module(skip)]
    cells: usize,
}

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

/// The grid head's raw output, `[B, S, S, 5]`.
#[derive(Debug, Clone)]
pub struct GridOutput {
    pub cells: Tensor<4>,
}

impl GridNet {
    pub fn new(config: &DetectorConfig, device: &Device) -> Self {
        let (features, pool, spatial, channels) = match config.backbone {
            Backbone::Vgg16 => (trunk::vgg16_convs(config, device), trunk::max_pool_2x2(), 7, config.channels(512)),
            Backbone::Alexnet => (trunk::alexnet_convs(config, device), trunk::alexnet_pool(), 6, config.channels(256)),
            Backbone::FasterRcnn => panic!("GridNet is for vgg16 and alexnet"),
        };
        let s = config.grid_cells;
        let head_init = Initializer::Normal { mean: 0.0, std: 0.01 };
        let (classifier, head_convs, pooled) = match config.grid_head {
            GridHead::Fc => {
                let h = config.hidden;
                // PyTorch's default init for the hidden layers: torchvision's N(0, 0.01)
                // for VGG suits 4096-wide layers but starves the narrow ones of signal.
                let linear = |i: usize, o: usize| LinearConfig::new(i, o).init(device);
                let mut head = LinearConfig::new(h, s * s * CELL_VALUES).with_initializer(head_init).init(device);
                head.bias = head.bias.map(|b| b.map(|old| trunk::replace_value(&old, prior_bias(s * s, device))));
                (vec![linear(channels * spatial * spatial, h), linear(h, h), head], vec![], spatial)
            }
            GridHead::Conv => {
                let hidden = Conv2dConfig::new([channels, channels], [3, 3])
                    .with_padding(PaddingConfig2d::Explicit(1, 1, 1, 1))
                    .init(device);
                let mut head =
                    Conv2dConfig::new([channels, CELL_VALUES], [1, 1]).with_initializer(head_init).init(device);
                head.bias = head.bias.map(|b| b.map(|old| trunk::replace_value(&old, prior_bias(1, device))));
                (vec![], vec![hidden, head], s)
            }
        };
        Self {
            features,
            classifier,
            head_convs,
            pool,
            avgpool: AdaptiveAvgPool2dConfig::new([pooled, pooled]).init(),
            dropout: DropoutConfig::new(0.5).init(),
            act: Relu::new(),
            backbone: config.backbone,
            head_kind: config.grid_head,
            cells: s,
        }
    }

    /// The convolutional features: `[B, C, 7, 7]` (VGG16) or `[B, C, 6, 6]`
    /// (AlexNet) for the fc head; `[B, C, S, S]` for the conv head (the
    /// stride-16 features without the last max pooling, resampled to the grid).
    pub fn trunk(&self, x: Tensor<4>) -> Tensor<4> {
        self.trunk_from(x, 0)
    }

    /// The trunk from convolution `start` on, for inputs that are the
    /// output of the first `start` convolutions (cached frozen features).
    pub fn trunk_from(&self, x: Tensor<4>, start: usize) -> Tensor<4> {
        self.avgpool.forward(self.convs(x, start..self.features.len()))
    }

    /// The first `end` convolutions only.
    pub fn trunk_until(&self, x: Tensor<4>, end: usize) -> Tensor<4> {
        self.convs(x, 0..end)
    }

    fn convs(&self, x: Tensor<4>, layers: std::ops::Range<usize>) -> Tensor<4> {
        let last_pool = self.head_kind == GridHead::Fc;
        match self.backbone {
            Backbone::Alexnet => {
                trunk::alexnet_forward_range(&self.features, &self.pool, &self.act, x, layers, last_pool)
            }
            _ => trunk::vgg16_forward_range(&self.features, &self.pool, &self.act, x, layers, last_pool),
        }
    }

    /// The head on trunk features.
    pub fn head(&self, features: Tensor<4>) -> GridOutput {
        let [b, ..] = features.dims();
        let cells = match self.head_kind {
            GridHead::Fc => {
                let out = self.classifier[2].forward(self.hidden(features));
                out.reshape([b, self.cells, self.cells, CELL_VALUES])
            }
            GridHead::Conv => {
                let x = self.act.forward(conv2d(&self.head_convs[0], features));
                conv2d(&self.head_convs[1], x).permute([0, 2, 3, 1])
            }
        };
        GridOutput { cells }
    }

    /// The output of the two hidden classifier layers (the input of the
    /// layer that torchvision's 1000 classes and our grid head share). Fc
    /// head only.
    pub fn hidden(&self, features: Tensor<4>) -> Tensor<2> {
        let x: Tensor<2> = features.flatten(1, 3);
        // torchvision: VGG applies dropout after each hidden layer, AlexNet before.
        match self.backbone {
            Backbone::Alexnet => {
                let x = self.act.forward(self.classifier[0].forward(self.dropout.forward(x)));
                self.act.forward(self.classifier[1].forward(self.dropout.forward(x)))
            }
            _ => {
                let x = self.dropout.forward(self.act.forward(self.classifier[0].forward(x)));
                self.dropout.forward(self.act.forward(self.classifier[1].forward(x)))
            }
        }
    }

    pub fn forward(&self, x: Tensor<4>) -> GridOutput {
        self.head(self.trunk(x))
    }
}
