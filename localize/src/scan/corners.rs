//! 3D corners where three planes meet (a 3 x 3 solve, kept only where all
//! three planes have points near the solution) and edge lines where two
//! planes meet at a shallow angle (a ramp and the floor).

use datasets::InvalidSetting;
use datasets::math::{Mat3, Vec3};
use nalgebra::Point3;
use serde::{Deserialize, Serialize};

use crate::error::Result;
use crate::scan::planes::{Plane, PlaneSet};
use crate::scan::scan_grid::ScanGrid;

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CornerConfig {
    /// Smallest |det| of the three unit normals: 1 for mutually perpendicular
    /// planes; a wall, the floor and a 10 degree ramp give about 0.17.
    pub min_conditioning: f64,
    /// Each plane needs `min_support` inliers within this radius of the corner,
    /// or within `support_range_fraction` of the corner's range if larger: a
    /// LIDAR with few beams sees the floor only in rings metres apart.
    pub support_radius_m: f64,
    pub support_range_fraction: f64,
    pub min_support: usize,
    /// Corners closer than this are one corner.
    pub merge_radius_m: f64,
    /// Edges: planes meeting at an angle in this range (degrees).
    pub edge_min_angle_deg: f64,
    pub edge_max_angle_deg: f64,
}

impl Default for CornerConfig {
    fn default() -> Self {
        Self {
            min_conditioning: 0.15,
            support_radius_m: 0.8,
            support_range_fraction: 0.3,
            min_support: 4,
            merge_radius_m: 0.1,
            edge_min_angle_deg: 4.0,
            edge_max_angle_deg: 30.0,
        }
    }
}

#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Corner3 {
    pub position: Vec3,
    /// Indices into the plane set.
    pub planes: [usize; 3],
    /// |det| of the normals: how well the position is determined.
    pub conditioning: f64,
}

/// The line where two planes meet, within the span of their points.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Edge {
    pub point: Vec3,
    pub direction: Vec3,
    pub planes: [usize; 2],
    pub angle_deg: f64,
}

#[derive(Debug, Clone, Default)]
pub struct CornerSet {
    pub corners: Vec<Corner3>,
    pub edges: Vec<Edge>,
}

/// The point where three planes meet and |det| of their normals (how well
/// it is determined); `None` below `min_conditioning`.
pub fn intersect_three(planes: [&Plane; 3], min_conditioning: f64) -> Option<(Vec3, f64)> {
    let [a, b, c] = planes;
    let normals = Mat3::from_rows(&[a.normal.transpose(), b.normal.transpose(), c.normal.transpose()]);
    let conditioning = normals.determinant().abs();
    if conditioning < min_conditioning {
        return None;
    }
    let position = normals.try_inverse()? * Vec3::new(a.distance, b.distance, c.distance);
    Some((position, conditioning))
}

pub struct CornerExtractor {
    config: CornerConfig,
}

impl CornerExtractor {
    pub fn new(config: CornerConfig) -> Result<Self> {
        if !(config.min_conditioning > 0.0 && config.min_conditioning <= 1.0) {
            let problem = format!("{} outside (0, 1]", config.min_conditioning);
            return Err(InvalidSetting::field("corners.min_conditioning", problem).into());
        }
        if !(config.support_radius_m > 0.0) {
            let problem = format!("{} m must be > 0", config.support_radius_m);
            return Err(InvalidSetting::field("corners.support_radius_m", problem).into());
        }
        Ok(Self { config })
    }

    /// Corners and edges of the planes of `points`, which `grid` indexes.
    pub fn extract(&self, set: &PlaneSet, points: &[Point3<f32>], grid: &ScanGrid) -> CornerSet {
        let c = &self.config;
        let planes = &set.planes;
        let sensor = grid.sensor();
        // Inliers of each plane near a position (from the shared grid).
        let support = |x: &Vec3| -> Vec<usize> {
            let radius = c.support_radius_m.max(c.support_range_fraction * (x - sensor).norm());
            let mut count = vec![0usize; planes.len()];
            grid.within(x, radius, |i| {
                if let Some(label) = set.labels[i] {
                    count[label as usize] += 1;
                }
            });
            count
        };
        let mut corners: Vec<Corner3> = Vec::new();
        for i in 0..planes.len() {
            for j in i + 1..planes.len() {
                for k in j + 1..planes.len() {
                    let Some((position, conditioning)) =
                        intersect_three([&planes[i], &planes[j], &planes[k]], c.min_conditioning)
                    else {
                        continue;
                    };
                    let count = support(&position);
                    if [i, j, k].iter().all(|&p| count[p] >= c.min_support) {
                        corners.push(Corner3 { position, planes: [i, j, k], conditioning });
                    }
                }
            }
        }
        // Best-conditioned first, then drop corners next to a kept one.
        corners.sort_by(|a, b| b.conditioning.total_cmp(&a.conditioning));
        let mut kept: Vec<Corner3> = Vec::new();
        for corner in corners {
            if kept.iter().all(|k| (k.position - corner.position).norm() > c.merge_radius_m) {
                kept.push(corner);
            }
        }
        let edges = self.edges(set, points);
        CornerSet { corners: kept, edges }
    }

    fn edges(&self, set: &PlaneSet, points: &[Point3<f32>]) -> Vec<Edge> {
        let c = &self.config;
        let planes = &set.planes;
        let mut edges = Vec::new();
        for i in 0..planes.len() {
            for j in i + 1..planes.len() {
                let (a, b) = (&planes[i], &planes[j]);
                let angle_deg = a.angle_deg(b);
                if !(c.edge_min_angle_deg..=c.edge_max_angle_deg).contains(&angle_deg) {
                    continue;
                }
                let direction = a.normal.cross(&b.normal).normalize();
                // The point of the line nearest the origin: on both planes and
                // orthogonal to the direction.
                let system = Mat3::from_rows(&[a.normal.transpose(), b.normal.transpose(), direction.transpose()]);
                let Some(inverse) = system.try_inverse() else { continue };
                let point = inverse * Vec3::new(a.distance, b.distance, 0.0);
                // Both planes must reach the line: an inlier of each within the
                // support radius of it.
                let near = |plane: &Plane| {
                    plane.inliers.iter().any(|&p| {
                        let v = points[p as usize].cast::<f64>().coords - point;
                        (v - direction * v.dot(&direction)).norm() < c.support_radius_m
                    })
                };
                if near(a) && near(b) {
                    edges.push(Edge { point, direction, planes: [i, j], angle_deg });
                }
            }
        }
        edges
    }
}
