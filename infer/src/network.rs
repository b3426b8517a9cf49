//! One type over the three networks, so that training, inference and
//! checkpoints handle them alike.

use burn::module::{ModuleVisitor, Param};
use burn::nn::Linear;
use burn::nn::conv::Conv2d;
use burn::prelude::*;

use crate::boxes::{BBox, batched_nms};
use crate::config::{Backbone, DetectorConfig};
use crate::faster_rcnn::{self, FasterRcnn};
use crate::grid_net::{CELL_VALUES, GridHeadLayers, GridNet};
use crate::trunk::{replace_value, widen_filters};

// One network lives per process; boxing the larger variant would buy nothing.
#[allow(clippy::large_enum_variant)]
#[derive(Debug, Clone)]
pub enum Network {
    FasterRcnn(FasterRcnn),
    Grid(GridNet),
}

/// A detection in the coordinates of the image it was asked for.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Detection {
    pub bbox: BBox,
    pub score: f32,
    pub class: usize,
}

impl Network {
    /// Builds the network with freshly drawn weights. Burn draws a
    /// parameter's initial value lazily, at its first use, from the device's
    /// generator; every parameter is drawn here instead, so that the weights
    /// depend only on the seed and not on what runs first (a feature cache,
    /// a validation pass).
    pub fn new(config: &DetectorConfig, device: &Device) -> Self {
        let network = match config.backbone {
            Backbone::FasterRcnn => Self::FasterRcnn(config.faster_rcnn().init(device)),
            Backbone::Vgg16 | Backbone::Alexnet => Self::Grid(config.grid_net().init(device)),
        };
        struct Draw;
        impl ModuleVisitor for Draw {
            fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
                let _ = param.val();
            }
        }
        match &network {
            Self::FasterRcnn(m) => m.visit(&mut Draw),
            Self::Grid(m) => m.visit(&mut Draw),
        }
        network
    }

    /// The path of the first parameter holding a NaN or an infinity, with
    /// how many of its values are not finite.
    pub fn first_non_finite(&self) -> Option<(String, usize)> {
        #[derive(Default)]
        struct Check {
            path: Vec<String>,
            found: Option<(String, usize)>,
        }
        impl ModuleVisitor for Check {
            fn enter_module(&mut self, name: &str, _container_type: &str) {
                self.path.push(name.to_string());
            }
            fn exit_module(&mut self, _name: &str, _container_type: &str) {
                self.path.pop();
            }
            fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
                if self.found.is_some() {
                    return;
                }
                let bad = crate::host(param.val()).iter().filter(|v| !v.is_finite()).count();
                if bad > 0 {
                    let path = self.path.iter().filter(|p| !p.is_empty()).cloned().collect::<Vec<_>>().join(".");
                    self.found = Some((path, bad));
                }
            }
        }
        let mut check = Check::default();
        match self {
            Self::FasterRcnn(m) => m.visit(&mut check),
            Self::Grid(m) => m.visit(&mut check),
        }
        check.found
    }

    pub fn num_params(&self) -> usize {
        match self {
            Self::FasterRcnn(m) => m.num_params(),
            Self::Grid(m) => m.num_params(),
        }
    }

    /// The trunk's convolutions and the two hidden fully connected layers
    /// (Faster R-CNN's fc6/fc7, the grid networks' first two classifier
    /// layers): what pretrained weights fill.
    pub fn trunk_layers_mut(&mut self) -> (&mut Vec<Conv2d>, Vec<&mut Linear>) {
        match self {
            Self::FasterRcnn(m) => (&mut m.trunk.features, vec![&mut m.box_head.fc6, &mut m.box_head.fc7]),
            Self::Grid(m) => {
                let GridNet { trunk, head } = m;
                let hidden = match head {
                    GridHeadLayers::Fc(fc) => fc.classifier.iter_mut().take(2).collect(),
                    GridHeadLayers::Conv(_) => Vec::new(),
                };
                (&mut trunk.features, hidden)
            }
        }
    }

    pub fn hidden_layers(&self) -> Vec<&Linear> {
        match self {
            Self::FasterRcnn(m) => vec![&m.box_head.fc6, &m.box_head.fc7],
            Self::Grid(m) => m.hidden_layers(),
        }
    }

    pub fn trunk_convs(&self) -> &[Conv2d] {
        match self {
            Self::FasterRcnn(m) => &m.trunk.features,
            Self::Grid(m) => &m.trunk.features,
        }
    }

    /// Gives the first convolution `channels` input channels, the new ones
    /// with zero weights: the network answers exactly as before until
    /// training teaches it to use them.
    pub fn widen_input(&mut self, channels: usize) {
        let (convs, _) = self.trunk_layers_mut();
        let first = &mut convs[0];
        let [out, have, kh, kw] = first.weight.dims();
        if channels <= have {
            return;
        }
        first.weight = first.weight.clone().map(|old| {
            let wide = widen_filters(&crate::host(old.clone()), out, kh * kw, channels);
            replace_value(&old, Tensor::<4>::from_data(TensorData::new(wide, [out, channels, kh, kw]), &old.device()))
        });
    }

    /// Stops training of the first `n` convolutions: no gradient reaches
    /// their parameters, so the optimizer leaves them bit-identical.
    pub fn freeze_convs(mut self, n: usize) -> Self {
        let (convs, _) = self.trunk_layers_mut();
        for conv in convs.iter_mut().take(n) {
            *conv = conv.clone().no_grad();
        }
        self
    }

    /// The output of the first `end` trunk convolutions (with their pooling).
    pub fn trunk_until(&self, x: Tensor<4>, end: usize) -> Tensor<4> {
        match self {
            Self::FasterRcnn(m) => m.trunk_until(x, end),
            Self::Grid(m) => m.trunk_until(x, end),
        }
    }

    /// Dropout off, no autodiff tracking: the network for inference.
    pub fn valid(&self) -> Self {
        match self {
            Self::FasterRcnn(m) => Self::FasterRcnn(m.valid()),
            Self::Grid(m) => Self::Grid(m.valid()),
        }
    }

    /// Detections on a batch `[B, C, S, S]` of network inputs, in input pixels.
    pub fn detect(&self, config: &DetectorConfig, inputs: Tensor<4>) -> Vec<Vec<Detection>> {
        let size = config.input_size() as f32;
        let d = &config.detection;
        match self {
            Self::FasterRcnn(m) => {
                let features = m.trunk(inputs);
                let rpn = m.rpn(features.clone());
                let [b, n] = rpn.objectness.dims();
                let objectness = crate::host(rpn.objectness);
                let deltas = crate::host(rpn.deltas);
                let anchors = faster_rcnn::anchors_for(&config.anchors, rpn.grid_h, rpn.grid_w);
                let settings = config.rpn.proposals(false);
                let proposals: Vec<Vec<BBox>> = (0..b)
                    .map(|i| {
                        faster_rcnn::proposals(
                            &objectness[i * n..(i + 1) * n],
                            &deltas[i * n * 4..(i + 1) * n * 4],
                            &anchors,
                            size,
                            settings,
                        )
                    })
                    .collect();
                if proposals.iter().all(Vec::is_empty) {
                    return vec![Vec::new(); b];
                }
                let head = m.head(features, &proposals);
                let mut out = Vec::with_capacity(b);
                let mut row = 0;
                for p in &proposals {
                    let rows = p.len();
                    if rows == 0 {
                        out.push(Vec::new());
                        continue;
                    }
                    let logits = head.class_logits.clone().narrow(0, row, rows);
                    let deltas = head.box_deltas.clone().narrow(0, row, rows);
                    row += rows;
                    let dets = faster_rcnn::postprocess(
                        logits,
                        deltas,
                        p,
                        config.roi.box_weights,
                        size,
                        d.score_threshold,
                        d.nms_iou,
                        d.max_detections,
                    );
                    out.push(dets.into_iter().map(|(bbox, score, class)| Detection { bbox, score, class }).collect());
                }
                out
            }
            Self::Grid(m) => {
                let cells = m.forward(inputs).cells;
                let [b, s, _, _] = cells.dims();
                let values = crate::host(cells);
                (0..b)
                    .map(|i| {
                        decode_grid(&values[i * s * s * CELL_VALUES..(i + 1) * s * s * CELL_VALUES], s, size, config)
                    })
                    .collect()
            }
        }
    }
}

