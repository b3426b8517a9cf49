//! Anchor boxes over a feature map, as torchvision's `AnchorGenerator` lays
//! them out: for each location (row-major), for each aspect ratio, for each
//! size, a box centred on `(x * stride, y * stride)` with corners rounded half to even
//! (as `torch.round`).

use serde::{Deserialize, Serialize};

use crate::boxes::BBox;

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AnchorConfig {
    /// Side of the square anchor before the aspect ratio is applied, in input pixels.
    pub sizes: Vec<f32>,
    /// Height / width.
    pub aspect_ratios: Vec<f32>,
}

impl Default for AnchorConfig {
    fn default() -> Self {
        // Corner boxes are 96 px squares in a 640x480 image: 34 x 45 px (height
        // / width 1.33) in the 224 x 224 input.
        Self { sizes: vec![32.0, 40.0, 56.0], aspect_ratios: vec![1.0, 1.3, 1.7] }
    }
}

impl AnchorConfig {
    pub fn per_location(&self) -> usize {
        self.sizes.len() * self.aspect_ratios.len()
    }

    /// The anchors centred on the origin, in torchvision's order.
    pub fn cell_anchors(&self) -> Vec<BBox> {
        let mut out = Vec::with_capacity(self.per_location());
        for &ratio in &self.aspect_ratios {
            let h_ratio = ratio.sqrt();
            let w_ratio = 1.0 / h_ratio;
            for &size in &self.sizes {
                let (w, h) = (w_ratio * size, h_ratio * size);
                out.push(BBox::new(
                    (-w / 2.0).round_ties_even(),
                    (-h / 2.0).round_ties_even(),
                    (w / 2.0).round_ties_even(),
                    (h / 2.0).round_ties_even(),
                ));
            }
        }
        out
    }

    /// All anchors of a `grid_h x grid_w` feature map of the given stride.
    pub fn grid_anchors(&self, grid_h: usize, grid_w: usize, stride: f32) -> Vec<BBox> {
        let cell = self.cell_anchors();
        let mut out = Vec::with_capacity(grid_h * grid_w * cell.len());
        for y in 0..grid_h {
            for x in 0..grid_w {
                let (sx, sy) = (x as f32 * stride, y as f32 * stride);
                out.extend(cell.iter().map(|a| BBox::new(a.x1 + sx, a.y1 + sy, a.x2 + sx, a.y2 + sy)));
            }
        }
        out
    }
}
