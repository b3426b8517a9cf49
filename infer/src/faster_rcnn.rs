//! Faster R-CNN on a VGG16 trunk (stride 16): a region proposal network over
//! anchors, proposals by decoding, clipping, small-box removal and NMS,
//! RoIAlign to 7 x 7, two fully connected layers, then class scores and
//! per-class box deltas.

use burn::config::Config;
use burn::nn::conv::{Conv2d, Conv2dConfig};
use burn::nn::{Initializer, Linear, LinearConfig, PaddingConfig2d, Relu};
use burn::prelude::*;
use burn::tensor::activation::softmax;

use crate::anchors::AnchorConfig;
use crate::boxes::{BBox, BoxCoder, batched_nms, nms, remove_small};
use crate::kernels::conv_op::{conv2d, conv2d_relu};
use crate::roi_align::roi_align;
use crate::trunk::{Trunk, TrunkConfig};

pub const STRIDE: f32 = 16.0;

/// torchvision's initialisation of the heads: N(0, std).
fn normal(std: f64) -> Initializer {
    Initializer::Normal { mean: 0.0, std }
}

#[derive(Config, Debug)]
pub struct FasterRcnnConfig {
    /// A VGG16 trunk.
    pub trunk: TrunkConfig,
    pub anchors_per_location: usize,
    /// Width of the two fully connected layers of the box head.
    pub hidden: usize,
    /// Object classes, without the background.
    pub num_classes: usize,
    /// RoIAlign's output side.
    #[config(default = 7)]
    pub pool_size: usize,
    #[config(default = 2)]
    pub sampling_ratio: usize,
}

impl FasterRcnnConfig {
    pub fn init(&self, device: &Device) -> FasterRcnn {
        let c = self.trunk.out_channels();
        FasterRcnn {
            trunk: self.trunk.init(device),
            rpn: RpnHeadConfig::new(c, self.anchors_per_location).init(device),
            box_head: BoxHeadConfig::new(c * self.pool_size * self.pool_size, self.hidden, self.num_classes + 1)
                .init(device),
            pool_size: self.pool_size,
            sampling_ratio: self.sampling_ratio,
        }
    }
}

/// The two stages on the trunk's stride-16 features.
#[derive(Module, Debug)]
pub struct FasterRcnn {
    /// VGG16 convolutions, run without the last pooling.
    pub trunk: Trunk,
    pub rpn: RpnHead,
    pub box_head: BoxHead,
    #[module(skip)]
    pool_size: usize,
    #[module(skip)]
    sampling_ratio: usize,
}

#[derive(Config, Debug)]
pub struct RpnHeadConfig {
    /// Channels of the trunk's features.
    pub channels: usize,
    pub anchors_per_location: usize,
}

impl RpnHeadConfig {
    pub fn init(&self, device: &Device) -> RpnHead {
        let (c, a) = (self.channels, self.anchors_per_location);
        let conv = |i: usize, o: usize, kernel: usize| {
            let pad = kernel / 2;
            Conv2dConfig::new([i, o], [kernel, kernel])
                .with_padding(PaddingConfig2d::Explicit(pad, pad, pad, pad))
                .with_initializer(normal(0.01))
                .init(device)
        };
        RpnHead { conv: conv(c, c, 3), cls: conv(c, a, 1), bbox: conv(c, 4 * a, 1), act: Relu::new() }
    }
}

/// A shared 3x3 convolution, then per anchor an objectness logit and four deltas.
#[derive(Module, Debug)]
pub struct RpnHead {
    pub conv: Conv2d,
    pub cls: Conv2d,
    pub bbox: Conv2d,
    act: Relu,
}

/// The RPN's raw output in anchor order (location-major, then anchor).
#[derive(Debug, Clone)]
pub struct RpnOutput {
    /// `[B, N]` objectness logits.
    pub objectness: Tensor<2>,
    /// `[B, N, 4]` deltas relative to the anchors.
    pub deltas: Tensor<3>,
    pub grid_h: usize,
    pub grid_w: usize,
}

