//! Detections scored against point labels on photographs (York Urban's
//! junctions, or any folder of `NAME.csv` files beside `NAME.jpg`): what
//! share of the points a method gives lie within a radius of a labelled
//! point (precision), and what share of the labelled points have one
//! within that radius (recall). Not one-to-one: a detector that fires
//! twice on one junction scores both, as the radius-based measures of
//! corner detectors do.

use image::DynamicImage;

use crate::corner_response::{CornerResponse, strongest_corners};
use crate::detector::Detector;

/// The methods scored side by side: the detector, then Shi-Tomasi, Harris
/// and random points at the detector's count on each photo.
pub const METHODS: [&str; 4] = ["detector", "shi-tomasi", "harris", "random"];

/// Each method's points on one photo scored against its labels (in the
/// order of `METHODS`): the corner responses at least `radius` apart, the
/// random points from a generator seeded by the photo's place `index`.
pub fn score_photo(
    detector: &Detector,
    image: &DynamicImage,
    labels: &[[f32; 2]],
    radius: f32,
    index: usize,
) -> [PointScores; 4] {
    let (w, h) = (image.width() as f32, image.height() as f32);
    let detected: Vec<[f32; 2]> =
        detector.detect(image).iter().map(|d| [(d.bbox.x1 + d.bbox.x2) / 2.0, (d.bbox.y1 + d.bbox.y2) / 2.0]).collect();
    let count = detected.len();
    let gray = image.to_luma8();
    let mut state = 0x9E37_79B9_7F4A_7C15u64 ^ index as u64;
    let mut uniform = || {
        state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        (state >> 40) as f32 / (1u64 << 24) as f32
    };
    let random: Vec<[f32; 2]> = (0..count).map(|_| [uniform() * w, uniform() * h]).collect();
    [
        detected,
        strongest_corners(&gray, CornerResponse::ShiTomasi, count, radius, 3),
        strongest_corners(&gray, CornerResponse::Harris, count, radius, 3),
        random,
    ]
    .map(|points| PointScores::of(&points, labels, radius))
}

/// Counts over one image or summed over many.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct PointScores {
    /// Points the method gave, and labelled points.
    pub points: usize,
    pub labels: usize,
    /// Points within the radius of some label.
    pub hits: usize,
    /// Labels with some point within the radius.
    pub found: usize,
}

impl PointScores {
    pub fn of(points: &[[f32; 2]], labels: &[[f32; 2]], radius: f32) -> Self {
        let near = |a: &[f32; 2], b: &[f32; 2]| (a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) <= radius * radius;
        Self {
            points: points.len(),
            labels: labels.len(),
            hits: points.iter().filter(|p| labels.iter().any(|l| near(p, l))).count(),
            found: labels.iter().filter(|l| points.iter().any(|p| near(p, l))).count(),
        }
    }

    pub fn add(&mut self, other: &Self) {
        self.points += other.points;
        self.labels += other.labels;
        self.hits += other.hits;
        self.found += other.found;
    }

    /// `None` without points.
    pub fn precision(&self) -> Option<f64> {
        (self.points > 0).then(|| self.hits as f64 / self.points as f64)
    }

    /// `None` without labels.
    pub fn recall(&self) -> Option<f64> {
        (self.labels > 0).then(|| self.found as f64 / self.labels as f64)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn precision_and_recall_count_within_the_radius() {
        let labels = [[10.0, 10.0], [50.0, 50.0], [90.0, 10.0]];
        // Two on the first label (both count), one 12 px from the second
        // (in at 12, out at 11.9), one far from all.
        let points = [[11.0, 10.0], [9.0, 11.0], [50.0, 62.0], [200.0, 200.0]];
        let at12 = PointScores::of(&points, &labels, 12.0);
        assert_eq!(at12, PointScores { points: 4, labels: 3, hits: 3, found: 2 });
        assert_eq!(at12.precision(), Some(0.75));
        assert_eq!(at12.recall(), Some(2.0 / 3.0));
        let tighter = PointScores::of(&points, &labels, 11.9);
        assert_eq!((tighter.hits, tighter.found), (2, 1));
        let mut sum = at12;
        sum.add(&PointScores::of(&[], &labels, 12.0));
        assert_eq!((sum.points, sum.labels, sum.precision(), sum.recall()), (4, 6, Some(0.75), Some(2.0 / 6.0)));
        assert_eq!(PointScores::of(&[], &[], 12.0).precision(), None);
    }
}
