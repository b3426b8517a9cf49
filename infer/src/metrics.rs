//! Detection quality: AP at IoU 0.5 (all-point interpolated, as PASCAL VOC
//! since 2010), precision and recall at an operating score, and the mean
//! distance between a found corner and the true one.

use serde::{Deserialize, Serialize};

use crate::boxes::{BBox, iou};
use crate::network::Detection;

/// A labeled corner: its box and exact point, in image pixels.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TruthCorner {
    pub bbox: BBox,
    pub point: [f32; 2],
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EvalMetrics {
    pub ap50: f64,
    pub precision: f64,
    pub recall: f64,
    /// Mean distance (image pixels) from a true-positive box's centre to its
    /// corner; `None` when nothing was found.
    pub mean_pixel_error: Option<f64>,
    pub images: usize,
    pub ground_truths: usize,
    pub detections: usize,
    /// Score at and above which detections count for precision, recall and pixel error.
    pub operating_score: f32,
}

pub const IOU_THRESHOLD: f32 = 0.5;

/// Evaluates detections against the truth, image by image (same order).
pub fn evaluate(predictions: &[Vec<Detection>], truth: &[Vec<TruthCorner>], operating_score: f32) -> EvalMetrics {
    evaluate_ignoring(predictions, truth, &vec![Vec::new(); truth.len()], operating_score)
}

/// As `evaluate`, but a detection that matches no true corner and covers an
/// ignore region of its image (IoU >= 0.5, as COCO's crowd regions) counts
/// neither as found nor as false.
pub fn evaluate_ignoring(
    predictions: &[Vec<Detection>],
    truth: &[Vec<TruthCorner>],
    ignore: &[Vec<BBox>],
    operating_score: f32,
) -> EvalMetrics {
    assert_eq!(predictions.len(), truth.len(), "one prediction list per image");
    assert_eq!(ignore.len(), truth.len(), "one ignore list per image");
    let total_truth: usize = truth.iter().map(Vec::len).sum();
    let mut all: Vec<(f32, usize, usize)> = Vec::new();
    for (img, dets) in predictions.iter().enumerate() {
        all.extend(dets.iter().enumerate().map(|(k, d)| (d.score, img, k)));
    }
    all.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)).then(a.2.cmp(&b.2)));
    let mut matched: Vec<Vec<bool>> = truth.iter().map(|t| vec![false; t.len()]).collect();
    let (mut tp, mut fp) = (0usize, 0usize);
    let mut curve = Vec::with_capacity(all.len());
    let (mut op_tp, mut op_fp, mut errors) = (0usize, 0usize, Vec::new());
    for &(score, img, k) in &all {
        let det = &predictions[img][k];
        let best = truth[img]
            .iter()
            .enumerate()
            .filter(|(j, _)| !matched[img][*j])
            .map(|(j, t)| (j, iou(&det.bbox, &t.bbox)))
            .max_by(|a, b| a.1.total_cmp(&b.1));
        let hit = match best {
            Some((j, overlap)) if overlap >= IOU_THRESHOLD => {
                matched[img][j] = true;
                Some(j)
            }
            _ => None,
        };
        match hit {
            Some(j) => {
                tp += 1;
                if score >= operating_score {
                    op_tp += 1;
                    let [cx, cy] = det.bbox.centre();
                    let [px, py] = truth[img][j].point;
                    errors.push(((cx - px).powi(2) + (cy - py).powi(2)).sqrt() as f64);
                }
            }
            None if ignore[img].iter().any(|r| iou(&det.bbox, r) >= IOU_THRESHOLD) => continue,
            None => {
                fp += 1;
                if score >= operating_score {
                    op_fp += 1;
                }
            }
        }
        curve.push((tp as f64 / total_truth.max(1) as f64, tp as f64 / (tp + fp) as f64));
    }
    EvalMetrics {
        ap50: average_precision(&curve),
        precision: if op_tp + op_fp > 0 { op_tp as f64 / (op_tp + op_fp) as f64 } else { 0.0 },
        recall: if total_truth > 0 { op_tp as f64 / total_truth as f64 } else { 0.0 },
        mean_pixel_error: (!errors.is_empty()).then(|| errors.iter().sum::<f64>() / errors.len() as f64),
        images: predictions.len(),
        ground_truths: total_truth,
        detections: all.len(),
        operating_score,
    }
}

