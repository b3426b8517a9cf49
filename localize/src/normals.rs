//! Surface normals: PCA of each point's k nearest neighbours (kd-tree), the
//! normal being the eigenvector of the smallest eigenvalue, oriented toward
//! the sensor.

use std::num::NonZero;

use datasets::InvalidSetting;
use datasets::math::{Mat3, Vec3};
use kiddo::{ImmutableKdTree, SquaredEuclidean};
use nalgebra::Point3;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::error::{LocalizeError, Result};

pub type PointTree = ImmutableKdTree<f32, 3>;

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct NormalConfig {
    /// Neighbours per point. A spinning LIDAR with few beams has points far
    /// denser along a ring than across rings: k must reach the next ring
    /// (about 2 x elevation step / azimuth step points), or the neighbourhood
    /// is a line and its smallest eigenvector meaningless.
    pub neighbours: usize,
}

impl Default for NormalConfig {
    fn default() -> Self {
        Self { neighbours: 40 }
    }
}

/// A point's normal and how planar its neighbourhood is.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PointNormal {
    pub normal: Vec3,
    /// Surface variation lambda_min / (lambda_0 + lambda_1 + lambda_2):
    /// 0 on a perfect plane, 1/3 for isotropic scatter.
    pub curvature: f64,
    /// The point's signed distance along `normal` from its neighbours' mean:
    /// mostly its own range noise. `point - offset * normal` is the point
    /// on its neighbourhood's plane.
    pub offset: f64,
}

pub struct NormalEstimator {
    config: NormalConfig,
}

/// The kd-tree of a cloud, built once per frame and shared by the stages.
pub fn build_tree(points: &[Point3<f32>]) -> PointTree {
    let coordinates: Vec<[f32; 3]> = points.iter().map(|p| [p.x, p.y, p.z]).collect();
    ImmutableKdTree::new_from_slice(&coordinates)
}

impl NormalEstimator {
    pub fn new(config: NormalConfig) -> Result<Self> {
        if config.neighbours < 3 {
            let problem = format!("{} is fewer than the 3 a plane needs", config.neighbours);
            return Err(InvalidSetting::field("normals.neighbours", problem).into());
        }
        Ok(Self { config })
    }

    /// One normal per point, each pointing toward `sensor` (the origin of the
    /// cloud's frame for a scan in its sensor frame).
    pub fn estimate(&self, points: &[Point3<f32>], tree: &PointTree, sensor: &Vec3) -> Result<Vec<PointNormal>> {
        let k = self.config.neighbours;
        if points.len() < k {
            return Err(LocalizeError::Cloud(format!(
                "{} points, fewer than the {k} neighbours a normal needs",
                points.len()
            )));
        }
        let k = NonZero::new(k).expect("checked above");
        Ok(points
            .par_chunks(HINT_CHUNK)
            .flat_map_iter(|chunk| {
                let mut radius2 = f32::INFINITY;
                chunk.iter().map(move |p| {
                    let neighbours = nearest_with_hint(tree, p, k, &mut radius2);
                    let at = |i: u64| points[i as usize].cast::<f64>().coords;
                    let mean = neighbours.iter().fold(Vec3::zeros(), |a, n| a + at(n.item)) / neighbours.len() as f64;
                    let mut covariance = Mat3::zeros();
                    for n in &neighbours {
                        let d = at(n.item) - mean;
                        covariance += d * d.transpose();
                    }
                    let (mut normal, curvature) = smallest_eigenvector(&covariance);
                    if normal.dot(&(sensor - p.cast::<f64>().coords)) < 0.0 {
                        normal = -normal;
                    }
                    let offset = normal.dot(&(p.cast::<f64>().coords - mean));
                    PointNormal { normal, curvature, offset }
                })
            })
            .collect())
    }
}

/// Points searched in order by one task, each search bounded by the
/// previous one's neighbourhood.
const HINT_CHUNK: usize = 256;

/// The `k` nearest neighbours of `p` (unordered). Scans list points in
/// sweep order, so a point's neighbourhood is about as large as the
/// previous point's: a search within 1.2 x that radius (`radius2`, squared,
/// updated here) prunes most of the tree and returns the same k points
/// whenever it finds k; otherwise it is repeated without a bound.
fn nearest_with_hint(
    tree: &PointTree,
    p: &Point3<f32>,
    k: NonZero<usize>,
    radius2: &mut f32,
) -> Vec<kiddo::NearestNeighbour<f32, u64>> {
    let query = [p.x, p.y, p.z];
    let mut found = tree.nearest_n_within::<SquaredEuclidean>(&query, *radius2, k, false);
    if found.len() < k.get() && radius2.is_finite() {
        found = tree.nearest_n_within::<SquaredEuclidean>(&query, f32::INFINITY, k, false);
    }
    let farthest = found.iter().fold(0.0f32, |m, n| m.max(n.distance));
    *radius2 = if farthest > 0.0 { farthest * 1.44 } else { f32::INFINITY };
    found
}

/// The unit eigenvector of the smallest eigenvalue of a symmetric 3x3 matrix
/// and the surface variation; a zero matrix gives +z and curvature 1/3.
pub fn smallest_eigenvector(covariance: &Mat3) -> (Vec3, f64) {
    let eigen = covariance.symmetric_eigen();
    let trace: f64 = eigen.eigenvalues.iter().sum();
    if trace.is_nan() || trace <= 0.0 {
        return (Vec3::z(), 1.0 / 3.0);
    }
    let (index, lambda) = eigen.eigenvalues.iter().enumerate().min_by(|a, b| a.1.total_cmp(b.1)).expect("three values");
    (eigen.eigenvectors.column(index).normalize(), lambda.max(0.0) / trace)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::rngs::ChaCha8Rng;
    use rand::{RngExt, SeedableRng};

    /// The k nearest by brute force, as sorted indices.
    fn brute_force(points: &[Point3<f32>], p: &Point3<f32>, k: usize) -> Vec<usize> {
        let mut order: Vec<usize> = (0..points.len()).collect();
        order.sort_by(|&a, &b| (points[a] - p).norm_squared().total_cmp(&(points[b] - p).norm_squared()));
        order.truncate(k);
        order.sort_unstable();
        order
    }

    #[test]
    fn the_bounded_search_finds_exactly_the_k_nearest_in_any_order() {
        // Rings of a scan (sweep order, where the bound helps), with one
        // far-away cluster so that the previous radius is sometimes too small.
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let mut points: Vec<Point3<f32>> = Vec::new();
        for ring in 0..6 {
            for step in 0..300 {
                let a = step as f32 * std::f32::consts::TAU / 300.0;
                let r = 3.0 + rng.random_range(-0.02..0.02);
                points.push(Point3::new(r * a.cos(), r * a.sin(), -1.0 + 0.15 * ring as f32));
            }
            for _ in 0..20 {
                points.push(Point3::new(20.0 + rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0), 0.0));
            }
        }
        let mut shuffled = points.clone();
        for i in (1..shuffled.len()).rev() {
            shuffled.swap(i, rng.random_range(0..=i));
        }
        let k = NonZero::new(25).unwrap();
        for cloud in [&points, &shuffled] {
            let tree = build_tree(cloud);
            let mut radius2 = f32::INFINITY;
            for p in cloud.iter() {
                let mut found: Vec<usize> =
                    nearest_with_hint(&tree, p, k, &mut radius2).iter().map(|n| n.item as usize).collect();
                found.sort_unstable();
                assert_eq!(found, brute_force(cloud, p, k.get()), "at {p:?}");
            }
        }
    }
}
