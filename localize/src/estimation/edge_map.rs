//! The edge map: the edge points (`image_edges`) the run has placed in the
//! world, in a voxel hash as the point map keeps its surface points. A frame's
//! edge point registers against the line through its nearest map edge
//! points (point-to-line, as LOAM's edge features do).

use datasets::math::{Mat3, Pose3, Vec3};
use rustc_hash::FxHashMap;

/// A line through map edge points: a point on it and its unit direction.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EdgeLine {
    pub point: Vec3,
    pub direction: Vec3,
}

/// Map edge points a line is fitted to.
const LINE_POINTS: usize = 5;
/// Least ratio of the largest spread to the next: below it the neighbours
/// are a blob or a corner, not a line.
const LINE_MIN_ELONGATION: f64 = 5.0;

pub struct EdgeMap {
    voxel_m: f64,
    points_per_voxel: usize,
    min_spacing_m: f64,
    voxels: FxHashMap<[i32; 3], Vec<Vec3>>,
    len: usize,
}

impl EdgeMap {
    /// `voxel_m` > 0 and `points_per_voxel` >= 1 (checked by the settings).
    pub fn new(voxel_m: f64, points_per_voxel: usize, min_spacing_m: f64) -> Self {
        Self { voxel_m, points_per_voxel, min_spacing_m, voxels: FxHashMap::default(), len: 0 }
    }

    pub fn len(&self) -> usize {
        self.len
    }

    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    fn key(&self, p: &Vec3) -> [i32; 3] {
        crate::estimation::point_map::voxel_key(p, self.voxel_m)
    }

    /// The squared distance from `query` to the cube of voxel `key`.
    fn box_distance2(&self, key: &[i32; 3], query: &Vec3) -> f64 {
        (0..3)
            .map(|k| {
                let low = f64::from(key[k]) * self.voxel_m;
                let gap = (low - query[k]).max(query[k] - (low + self.voxel_m)).max(0.0);
                gap * gap
            })
            .sum()
    }

    /// Adds robot-frame edge points placed in the world by `pose`; a full
    /// voxel, or a point too close to one kept, is skipped.
    pub fn insert(&mut self, points: &[Vec3], pose: &Pose3) {
        let spacing2 = self.min_spacing_m * self.min_spacing_m;
        for p in points {
            let position = (pose * nalgebra::Point3::from(*p)).coords;
            let key = self.key(&position);
            let voxel = self.voxels.entry(key).or_default();
            if voxel.len() >= self.points_per_voxel || voxel.iter().any(|q| (q - position).norm_squared() < spacing2) {
                continue;
            }
            voxel.push(position);
            self.len += 1;
        }
    }

    /// The line through the `LINE_POINTS` map edge points nearest to `query`,
    /// all within `max_distance_m` (at most one voxel edge); `None` where
    /// there are fewer or they do not lie along a line.
    pub fn line_near(&self, query: &Vec3, max_distance_m: f64) -> Option<EdgeLine> {
        let [x, y, z] = self.key(query);
        let limit = max_distance_m * max_distance_m;
        // The nearest few, kept sorted by distance.
        let mut nearest: [(f64, Vec3); LINE_POINTS] = [(f64::INFINITY, Vec3::zeros()); LINE_POINTS];
        for dx in -1..=1 {
            for dy in -1..=1 {
                for dz in -1..=1 {
                    let key = [x + dx, y + dy, z + dz];
                    // A voxel wholly farther than the fifth nearest so far has nothing nearer.
                    if self.box_distance2(&key, query) > limit.min(nearest[LINE_POINTS - 1].0) {
                        continue;
                    }
                    let Some(voxel) = self.voxels.get(&key) else { continue };
                    for p in voxel {
                        let d = (p - query).norm_squared();
                        if d <= limit && d < nearest[LINE_POINTS - 1].0 {
                            nearest[LINE_POINTS - 1] = (d, *p);
                            nearest.sort_unstable_by(|a, b| a.0.total_cmp(&b.0));
                        }
                    }
                }
            }
        }
        if !nearest[LINE_POINTS - 1].0.is_finite() {
            return None;
        }
        let centroid = nearest.iter().map(|n| n.1).sum::<Vec3>() / LINE_POINTS as f64;
        let mut covariance = Mat3::zeros();
        for (_, p) in &nearest {
            let d = p - centroid;
            covariance += d * d.transpose();
        }
        let eigen = covariance.symmetric_eigen();
        let mut order = [0, 1, 2];
        order.sort_unstable_by(|&a, &b| eigen.eigenvalues[b].total_cmp(&eigen.eigenvalues[a]));
        let (largest, next) = (eigen.eigenvalues[order[0]], eigen.eigenvalues[order[1]]);
        if !(largest > 0.0 && largest >= LINE_MIN_ELONGATION * next) {
            return None;
        }
        Some(EdgeLine { point: centroid, direction: eigen.eigenvectors.column(order[0]).into_owned() })
    }

    /// Every map edge point, in no particular order.
    pub fn points(&self) -> impl Iterator<Item = &Vec3> {
        self.voxels.values().flatten()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_line_is_found_along_an_edge_and_not_at_a_blob() {
        let mut map = EdgeMap::new(0.2, 40, 0.005);
        // A box edge along y at x = 1, z = 0.5, 1 cm apart, placed by a pose 90 degrees about z.
        let edge: Vec<Vec3> = (0..60).map(|k| Vec3::new(1.0, -0.3 + 0.01 * k as f64, 0.5)).collect();
        let pose = Pose3::new(Vec3::new(0.5, 0.0, 0.0), Vec3::new(0.0, 0.0, std::f64::consts::FRAC_PI_2));
        map.insert(&edge, &pose);
        assert_eq!(map.len(), 60);
        // In the world the edge runs along x at y = 1, z = 0.5.
        let line = map.line_near(&Vec3::new(0.6, 1.03, 0.52), 0.1).unwrap();
        assert!(line.direction.x.abs() > 0.999, "{:?}", line.direction);
        assert!((line.point.y - 1.0).abs() < 1e-9 && (line.point.z - 0.5).abs() < 1e-9);
        assert!(map.line_near(&Vec3::new(0.6, 1.5, 0.5), 0.1).is_none(), "farther than the gate");
        // A square blob of points is no line.
        let blob: Vec<Vec3> =
            (0..36).map(|k| Vec3::new(3.0 + 0.01 * (k % 6) as f64, 0.01 * (k / 6) as f64, 0.0)).collect();
        map.insert(&blob, &Pose3::identity());
        assert!(map.line_near(&Vec3::new(3.02, 0.02, 0.0), 0.1).is_none());
        // Points closer than the spacing add nothing.
        map.insert(&[Vec3::new(3.001, 0.0, 0.0)], &Pose3::identity());
        assert_eq!(map.len(), 96);
    }
}
