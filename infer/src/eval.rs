//! Evaluation of a detector on a labeled set.

use crate::detector::Detector;
use crate::labeled::LabeledImage;
use crate::metrics::{EvalMetrics, evaluate_ignoring};
use crate::network::Detection;

/// Score at and above which a detection counts as found (precision, recall, pixel error).
pub const OPERATING_SCORE: f32 = 0.5;

/// Runs the detector over `set` in batches and scores it in image pixels.
pub fn evaluate_set(detector: &Detector, set: &[LabeledImage], batch: usize) -> EvalMetrics {
    let size = detector.config.preprocess.size;
    let mut predictions: Vec<Vec<Detection>> = Vec::with_capacity(set.len());
    for chunk in set.chunks(batch.max(1)) {
        let inputs: Vec<_> = chunk.iter().map(|im| im.input.clone()).collect();
        for (dets, im) in detector.detect_inputs(&inputs).into_iter().zip(chunk) {
            let map = im.to_net(size);
            predictions.push(dets.into_iter().map(|d| Detection { bbox: map.to_image(&d.bbox), ..d }).collect());
        }
    }
    let truth: Vec<_> = set.iter().map(|im| im.truth.clone()).collect();
    let ignore: Vec<_> = set.iter().map(|im| im.ignore.clone()).collect();
    evaluate_ignoring(&predictions, &truth, &ignore, OPERATING_SCORE)
}