fn sigmoid(x: f32) -> f32 {
    1.0 / (1.0 + (-x).exp())
}

/// Boxes from one image's grid output (`[S, S, 5]`, row-major).
pub fn decode_grid(values: &[f32], s: usize, size: f32, config: &DetectorConfig) -> Vec<Detection> {
    let cell = size / s as f32;
    let d = &config.detection;
    let (mut boxes, mut scores) = (Vec::new(), Vec::new());
    for row in 0..s {
        for col in 0..s {
            let v = &values[(row * s + col) * CELL_VALUES..(row * s + col + 1) * CELL_VALUES];
            let score = sigmoid(v[0]);
            if score <= d.score_threshold {
                continue;
            }
            let cx = (col as f32 + sigmoid(v[1])) * cell;
            let cy = (row as f32 + sigmoid(v[2])) * cell;
            let (w, h) = (v[3].clamp(-4.0, 4.0).exp() * cell, v[4].clamp(-4.0, 4.0).exp() * cell);
            boxes.push(BBox::new(cx - w / 2.0, cy - h / 2.0, cx + w / 2.0, cy + h / 2.0).clip(size, size));
            scores.push(score);
        }
    }
    let classes = vec![0; boxes.len()];
    let mut keep = batched_nms(&boxes, &scores, &classes, d.nms_iou);
    keep.truncate(d.max_detections);
    keep.into_iter().map(|i| Detection { bbox: boxes[i], score: scores[i], class: 0 }).collect()
}
