//! VGG16 and AlexNet as the paper's baselines: torchvision's layers with the
//! last classifier layer replaced by a grid head. For each cell of an S x S
//! grid over the input the head predicts a corner-presence logit, the
//! corner's offset within the cell (two logits, squashed to 0..1) and its
//! box size (log of width and height over the cell side).

use burn::nn::conv::Conv2d;
use burn::nn::pool::{AdaptiveAvgPool2d, AdaptiveAvgPool2dConfig, MaxPool2d};
use burn::nn::{Dropout, DropoutConfig, Initializer, Linear, LinearConfig, Relu};
use burn::prelude::*;

use crate::config::{Backbone, DetectorConfig};
use crate::trunk;

/// Values per grid cell: presence, offset x, offset y, log width, log height.
pub const CELL_VALUES: usize = 5;

#[derive(Module, Debug)]
pub struct GridNet {
    /// Convolutions (`features.N` in torchvision).
    pub features: Vec<Conv2d>,
    /// Three linear layers; the last is the grid head (`classifier.N`).
    pub classifier: Vec<Linear>,
    pool: MaxPool2d,
    avgpool: AdaptiveAvgPool2d,
    dropout: Dropout,
    act: Relu,
    #[module(skip)]
    backbone: Backbone,
    #[module(skip)]
    cells: usize,
}

/// Expected share of cells holding a corner, used to start the presence
/// logits there (RetinaNet's prior trick): a zero logit would claim half the
/// cells and the optimizer would spend its first thousand steps undoing it.
pub const PRESENCE_PRIOR: f64 = 0.03;

/// Zero bias except the presence logit of every cell, set to the prior.
fn prior_bias(mut layer: Linear, cells: usize, device: &Device) -> Linear {
    let logit = -((1.0 - PRESENCE_PRIOR) / PRESENCE_PRIOR).ln() as f32;
    let values: Vec<f32> = (0..cells * CELL_VALUES).map(|i| if i % CELL_VALUES == 0 { logit } else { 0.0 }).collect();
    let n = values.len();
    let prior = Tensor::<1>::from_data(TensorData::new(values, [n]), device);
    layer.bias = layer.bias.map(|b| b.map(|old| trunk::replace_value(&old, prior)));
    layer
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
        let h = config.hidden;
        let s = config.grid_cells;
        // PyTorch's default init for the hidden layers: torchvision's N(0, 0.01)
        // for VGG suits 4096-wide layers but starves the narrow ones of signal.
        let linear = |i: usize, o: usize| LinearConfig::new(i, o).init(device);
        let head = LinearConfig::new(h, s * s * CELL_VALUES)
            .with_initializer(Initializer::Normal { mean: 0.0, std: 0.01 })
            .init(device);
        let classifier = vec![linear(channels * spatial * spatial, h), linear(h, h), prior_bias(head, s * s, device)];
        Self {
            features,
            classifier,
            pool,
            avgpool: AdaptiveAvgPool2dConfig::new([spatial, spatial]).init(),
            dropout: DropoutConfig::new(0.5).init(),
            act: Relu::new(),
            backbone: config.backbone,
            cells: s,
        }
    }

    /// The convolutional features: `[B, C, 7, 7]` (VGG16) or `[B, C, 6, 6]` (AlexNet).
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
        match self.backbone {
            Backbone::Alexnet => trunk::alexnet_forward_range(&self.features, &self.pool, &self.act, x, layers),
            _ => trunk::vgg16_forward_range(&self.features, &self.pool, &self.act, x, layers, true),
        }
    }

    /// The head on trunk features.
    pub fn head(&self, features: Tensor<4>) -> GridOutput {
        let [b, ..] = features.dims();
        let out = self.classifier[2].forward(self.hidden(features));
        GridOutput { cells: out.reshape([b, self.cells, self.cells, CELL_VALUES]) }
    }

    /// The output of the two hidden classifier layers (the input of the
    /// layer that torchvision's 1000 classes and our grid head share).
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
