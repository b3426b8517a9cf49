//! The training losses of the three networks, on tensors so that autodiff
//! differentiates them: Faster R-CNN's four (RPN objectness, RPN box, head
//! classification, head box) and the grid heads' three (presence, offset,
//! size).

use burn::nn::loss::CrossEntropyLossConfig;
use burn::prelude::*;
use burn::tensor::activation::sigmoid;

use crate::targets::{GridTargets, RoiTargets, RpnTargets};
use infer::faster_rcnn::{HeadOutput, RpnOutput};
use infer::grid_net::GridOutput;

/// A loss and its named parts (for the loss log).
#[derive(Debug, Clone)]
pub struct Losses {
    pub total: Tensor<1>,
    pub parts: Vec<(&'static str, Tensor<1>)>,
}

impl Losses {
    fn new(parts: Vec<(&'static str, Tensor<1>)>) -> Self {
        let total = parts.iter().map(|(_, t)| t.clone()).reduce(|a, b| a + b).expect("at least one part");
        Self { total, parts }
    }
}

/// Part names of each network's loss, in log order.
pub const FASTER_RCNN_PARTS: [&str; 4] = ["rpn_objectness", "rpn_box", "classifier", "box"];
pub const GRID_PARTS: [&str; 4] = ["presence", "offset", "size", "unused"];

/// Smooth L1 (Huber with `beta`), element-wise, without branches:
/// with `q = min(|d|, beta)`, it is `0.5 q^2 / beta + (|d| - q)`.
pub fn smooth_l1<const D: usize>(pred: Tensor<D>, target: Tensor<D>, beta: f32) -> Tensor<D> {
    let d = (pred - target).abs();
    let q = d.clone().clamp_max(beta);
    q.clone().powf_scalar(2.0).mul_scalar(0.5 / beta) + d - q
}

/// Binary cross entropy on logits, element-wise, numerically stable:
/// `max(x, 0) - x y + log(1 + exp(-|x|))`.
pub fn bce_with_logits<const D: usize>(logits: Tensor<D>, targets: Tensor<D>) -> Tensor<D> {
    let softplus_neg_abs = logits.clone().abs().neg().exp().add_scalar(1.0).log();
    logits.clone().clamp_min(0.0) - logits * targets + softplus_neg_abs
}

fn int_tensor(values: Vec<i64>, device: &Device) -> Tensor<1, Int> {
    let n = values.len();
    Tensor::<1, Int>::from_data(TensorData::new(values, [n]), device)
}

fn float_tensor<const D: usize>(values: Vec<f32>, shape: [usize; D], device: &Device) -> Tensor<D> {
    Tensor::<D>::from_data(TensorData::new(values, shape), device)
}

fn zero(device: &Device) -> Tensor<1> {
    Tensor::<1>::zeros([1], device)
}

/// RPN losses: mean BCE over the sampled anchors, and smooth L1 (beta 1/9)
/// over the positives divided by the number sampled, as torchvision does.
pub fn rpn_losses(rpn: &RpnOutput, targets: &[RpnTargets]) -> (Tensor<1>, Tensor<1>) {
    let device = rpn.objectness.device();
    let [b, n] = rpn.objectness.dims();
    let (mut idx, mut labels, mut pos_idx, mut pos_targets) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    for (i, t) in targets.iter().enumerate() {
        for &(a, l) in &t.sampled {
            idx.push((i * n + a) as i64);
            labels.push(l);
        }
        for &(a, d) in &t.positives {
            pos_idx.push((i * n + a) as i64);
            pos_targets.extend_from_slice(&d);
        }
    }
    let sampled = idx.len();
    if sampled == 0 {
        return (zero(&device), zero(&device));
    }
    let logits = rpn.objectness.clone().reshape([b * n]).select(0, int_tensor(idx, &device));
    let objectness = bce_with_logits(logits, float_tensor(labels, [sampled], &device)).mean();
    let box_loss = if pos_idx.is_empty() {
        zero(&device)
    } else {
        let p = pos_idx.len();
        let pred = rpn.deltas.clone().reshape([b * n, 4]).select(0, int_tensor(pos_idx, &device));
        smooth_l1(pred, float_tensor(pos_targets, [p, 4], &device), 1.0 / 9.0).sum().div_scalar(sampled as f32)
    };
    (objectness, box_loss)
}

/// Head losses: cross entropy over the sampled RoIs, and smooth L1 (beta
/// 1/9) on the foreground RoIs' deltas of their class, divided by the RoIs.
pub fn head_losses(head: &HeadOutput, targets: &[RoiTargets]) -> (Tensor<1>, Tensor<1>) {
    let device = head.class_logits.device();
    let labels: Vec<i64> = targets.iter().flat_map(|t| t.labels.iter().map(|&l| l as i64)).collect();
    let k = labels.len();
    let classification = CrossEntropyLossConfig::new()
        .init(&device)
        .forward(head.class_logits.clone(), int_tensor(labels.clone(), &device));
    let deltas: Vec<[f32; 4]> = targets.iter().flat_map(|t| t.deltas.iter().copied()).collect();
    let (mut rows, mut cols, mut goal) = (Vec::new(), Vec::new(), Vec::new());
    for (r, (&l, d)) in labels.iter().zip(&deltas).enumerate() {
        if l > 0 {
            rows.push(r as i64);
            cols.extend((0..4).map(|j| 4 * l + j));
            goal.extend_from_slice(d);
        }
    }
    let box_loss = if rows.is_empty() {
        zero(&device)
    } else {
        let p = rows.len();
        let picked = head.box_deltas.clone().select(0, int_tensor(rows, &device));
        let cols = Tensor::<2, Int>::from_data(TensorData::new(cols, [p, 4]), &device);
        smooth_l1(picked.gather(1, cols), float_tensor(goal, [p, 4], &device), 1.0 / 9.0).sum().div_scalar(k as f32)
    };
    (classification, box_loss)
}

pub fn faster_rcnn_losses(
    rpn: &RpnOutput,
    rpn_targets: &[RpnTargets],
    head: Option<&HeadOutput>,
    roi_targets: &[RoiTargets],
) -> Losses {
    let (objectness, rpn_box) = rpn_losses(rpn, rpn_targets);
    let (classifier, box_loss) = match head {
        Some(head) => head_losses(head, roi_targets),
        None => (zero(&objectness.device()), zero(&objectness.device())),
    };
    Losses::new(vec![
        ("rpn_objectness", objectness),
        ("rpn_box", rpn_box),
        ("classifier", classifier),
        ("box", box_loss),
    ])
}

/// Grid losses: presence BCE averaged over all cells (positives weighted by
/// `positive_weight`, since corners fill few cells; ignored cells by 0), offset (on the squashed
/// offsets) and size smooth L1 summed over positive cells per positive.
pub fn grid_losses(out: &GridOutput, targets: &[GridTargets], positive_weight: f32) -> Losses {
    let device = out.cells.device();
    let [b, s, _, v] = out.cells.dims();
    let n = b * s * s;
    let cells = out.cells.clone().reshape([n, v]);
    let presence: Vec<f32> = targets.iter().flat_map(|t| t.presence.iter().copied()).collect();
    let ignored = targets.iter().flat_map(|t| t.ignored.iter().copied());
    let weights: Vec<f32> = presence
        .iter()
        .zip(ignored)
        .map(|(&p, ignored)| {
            if p > 0.0 {
                positive_weight
            } else if ignored {
                0.0
            } else {
                1.0
            }
        })
        .collect();
    let logits = cells.clone().slice([0..n, 0..1]).reshape([n]);
    let presence_loss = (bce_with_logits(logits, float_tensor(presence.clone(), [n], &device))
        * float_tensor(weights, [n], &device))
    .mean();
    let pos: Vec<i64> = (0..n).filter(|&i| presence[i] > 0.0).map(|i| i as i64).collect();
    if pos.is_empty() {
        return Losses::new(vec![("presence", presence_loss), ("offset", zero(&device)), ("size", zero(&device))]);
    }
    let p = pos.len();
    let offsets: Vec<f32> =
        pos.iter().flat_map(|&i| targets[i as usize / (s * s)].offsets[i as usize % (s * s)]).collect();
    let sizes: Vec<f32> =
        pos.iter().flat_map(|&i| targets[i as usize / (s * s)].log_sizes[i as usize % (s * s)]).collect();
    let picked = cells.select(0, int_tensor(pos, &device));
    let offset_loss =
        smooth_l1(sigmoid(picked.clone().slice([0..p, 1..3])), float_tensor(offsets, [p, 2], &device), 1.0 / 9.0)
            .sum()
            .div_scalar(p as f32);
    let size_loss = smooth_l1(picked.slice([0..p, 3..5]), float_tensor(sizes, [p, 2], &device), 1.0 / 9.0)
        .sum()
        .div_scalar(p as f32);
    Losses::new(vec![("presence", presence_loss), ("offset", offset_loss), ("size", size_loss)])
}
