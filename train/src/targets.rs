//! Training targets, on the host: torchvision's `Matcher` (IoU thresholds,
//! optional low-quality matches) and `BalancedPositiveNegativeSampler`, the
//! RPN's anchor labels, the box head's proposal labels, and the grid heads'
//! cell targets.

use infer::boxes::{BBox, BoxCoder, box_iou};
use rand::RngExt;
use rand::rngs::ChaCha8Rng;
use rand::seq::SliceRandom;

/// What each candidate box (anchor or proposal) was matched to.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Match {
    /// The index of a ground-truth box.
    Object(usize),
    Background,
    /// Between the thresholds: neither positive nor negative.
    Ignore,
}

/// Matches `candidates` to `truth`: IoU >= `fg` is a match, < `bg` is
/// background, between is ignored; with `low_quality`, each ground truth
/// also claims the candidates of its highest IoU (as the RPN does).
pub fn match_boxes(candidates: &[BBox], truth: &[BBox], fg: f32, bg: f32, low_quality: bool) -> Vec<Match> {
    if truth.is_empty() {
        return vec![Match::Background; candidates.len()];
    }
    let iou = box_iou(truth, candidates); // [G][N]
    let mut matches: Vec<Match> = (0..candidates.len())
        .map(|n| {
            let (best_g, best) =
                (0..truth.len()).map(|g| (g, iou[g][n])).fold((0, f32::MIN), |a, b| if b.1 > a.1 { b } else { a });
            if best >= fg {
                Match::Object(best_g)
            } else if best < bg {
                Match::Background
            } else {
                Match::Ignore
            }
        })
        .collect();
    if low_quality {
        for row in &iou {
            let top = row.iter().cloned().fold(f32::MIN, f32::max);
            if top <= 0.0 {
                continue;
            }
            for (n, &v) in row.iter().enumerate() {
                if v == top {
                    // Like torchvision, the candidate keeps its own best ground truth.
                    let best_g = (0..truth.len())
                        .map(|g| (g, iou[g][n]))
                        .fold((0, f32::MIN), |a, b| if b.1 > a.1 { b } else { a })
                        .0;
                    matches[n] = Match::Object(best_g);
                }
            }
        }
    }
    matches
}

/// Background candidates that would match an ignore region as they would a
/// ground truth (IoU >= `bg`) become `Ignore`: an unlabelled corner may lie there.
pub fn ignore_regions(matches: &mut [Match], candidates: &[BBox], ignore: &[BBox], bg: f32) {
    if ignore.is_empty() {
        return;
    }
    for (m, c) in matches.iter_mut().zip(candidates) {
        if *m == Match::Background && ignore.iter().any(|r| infer::boxes::iou(c, r) >= bg) {
            *m = Match::Ignore;
        }
    }
}

/// Picks at most `batch` candidates, at most `fraction` of them positive,
/// at random: returns (positives, negatives).
pub fn sample(matches: &[Match], batch: usize, fraction: f32, rng: &mut ChaCha8Rng) -> (Vec<usize>, Vec<usize>) {
    let mut pos: Vec<usize> = (0..matches.len()).filter(|&i| matches!(matches[i], Match::Object(_))).collect();
    let mut neg: Vec<usize> = (0..matches.len()).filter(|&i| matches[i] == Match::Background).collect();
    let n_pos = pos.len().min((batch as f32 * fraction) as usize);
    let n_neg = neg.len().min(batch - n_pos);
    pos.shuffle(rng);
    neg.shuffle(rng);
    pos.truncate(n_pos);
    neg.truncate(n_neg);
    (pos, neg)
}

/// The RPN's sampled anchors of one image.
#[derive(Debug, Clone, Default)]
pub struct RpnTargets {
    /// Sampled anchor indices and their labels (1 object, 0 background).
    pub sampled: Vec<(usize, f32)>,
    /// Positive anchors with their regression targets.
    pub positives: Vec<(usize, [f32; 4])>,
}

pub fn rpn_targets(
    anchors: &[BBox],
    truth: &[BBox],
    ignore: &[BBox],
    config: &infer::config::RpnConfig,
    rng: &mut ChaCha8Rng,
) -> RpnTargets {
    let mut matches = match_boxes(anchors, truth, config.fg_iou, config.bg_iou, true);
    ignore_regions(&mut matches, anchors, ignore, config.bg_iou);
    let (pos, neg) = sample(&matches, config.batch_size_per_image, config.positive_fraction, rng);
    let coder = BoxCoder::new([1.0; 4]);
    let positives = pos
        .iter()
        .map(|&i| {
            let Match::Object(g) = matches[i] else { unreachable!("positives are matched") };
            (i, coder.encode(&anchors[i], &truth[g]))
        })
        .collect();
    let sampled = pos.iter().map(|&i| (i, 1.0)).chain(neg.iter().map(|&i| (i, 0.0))).collect();
    RpnTargets { sampled, positives }
}

/// The box head's sampled RoIs of one image.
#[derive(Debug, Clone, Default)]
pub struct RoiTargets {
    pub rois: Vec<BBox>,
    /// Class per RoI: 0 background, `c + 1` for foreground class `c`.
    pub labels: Vec<usize>,
    /// Regression targets of the foreground RoIs (zeros for background).
    pub deltas: Vec<[f32; 4]>,
}

