//! Box operations on plain vectors, following torchvision's definitions
//! (`torchvision.ops.box_iou`, `nms`, `batched_nms`, `clip_boxes_to_image`,
//! `remove_small_boxes`, and `models.detection._utils.BoxCoder`): boxes are
//! `x1 y1 x2 y2` in continuous coordinates, area is `(x2-x1)*(y2-y1)`.

pub use datasets::bbox::BBox;

/// Intersection over union of every pair: `iou[i][j]` for `a[i]`, `b[j]`.
pub fn box_iou(a: &[BBox], b: &[BBox]) -> Vec<Vec<f32>> {
    a.iter().map(|p| b.iter().map(|q| iou(p, q)).collect()).collect()
}

pub fn iou(p: &BBox, q: &BBox) -> f32 {
    let w = (p.x2.min(q.x2) - p.x1.max(q.x1)).max(0.0);
    let h = (p.y2.min(q.y2) - p.y1.max(q.y1)).max(0.0);
    let inter = w * h;
    let union = p.area() + q.area() - inter;
    if union > 0.0 { inter / union } else { 0.0 }
}

/// Greedy non-maximum suppression: indices of the kept boxes, by
/// decreasing score. Ties keep the lower index first.
pub fn nms(boxes: &[BBox], scores: &[f32], iou_threshold: f32) -> Vec<usize> {
    let mut order: Vec<usize> = (0..boxes.len()).collect();
    order.sort_by(|&a, &b| scores[b].total_cmp(&scores[a]).then(a.cmp(&b)));
    let mut suppressed = vec![false; boxes.len()];
    let mut keep = Vec::new();
    for (k, &i) in order.iter().enumerate() {
        if suppressed[i] {
            continue;
        }
        keep.push(i);
        for &j in &order[k + 1..] {
            if !suppressed[j] && iou(&boxes[i], &boxes[j]) > iou_threshold {
                suppressed[j] = true;
            }
        }
    }
    keep
}

/// NMS within each class only (torchvision's `batched_nms`): indices of the
/// kept boxes by decreasing score.
pub fn batched_nms(boxes: &[BBox], scores: &[f32], classes: &[usize], iou_threshold: f32) -> Vec<usize> {
    let mut keep = Vec::new();
    let mut labels: Vec<usize> = classes.to_vec();
    labels.sort_unstable();
    labels.dedup();
    for c in labels {
        let members: Vec<usize> = (0..boxes.len()).filter(|&i| classes[i] == c).collect();
        let b: Vec<BBox> = members.iter().map(|&i| boxes[i]).collect();
        let s: Vec<f32> = members.iter().map(|&i| scores[i]).collect();
        keep.extend(nms(&b, &s, iou_threshold).into_iter().map(|k| members[k]));
    }
    keep.sort_by(|&a, &b| scores[b].total_cmp(&scores[a]).then(a.cmp(&b)));
    keep
}

/// Indices of the boxes at least `min_size` wide and high.
pub fn remove_small(boxes: &[BBox], min_size: f32) -> Vec<usize> {
    (0..boxes.len()).filter(|&i| boxes[i].width() >= min_size && boxes[i].height() >= min_size).collect()
}

/// Box regression coding relative to reference boxes (anchors or proposals),
/// with torchvision's weights and its clamp of the size deltas.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BoxCoder {
    pub weights: [f32; 4],
    /// Largest `dw`, `dh` decoded: ln(1000 / 16), so boxes cannot explode.
    pub clip: f32,
}

impl BoxCoder {
    pub fn new(weights: [f32; 4]) -> Self {
        Self { weights, clip: (1000.0f32 / 16.0).ln() }
    }

    /// The deltas `(dx, dy, dw, dh)` that turn `reference` into `target`.
    pub fn encode(&self, reference: &BBox, target: &BBox) -> [f32; 4] {
        let [wx, wy, ww, wh] = self.weights;
        let (rw, rh) = (reference.width(), reference.height());
        let (rx, ry) = (reference.x1 + 0.5 * rw, reference.y1 + 0.5 * rh);
        let (tw, th) = (target.width(), target.height());
        let (tx, ty) = (target.x1 + 0.5 * tw, target.y1 + 0.5 * th);
        [wx * (tx - rx) / rw, wy * (ty - ry) / rh, ww * (tw / rw).ln(), wh * (th / rh).ln()]
    }

    /// Applies `deltas` to `reference`.
    pub fn decode(&self, reference: &BBox, deltas: [f32; 4]) -> BBox {
        let [wx, wy, ww, wh] = self.weights;
        let (rw, rh) = (reference.width(), reference.height());
        let (rx, ry) = (reference.x1 + 0.5 * rw, reference.y1 + 0.5 * rh);
        let (dx, dy) = (deltas[0] / wx, deltas[1] / wy);
        let (dw, dh) = ((deltas[2] / ww).min(self.clip), (deltas[3] / wh).min(self.clip));
        let (cx, cy) = (dx * rw + rx, dy * rh + ry);
        let (w, h) = (dw.exp() * rw, dh.exp() * rh);
        BBox::new(cx - 0.5 * w, cy - 0.5 * h, cx + 0.5 * w, cy + 0.5 * h)
    }
}