impl RpnHead {
    /// `features`: `[B, C, H, W]`.
    pub fn forward(&self, features: Tensor<4>) -> RpnOutput {
        let [b, _, h, w] = features.dims();
        let [a, ..] = self.cls.weight.dims();
        let t = conv2d_relu(&self.conv, features);
        // [B, A, H, W] -> [B, H, W, A] -> [B, H*W*A]
        let objectness = conv2d(&self.cls, t.clone()).permute([0, 2, 3, 1]).reshape([b, h * w * a]);
        // [B, A*4, H, W] -> [B, A, 4, H, W] -> [B, H, W, A, 4] -> [B, H*W*A, 4]
        let deltas = conv2d(&self.bbox, t).reshape([b, a, 4, h, w]).permute([0, 3, 4, 1, 2]).reshape([b, h * w * a, 4]);
        RpnOutput { objectness, deltas, grid_h: h, grid_w: w }
    }
}

#[derive(Config, Debug)]
pub struct BoxHeadConfig {
    /// Values of one pooled RoI (channels x pool size x pool size).
    pub in_features: usize,
    pub hidden: usize,
    /// Classes with the background.
    pub classes: usize,
}

impl BoxHeadConfig {
    pub fn init(&self, device: &Device) -> BoxHead {
        let (h, k) = (self.hidden, self.classes);
        BoxHead {
            fc6: LinearConfig::new(self.in_features, h).init(device),
            fc7: LinearConfig::new(h, h).init(device),
            cls_score: LinearConfig::new(h, k).with_initializer(normal(0.01)).init(device),
            bbox_pred: LinearConfig::new(h, 4 * k).with_initializer(normal(0.001)).init(device),
            act: Relu::new(),
        }
    }
}

/// torchvision's `TwoMLPHead` and `FastRCNNPredictor`: two fully connected
/// layers, then class logits and per-class box deltas.
#[derive(Module, Debug)]
pub struct BoxHead {
    pub fc6: Linear,
    pub fc7: Linear,
    pub cls_score: Linear,
    pub bbox_pred: Linear,
    act: Relu,
}

/// The box head's raw output for a set of RoIs.
#[derive(Debug, Clone)]
pub struct HeadOutput {
    /// `[K, classes + 1]` logits; column 0 is background.
    pub class_logits: Tensor<2>,
    /// `[K, 4 * (classes + 1)]` deltas per class.
    pub box_deltas: Tensor<2>,
}

impl BoxHead {
    /// `pooled`: `[K, in_features]`, one flattened RoI per row.
    pub fn forward(&self, pooled: Tensor<2>) -> HeadOutput {
        let x = self.act.forward(self.fc6.forward(pooled));
        let x = self.act.forward(self.fc7.forward(x));
        HeadOutput { class_logits: self.cls_score.forward(x.clone()), box_deltas: self.bbox_pred.forward(x) }
    }
}

impl FasterRcnn {
    /// `[B, C, H/16, W/16]` features.
    pub fn trunk(&self, x: Tensor<4>) -> Tensor<4> {
        self.trunk_from(x, 0)
    }

    /// The trunk from convolution `start` on, for inputs that are the
    /// output of the first `start` convolutions (cached frozen features).
    pub fn trunk_from(&self, x: Tensor<4>, start: usize) -> Tensor<4> {
        self.trunk.forward(x, start..self.trunk.features.len(), false)
    }

    /// The first `end` convolutions only.
    pub fn trunk_until(&self, x: Tensor<4>, end: usize) -> Tensor<4> {
        self.trunk.forward(x, 0..end, false)
    }

    pub fn rpn(&self, features: Tensor<4>) -> RpnOutput {
        self.rpn.forward(features)
    }