/// Area under the precision envelope of a (recall, precision) curve ordered by
/// decreasing score.
pub fn average_precision(curve: &[(f64, f64)]) -> f64 {
    let mut recall = vec![0.0];
    let mut precision = vec![0.0];
    for &(r, p) in curve {
        recall.push(r);
        precision.push(p);
    }
    recall.push(1.0);
    precision.push(0.0);
    for i in (0..precision.len() - 1).rev() {
        precision[i] = precision[i].max(precision[i + 1]);
    }
    (1..recall.len()).map(|i| (recall[i] - recall[i - 1]) * precision[i]).sum()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn det(x: f32, score: f32) -> Detection {
        Detection { bbox: BBox::new(x, 0.0, x + 10.0, 10.0), score, class: 0 }
    }
    fn truth(x: f32) -> TruthCorner {
        TruthCorner { bbox: BBox::new(x, 0.0, x + 10.0, 10.0), point: [x + 5.0, 5.0] }
    }

    #[test]
    fn hand_computed_ap_precision_recall() {
        // Image 0: two corners; detections: a hit (0.9), a miss (0.8), a hit shifted by 1 px (0.6).
        // Image 1: one corner, never found; one false detection (0.7).
        let predictions = vec![vec![det(0.0, 0.9), det(100.0, 0.8), det(51.0, 0.6)], vec![det(200.0, 0.7)]];
        let truths = vec![vec![truth(0.0), truth(50.0)], vec![truth(20.0)]];
        let m = evaluate(&predictions, &truths, 0.5);
        // Ranked: TP (r 1/3, p 1), FP (1/3, 1/2), FP (1/3, 1/3), TP (2/3, 1/2).
        // Envelope: p = 1 up to r = 1/3, then 1/2 up to 2/3: AP = 1/3 + 1/6 = 1/2.
        assert!((m.ap50 - 0.5).abs() < 1e-12, "{}", m.ap50);
        assert!((m.precision - 0.5).abs() < 1e-12 && (m.recall - 2.0 / 3.0).abs() < 1e-12);
        assert!((m.mean_pixel_error.unwrap() - 0.5).abs() < 1e-6, "{:?}", m.mean_pixel_error);
        // Perfect detections: AP 1.
        let m = evaluate(&[vec![det(0.0, 0.9)]], &[vec![truth(0.0)]], 0.5);
        assert_eq!((m.ap50, m.precision, m.recall, m.mean_pixel_error), (1.0, 1.0, 1.0, Some(0.0)));
    }

    #[test]
    fn detections_in_ignore_regions_count_neither_way() {
        // The false detections at 100 (0.8) and 200 (0.7) fall in ignore regions:
        // ranked TP, TP left, the miss of image 1 still missed: AP 2/3.
        let predictions = vec![vec![det(0.0, 0.9), det(100.0, 0.8), det(51.0, 0.6)], vec![det(200.0, 0.7)]];
        let truths = vec![vec![truth(0.0), truth(50.0)], vec![truth(20.0)]];
        let ignore = vec![vec![BBox::new(101.0, 0.0, 111.0, 10.0)], vec![BBox::new(200.0, 0.0, 210.0, 10.0)]];
        let m = evaluate_ignoring(&predictions, &truths, &ignore, 0.5);
        assert!((m.ap50 - 2.0 / 3.0).abs() < 1e-12, "{}", m.ap50);
        assert_eq!(m.precision, 1.0);
        // A region the detection barely touches (IoU < 0.5) does not excuse it.
        let far = vec![vec![BBox::new(106.0, 0.0, 116.0, 10.0)], vec![]];
        let m = evaluate_ignoring(&predictions, &truths, &far, 0.5);
        assert_eq!(m.precision, 0.5);
        // An ignore region does not take a true corner's match.
        let over_truth = vec![vec![BBox::new(0.0, 0.0, 10.0, 10.0)], vec![]];
        let m = evaluate_ignoring(&predictions, &truths, &over_truth, 0.5);
        assert_eq!(m.recall, 2.0 / 3.0);
    }
}