/// Adds the ground truth to the proposals, matches, samples, encodes.
pub fn roi_targets(
    proposals: &[BBox],
    truth: &[BBox],
    truth_classes: &[usize],
    ignore: &[BBox],
    config: &infer::config::RoiConfig,
    rng: &mut ChaCha8Rng,
) -> RoiTargets {
    let mut candidates = proposals.to_vec();
    candidates.extend_from_slice(truth);
    let mut matches = match_boxes(&candidates, truth, config.fg_iou, config.bg_iou, false);
    ignore_regions(&mut matches, &candidates, ignore, config.bg_iou);
    let (pos, neg) = sample(&matches, config.batch_size_per_image, config.positive_fraction, rng);
    let coder = BoxCoder::new(config.box_weights);
    let mut t = RoiTargets::default();
    for &i in pos.iter().chain(&neg) {
        t.rois.push(candidates[i]);
        match matches[i] {
            Match::Object(g) => {
                t.labels.push(truth_classes[g] + 1);
                t.deltas.push(coder.encode(&candidates[i], &truth[g]));
            }
            _ => {
                t.labels.push(0);
                t.deltas.push([0.0; 4]);
            }
        }
    }
    t
}

/// Cell targets of a grid head: presence, in-cell offset and log size of the
/// corner whose centre falls in each cell (the first, if two do); a cell
/// holding an ignore region's centre and no corner is left out of the loss.
#[derive(Debug, Clone)]
pub struct GridTargets {
    pub presence: Vec<f32>,
    pub ignored: Vec<bool>,
    pub offsets: Vec<[f32; 2]>,
    pub log_sizes: Vec<[f32; 2]>,
}

pub fn grid_targets(truth: &[BBox], ignore: &[BBox], cells: usize, input_size: f32) -> GridTargets {
    let n = cells * cells;
    let cell = input_size / cells as f32;
    let mut t = GridTargets {
        presence: vec![0.0; n],
        ignored: vec![false; n],
        offsets: vec![[0.0; 2]; n],
        log_sizes: vec![[0.0; 2]; n],
    };
    let cell_of = |b: &BBox| {
        let [cx, cy] = b.centre();
        let (col, row) = ((cx / cell).floor(), (cy / cell).floor());
        let inside = col >= 0.0 && row >= 0.0 && col < cells as f32 && row < cells as f32;
        inside.then(|| (row as usize * cells + col as usize, [cx / cell - col, cy / cell - row]))
    };
    for b in ignore {
        if let Some((k, _)) = cell_of(b) {
            t.ignored[k] = true;
        }
    }
    for b in truth {
        let Some((k, offset)) = cell_of(b) else { continue };
        t.ignored[k] = false;
        if t.presence[k] > 0.0 {
            continue;
        }
        t.presence[k] = 1.0;
        t.offsets[k] = offset;
        t.log_sizes[k] = [(b.width().max(1.0) / cell).ln(), (b.height().max(1.0) / cell).ln()];
    }
    t
}

/// A fair coin toss, for augmentation decisions.
pub fn coin(rng: &mut ChaCha8Rng) -> bool {
    rng.random_bool(0.5)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    #[test]
    fn candidates_on_an_ignore_region_are_neither_positive_nor_negative() {
        let truth = [BBox::new(0.0, 0.0, 10.0, 10.0)];
        let ignore = [BBox::new(100.0, 0.0, 110.0, 10.0)];
        let candidates = [
            BBox::new(0.0, 0.0, 10.0, 10.0),    // the truth: positive
            BBox::new(101.0, 0.0, 111.0, 10.0), // IoU 0.82 with the region
            BBox::new(104.0, 0.0, 114.0, 10.0), // IoU 0.43: between the thresholds
            BBox::new(107.0, 0.0, 117.0, 10.0), // IoU 0.18: background still
            BBox::new(200.0, 0.0, 210.0, 10.0), // far from both
        ];
        let mut m = match_boxes(&candidates, &truth, 0.7, 0.3, false);
        assert_eq!(m, [Match::Object(0), Match::Background, Match::Background, Match::Background, Match::Background]);
        ignore_regions(&mut m, &candidates, &ignore, 0.3);
        assert_eq!(m, [Match::Object(0), Match::Ignore, Match::Ignore, Match::Background, Match::Background]);
        // Sampling never draws an ignored candidate.
        let (pos, neg) = sample(&m, 10, 0.5, &mut ChaCha8Rng::seed_from_u64(1));
        assert_eq!(pos, [0]);
        let mut neg = neg;
        neg.sort();
        assert_eq!(neg, [3, 4]);
        // A region never takes a truth's match away.
        let mut m = match_boxes(&candidates, &truth, 0.7, 0.3, false);
        ignore_regions(&mut m, &candidates, &truth, 0.3);
        assert_eq!(m[0], Match::Object(0));
    }

    #[test]
    fn a_grid_cell_with_an_ignore_region_and_no_corner_is_left_out() {
        // 4 x 4 cells of 8 px: a corner centred in cell (0, 0), a region in
        // cell (1, 2) and one on the corner's cell.
        let truth = [BBox::new(2.0, 2.0, 6.0, 6.0)];
        let ignore = [BBox::new(18.0, 10.0, 22.0, 14.0), BBox::new(1.0, 1.0, 5.0, 5.0)];
        let t = grid_targets(&truth, &ignore, 4, 32.0);
        assert_eq!(t.presence[0], 1.0);
        assert!(!t.ignored[0], "a corner's cell is taught");
        assert!(t.ignored[4 + 2]);
        assert_eq!(t.ignored.iter().filter(|&&i| i).count(), 1);
        assert_eq!(t.offsets[0], [0.5, 0.5]);
    }
}