    /// RoIAlign of each image's RoIs (input pixels) from `features`, then the
    /// box head.
    pub fn head(&self, features: Tensor<4>, rois: &[Vec<BBox>]) -> HeadOutput {
        let [b, ..] = features.dims();
        let mut pooled = Vec::with_capacity(b);
        for (i, image_rois) in rois.iter().enumerate() {
            if image_rois.is_empty() {
                continue;
            }
            let scaled: Vec<BBox> = image_rois.iter().map(|r| r.scale(1.0 / STRIDE, 1.0 / STRIDE)).collect();
            let map = features.clone().narrow(0, i, 1);
            pooled.push(roi_align(map, &scaled, self.pool_size, self.sampling_ratio));
        }
        // [K, C, P, P] -> [K, C*P*P]
        self.box_head.forward(Tensor::cat(pooled, 0).flatten(1, 3))
    }
}

/// Proposal settings of one phase (training or testing).
#[derive(Debug, Clone, Copy)]
pub struct ProposalSettings {
    pub pre_nms_top_n: usize,
    pub post_nms_top_n: usize,
    pub nms_iou: f32,
    pub min_size: f32,
}

/// Turns the RPN's output into proposals per image (input pixels), as
/// torchvision does: top-k by objectness, decode, clip, drop tiny boxes,
/// NMS, keep the best.
pub fn proposals(
    objectness: &[f32],
    deltas: &[f32],
    anchors: &[BBox],
    image_size: f32,
    settings: ProposalSettings,
) -> Vec<BBox> {
    let coder = BoxCoder::new([1.0, 1.0, 1.0, 1.0]);
    let mut order: Vec<usize> = (0..anchors.len()).collect();
    order.sort_by(|&a, &b| objectness[b].total_cmp(&objectness[a]).then(a.cmp(&b)));
    order.truncate(settings.pre_nms_top_n);
    let boxes: Vec<BBox> = order
        .iter()
        .map(|&i| {
            let d = [deltas[4 * i], deltas[4 * i + 1], deltas[4 * i + 2], deltas[4 * i + 3]];
            coder.decode(&anchors[i], d).clip(image_size, image_size)
        })
        .collect();
    let scores: Vec<f32> = order.iter().map(|&i| objectness[i]).collect();
    let kept = remove_small(&boxes, settings.min_size);
    let boxes: Vec<BBox> = kept.iter().map(|&i| boxes[i]).collect();
    let scores: Vec<f32> = kept.iter().map(|&i| scores[i]).collect();
    let mut keep = nms(&boxes, &scores, settings.nms_iou);
    keep.truncate(settings.post_nms_top_n);
    keep.into_iter().map(|i| boxes[i]).collect()
}

/// The anchors of a feature grid.
pub fn anchors_for(config: &AnchorConfig, grid_h: usize, grid_w: usize) -> Vec<BBox> {
    config.grid_anchors(grid_h, grid_w, STRIDE)
}

/// Final detections of one image from the head's output on its proposals:
/// softmax scores, per-class decoding, clipping, thresholding, per-class NMS.
#[allow(clippy::too_many_arguments)]
pub fn postprocess(
    class_logits: Tensor<2>,
    box_deltas: Tensor<2>,
    proposals: &[BBox],
    box_weights: [f32; 4],
    image_size: f32,
    score_threshold: f32,
    nms_iou: f32,
    max_detections: usize,
) -> Vec<(BBox, f32, usize)> {
    let [_, k] = class_logits.dims();
    let scores = crate::host(softmax(class_logits, 1));
    let deltas = crate::host(box_deltas);
    let coder = BoxCoder::new(box_weights);
    let (mut boxes, mut best, mut classes) = (Vec::new(), Vec::new(), Vec::new());
    for (i, p) in proposals.iter().enumerate() {
        for c in 1..k {
            let s = scores[i * k + c];
            if s <= score_threshold {
                continue;
            }
            let o = i * 4 * k + 4 * c;
            let b =
                coder.decode(p, [deltas[o], deltas[o + 1], deltas[o + 2], deltas[o + 3]]).clip(image_size, image_size);
            if b.width() < 1e-2 || b.height() < 1e-2 {
                continue;
            }
            boxes.push(b);
            best.push(s);
            classes.push(c - 1);
        }
    }
    let mut keep = batched_nms(&boxes, &best, &classes, nms_iou);
    keep.truncate(max_detections);
    keep.into_iter().map(|i| (boxes[i], best[i], classes[i])).collect()
}
