//! Surface normals: PCA of each point's k nearest neighbours (kd-tree), the
//! normal being the eigenvector of the smallest eigenvalue, oriented toward
//! the sensor.

use std::num::NonZero;

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
            return Err(LocalizeError::Config(format!("normals: neighbours {} < 3", config.neighbours)));
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
            .par_iter()
            .map(|p| {
                let neighbours = tree.nearest_n::<SquaredEuclidean>(&[p.x, p.y, p.z], k);
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
                PointNormal { normal, curvature }
            })
            .collect())
    }
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
