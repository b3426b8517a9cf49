//! One training (or validation) step's loss: batch assembly with optional
//! horizontal flips, target assignment and the network's losses.

use burn::prelude::*;
use rand::rngs::ChaCha8Rng;

use crate::losses::{Losses, faster_rcnn_losses, grid_losses};
use crate::targets::{grid_targets, roi_targets, rpn_targets};
use datasets::preprocess::NetInput;
use infer::boxes::BBox;
use infer::config::DetectorConfig;
use infer::detector::input_tensor;
use infer::faster_rcnn;
use infer::labeled::LabeledImage;
use infer::network::Network;

/// Network inputs with their ground-truth boxes in input pixels.
pub struct Batch {
    /// Images `[B, C, S, S]` when `start` is 0, else the cached output of
    /// the first `start` (frozen) trunk convolutions.
    pub inputs: Tensor<4>,
    pub start: usize,
    pub boxes: Vec<Vec<BBox>>,
    /// Each image's ignore regions, in input pixels.
    pub ignore: Vec<Vec<BBox>>,
}

/// Stacks images (flipped left-right where `flips` says so) into a batch.
pub fn make_batch(images: &[&LabeledImage], flips: &[bool], size: u32, device: &Device) -> Batch {
    Batch {
        inputs: batch_inputs(images, flips, device),
        start: 0,
        boxes: batch_boxes(images, flips, size),
        ignore: batch_ignore(images, flips, size),
    }
}

/// The images' network inputs as a `[B, C, S, S]` tensor, mirrored where flipped.
pub fn batch_inputs(images: &[&LabeledImage], flips: &[bool], device: &Device) -> Tensor<4> {
    let inputs: Vec<_> = images
        .iter()
        .zip(flips)
        .map(|(im, &flip)| if flip { im.input.flip_horizontal() } else { im.input.clone() })
        .collect();
    input_tensor(&inputs, device)
}

/// The images' boxes in input pixels, mirrored where flipped.
pub fn batch_boxes(images: &[&LabeledImage], flips: &[bool], size: u32) -> Vec<Vec<BBox>> {
    mirrored(images.iter().map(|im| im.net_boxes(size)), flips, size)
}

/// The images' ignore regions in input pixels, mirrored where flipped.
pub fn batch_ignore(images: &[&LabeledImage], flips: &[bool], size: u32) -> Vec<Vec<BBox>> {
    mirrored(images.iter().map(|im| im.net_ignore(size)), flips, size)
}

fn mirrored(boxes: impl Iterator<Item = Vec<BBox>>, flips: &[bool], size: u32) -> Vec<Vec<BBox>> {
    let s = size as f32;
    boxes
        .zip(flips)
        .map(|(b, &flip)| if flip { b.iter().map(|b| BBox::new(s - b.x2, b.y1, s - b.x1, b.y2)).collect() } else { b })
        .collect()
}

/// Weight of a positive cell in the grid heads' presence loss.
pub const GRID_POSITIVE_WEIGHT: f32 = 5.0;

/// The loss of `network` on `batch`; `rng` drives the anchor and RoI sampling.
pub fn batch_losses(network: &Network, config: &DetectorConfig, batch: &Batch, rng: &mut ChaCha8Rng) -> Losses {
    let size = config.input_size() as f32;
    match network {
        Network::FasterRcnn(m) => {
            let features = m.trunk_from(batch.inputs.clone(), batch.start);
            let rpn = m.rpn(features.clone());
            let [b, n] = rpn.objectness.dims();
            let anchors = faster_rcnn::anchors_for(&config.anchors, rpn.grid_h, rpn.grid_w);
            let rpn_t: Vec<_> = batch
                .boxes
                .iter()
                .zip(&batch.ignore)
                .map(|(truth, ignore)| rpn_targets(&anchors, truth, ignore, &config.rpn, rng))
                .collect();
            let objectness = infer::host(rpn.objectness.clone());
            let deltas = infer::host(rpn.deltas.clone());
            let settings = config.rpn.proposals(true);
            let roi_t: Vec<_> = (0..b)
                .map(|i| {
                    let proposals = faster_rcnn::proposals(
                        &objectness[i * n..(i + 1) * n],
                        &deltas[i * n * 4..(i + 1) * n * 4],
                        &anchors,
                        size,
                        settings,
                    );
                    let classes = vec![0; batch.boxes[i].len()];
                    roi_targets(&proposals, &batch.boxes[i], &classes, &batch.ignore[i], &config.roi, rng)
                })
                .collect();
            let rois: Vec<Vec<BBox>> = roi_t.iter().map(|t| t.rois.clone()).collect();
            // A batch without corners and without proposals has no RoIs: no head loss then.
            let head = rois.iter().any(|r| !r.is_empty()).then(|| m.head(features, &rois));
            faster_rcnn_losses(&rpn, &rpn_t, head.as_ref(), &roi_t)
        }
        Network::Grid(m) => {
            let out = m.head(m.trunk_from(batch.inputs.clone(), batch.start));
            let targets: Vec<_> = batch
                .boxes
                .iter()
                .zip(&batch.ignore)
                .map(|(truth, ignore)| grid_targets(truth, ignore, config.grid_cells, size))
                .collect();
            grid_losses(&out, &targets, GRID_POSITIVE_WEIGHT)
        }
    }
}

/// A synthetic batch (benchmarks, backend comparisons): edge maps of a
/// diagonal pattern with six boxes each (every channel alike), the same on
/// every device.
pub fn synthetic_batch(config: &DetectorConfig, batch: usize, device: &Device) -> Batch {
    let size = config.preprocess.size;
    let inputs: Vec<NetInput> = (0..batch)
        .map(|i| {
            let plane = image::GrayImage::from_fn(size, size, |x, y| {
                if (x * 7 + y * 13 + i as u32 * 31).is_multiple_of(17) { image::Luma([255]) } else { image::Luma([0]) }
            });
            NetInput { planes: vec![plane; config.in_channels] }
        })
        .collect();
    let boxes: Vec<Vec<BBox>> = (0..batch)
        .map(|i| {
            (0..6)
                .map(|k| {
                    let (x, y) = (20.0 + 30.0 * k as f32, 30.0 + 20.0 * ((i + k) % 7) as f32);
                    BBox::new(x, y, x + 17.0, y + 22.0)
                })
                .collect()
        })
        .collect();
    Batch { inputs: input_tensor(&inputs, device), start: 0, ignore: vec![Vec::new(); boxes.len()], boxes }
}
