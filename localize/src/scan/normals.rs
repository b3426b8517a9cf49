//! Surface normals: PCA of each point's k nearest neighbours (found in the
//! scan's direction grid), the normal being the eigenvector of the smallest
//! eigenvalue, oriented toward the sensor.

use datasets::InvalidSetting;
use datasets::math::{Mat3, Vec3};
use nalgebra::Point3;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::error::{LocalizeError, Result};
use crate::scan::organised_normals::OrganisedNormalConfig;
use crate::scan::scan_grid::{NeighbourScratch, ScanGrid};

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct NormalConfig {
    /// Neighbours per point. A spinning LIDAR with few beams has points far
    /// denser along a ring than across rings: k must reach the next ring
    /// (about 2 x elevation step / azimuth step points), or the neighbourhood
    /// is a line and its smallest eigenvector meaningless.
    pub neighbours: usize,
    /// Normals from the range image where the scan has one.
    pub organised: OrganisedNormalConfig,
}

impl Default for NormalConfig {
    fn default() -> Self {
        Self { neighbours: 40, organised: OrganisedNormalConfig::default() }
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

impl NormalEstimator {
    pub fn new(config: NormalConfig) -> Result<Self> {
        if config.neighbours < 3 {
            let problem = format!("{} is fewer than the 3 a plane needs", config.neighbours);
            return Err(InvalidSetting::field("normals.neighbours", problem).into());
        }
        config.organised.validate().map_err(|e| e.within("normals.organised"))?;
        Ok(Self { config })
    }

    pub fn config(&self) -> &NormalConfig {
        &self.config
    }

    /// One normal per point of the cloud `grid` indexes (`points`, in the
    /// same order), each pointing toward the grid's sensor.
    pub fn estimate(&self, points: &[Point3<f32>], grid: &ScanGrid) -> Result<Vec<PointNormal>> {
        let k = self.config.neighbours;
        if grid.len() != points.len() {
            return Err(LocalizeError::Cloud(format!(
                "{} points but a neighbour grid of {}: the grid must index these points",
                points.len(),
                grid.len()
            )));
        }
        if points.len() < k {
            return Err(LocalizeError::Cloud(format!(
                "{} points, fewer than the {k} neighbours a normal needs",
                points.len()
            )));
        }
        let mut normals = vec![PointNormal { normal: Vec3::z(), curvature: 0.0, offset: 0.0 }; points.len()];
        normals.par_chunks_mut(CHUNK).enumerate().for_each(|(c, out)| fill(points, grid, k, c * CHUNK, out));
        Ok(normals)
    }
}

/// The normals of `points[first..first + out.len()]`, compiled for AVX-512,
/// or AVX2 and FMA, where the CPU has them: one binary for every x86-64
/// CPU, and the same results either way (Rust never fuses a multiply and an
/// add on its own).
fn fill(points: &[Point3<f32>], grid: &ScanGrid, k: usize, first: usize, out: &mut [PointNormal]) {
    let scratch = NeighbourScratch::default();
    #[cfg(target_arch = "x86_64")]
    if scratch.is_avx512() {
        // SAFETY: the scratch searches with AVX-512F only where the CPU has it.
        unsafe { fill_avx512(points, grid, k, first, out, scratch) };
        return;
    }
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma") {
        // SAFETY: the CPU has both features, checked just above.
        unsafe { fill_avx2_fma(points, grid, k, first, out, scratch) };
        return;
    }
    fill_portable(points, grid, k, first, out, scratch);
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx2,fma")]
fn fill_avx512(
    points: &[Point3<f32>],
    grid: &ScanGrid,
    k: usize,
    first: usize,
    out: &mut [PointNormal],
    scratch: NeighbourScratch,
) {
    fill_portable(points, grid, k, first, out, scratch);
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn fill_avx2_fma(
    points: &[Point3<f32>],
    grid: &ScanGrid,
    k: usize,
    first: usize,
    out: &mut [PointNormal],
    scratch: NeighbourScratch,
) {
    fill_portable(points, grid, k, first, out, scratch);
}

#[inline(always)]
fn fill_portable(
    points: &[Point3<f32>],
    grid: &ScanGrid,
    k: usize,
    first: usize,
    out: &mut [PointNormal],
    mut scratch: NeighbourScratch,
) {
    let sensor = grid.sensor();
    let mut hint = f64::INFINITY;
    for (i, normal_out) in (first..).zip(out.iter_mut()) {
        let neighbours = grid.nearest(i, k, &mut hint, &mut scratch);
        *normal_out = plane_of_neighbours(points[i], neighbours.iter().map(|&slot| grid.point(slot)), &sensor);
    }
}

/// The normal of `point`'s neighbourhood (`neighbours`, itself among them)
/// by PCA, oriented toward `sensor`.
#[inline(always)]
pub(crate) fn plane_of_neighbours(
    point: Point3<f32>,
    neighbours: impl Iterator<Item = [f32; 3]>,
    sensor: &Vec3,
) -> PointNormal {
    // One pass over the neighbours, relative to the point itself (small
    // numbers: no cancellation to speak of).
    let p = point.cast::<f64>().coords;
    let (mut sum, mut products, mut count) = (Vec3::zeros(), [0.0; 6], 0usize);
    for q in neighbours {
        let d = [f64::from(q[0]) - p.x, f64::from(q[1]) - p.y, f64::from(q[2]) - p.z];
        sum += Vec3::from(d);
        products[0] += d[0] * d[0];
        products[1] += d[0] * d[1];
        products[2] += d[0] * d[2];
        products[3] += d[1] * d[1];
        products[4] += d[1] * d[2];
        products[5] += d[2] * d[2];
        count += 1;
    }
    plane_from_moments(&p, &sum, products, count as f64, sensor)
}

/// The normal at `p` of neighbours whose offsets from `p` sum to `sum`,
/// their products (xx, xy, xz, yy, yz, zz) to `products`, `n` of them;
/// oriented toward `sensor`.
#[inline(always)]
pub(crate) fn plane_from_moments(p: &Vec3, sum: &Vec3, products: [f64; 6], n: f64, sensor: &Vec3) -> PointNormal {
    let mean = sum / n;
    let [xx, xy, xz, yy, yz, zz] = products;
    let covariance = Mat3::new(xx, xy, xz, xy, yy, yz, xz, yz, zz) - mean * sum.transpose();
    let (mut normal, curvature) = smallest_eigenvector(&covariance);
    if normal.dot(&(sensor - p)) < 0.0 {
        normal = -normal;
    }
    // The point's distance from its neighbours' mean, along the normal.
    let offset = -normal.dot(&mean);
    PointNormal { normal, curvature, offset }
}

/// Points searched in order by one task, each search starting from the
/// previous one's neighbourhood size.
const CHUNK: usize = 256;

/// The unit eigenvector of the smallest eigenvalue of a symmetric 3x3 matrix
/// and the surface variation; a zero matrix gives +z and curvature 1/3.
///
/// In closed form (the eigenvalues from the characteristic cubic, the
/// eigenvector as the cross product of two rows of `A - lambda I`), several
/// times faster than an iterative solver; where the smallest eigenvalue is
/// not simple (a line, an isotropic blob: no normal to speak of) the
/// iterative solver decides, as it always did.
#[inline(always)]
pub fn smallest_eigenvector(covariance: &Mat3) -> (Vec3, f64) {
    let a = covariance;
    let trace = a.trace();
    if trace.is_nan() || trace <= 0.0 {
        return (Vec3::z(), 1.0 / 3.0);
    }
    let q = trace / 3.0;
    let b = a - Mat3::identity() * q;
    let off = a[(0, 1)].powi(2) + a[(0, 2)].powi(2) + a[(1, 2)].powi(2);
    let p = ((b[(0, 0)].powi(2) + b[(1, 1)].powi(2) + b[(2, 2)].powi(2) + 2.0 * off) / 6.0).sqrt();
    if p > 1e-9 * q {
        let r = ((b / p).determinant() / 2.0).clamp(-1.0, 1.0);
        let phi = r.acos() / 3.0;
        let largest = q + 2.0 * p * phi.cos();
        let smallest = q + 2.0 * p * (phi + 2.0 * std::f64::consts::FRAC_PI_3).cos();
        let m = a - Mat3::identity() * smallest;
        let rows = [m.row(0).transpose(), m.row(1).transpose(), m.row(2).transpose()];
        let crosses = [rows[0].cross(&rows[1]), rows[0].cross(&rows[2]), rows[1].cross(&rows[2])];
        let best = crosses.iter().max_by(|x, y| x.norm_squared().total_cmp(&y.norm_squared())).expect("three");
        // |best| is about (lambda_1 - lambda_3)(lambda_2 - lambda_3): small
        // against the spread when the smallest eigenvalue is (nearly) double.
        let spread = largest - smallest;
        if best.norm() > 1e-6 * spread * spread {
            return (best.normalize(), smallest.max(0.0) / trace);
        }
    }
    iterative_smallest_eigenvector(covariance, trace)
}

/// `smallest_eigenvector` by nalgebra's iterative solver (`trace` > 0).
fn iterative_smallest_eigenvector(covariance: &Mat3, trace: f64) -> (Vec3, f64) {
    let eigen = covariance.symmetric_eigen();
    let (index, lambda) = eigen.eigenvalues.iter().enumerate().min_by(|a, b| a.1.total_cmp(b.1)).expect("three values");
    (eigen.eigenvectors.column(index).normalize(), lambda.max(0.0) / trace)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::rngs::ChaCha8Rng;
    use rand::{RngExt, SeedableRng};

    #[test]
    fn a_grid_of_other_points_is_an_error() {
        let points: Vec<Point3<f32>> = (0..50).map(|i| Point3::new(1.0, i as f32 * 0.01, 0.0)).collect();
        let grid = ScanGrid::new(&points[..45], &Vec3::zeros());
        let estimator = NormalEstimator::new(NormalConfig::default()).unwrap();
        let error = estimator.estimate(&points, &grid).unwrap_err().to_string();
        assert!(error.contains("50 points but a neighbour grid of 45"), "{error}");
    }

    /// A spinning LIDAR's scan of a box-shaped room (walls, floor and
    /// ceiling at different distances, 5 mm range noise), in sweep order.
    fn room_scan(rng: &mut ChaCha8Rng) -> Vec<Point3<f32>> {
        let mut points = Vec::new();
        for step in 0..240 {
            let azimuth = step as f64 * std::f64::consts::TAU / 240.0;
            for beam in 0..12 {
                let elevation = (-25.0 + 3.5 * beam as f64).to_radians();
                let ray = Vec3::new(elevation.cos() * azimuth.cos(), elevation.cos() * azimuth.sin(), elevation.sin());
                // The nearest of the six faces: x in [-3, 2.5], y in [-4, 3.5], z in [-1.2, 2].
                let range = [(-3.0, ray.x), (2.5, ray.x), (-4.0, ray.y), (3.5, ray.y), (-1.2, ray.z), (2.0, ray.z)]
                    .iter()
                    .filter(|(face, along)| face * along > 0.0)
                    .map(|(face, along)| face / along)
                    .fold(f64::INFINITY, f64::min);
                points.push((ray * (range + rng.random_range(-0.005..0.005))).cast::<f32>().into());
            }
        }
        points
    }

    #[test]
    fn normals_match_a_brute_force_reference() {
        let mut rng = ChaCha8Rng::seed_from_u64(12);
        let points = room_scan(&mut rng);
        let sensor = Vec3::zeros();
        let grid = ScanGrid::new(&points, &sensor);
        let k = NormalConfig::default().neighbours;
        let normals = NormalEstimator::new(NormalConfig::default()).unwrap().estimate(&points, &grid).unwrap();
        // The reference: the k nearest by sorting every squared distance (in
        // f32, as the search measures them), a two-pass covariance from the
        // input points, nalgebra's iterative eigen solver.
        // Every 5th point: all six faces, and a test that stays quick unoptimised.
        for (i, (p, estimated)) in points.iter().zip(&normals).enumerate().step_by(5) {
            let d2 = |q: &Point3<f32>| {
                let d = [q.x - p.x, q.y - p.y, q.z - p.z];
                d[0] * d[0] + d[1] * d[1] + d[2] * d[2]
            };
            let mut order: Vec<usize> = (0..points.len()).collect();
            order.sort_by(|&a, &b| d2(&points[a]).total_cmp(&d2(&points[b])));
            let near: Vec<Vec3> = order[..k].iter().map(|&j| points[j].cast::<f64>().coords).collect();
            let mean = near.iter().sum::<Vec3>() / k as f64;
            let covariance = near.iter().fold(Mat3::zeros(), |c, q| c + (q - mean) * (q - mean).transpose());
            let (mut normal, curvature) = iterative_smallest_eigenvector(&covariance, covariance.trace());
            let at = p.cast::<f64>().coords;
            if normal.dot(&(sensor - at)) < 0.0 {
                normal = -normal;
            }
            let angle = normal.dot(&estimated.normal).clamp(-1.0, 1.0).acos();
            assert!(angle < 1e-6, "point {i}: normals {angle} rad apart");
            assert!(
                (curvature - estimated.curvature).abs() < 1e-9,
                "point {i}: curvature {curvature} vs {}",
                estimated.curvature
            );
            let offset = normal.dot(&(at - mean));
            assert!((offset - estimated.offset).abs() < 1e-9, "point {i}: offset {offset} vs {}", estimated.offset);
        }
        // The code compiled for any x86-64 CPU gives the very same normals.
        let mut portable = normals.clone();
        for (c, out) in portable.chunks_mut(CHUNK).enumerate() {
            fill_portable(&points, &grid, k, c * CHUNK, out, NeighbourScratch::portable());
        }
        assert!(portable == normals, "the portable build differs");
        // The walls' normals point into the room: a wall at x = 2.5 faces -x.
        let wall = points.iter().position(|p| (p.x - 2.5).abs() < 0.01 && p.y.abs() < 1.0 && p.z.abs() < 0.5).unwrap();
        assert!(normals[wall].normal.x < -0.99, "{:?}", normals[wall].normal);
    }

    #[test]
    fn the_closed_form_agrees_with_the_iterative_solver() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        // Patches of 40 points: planes with noise from 1e-6 to 0.3 of their
        // extent (the normals' working range), at random orientations, and
        // lines and blobs (no simple smallest eigenvalue).
        for case in 0..3000 {
            let rotation = nalgebra::Rotation3::from_scaled_axis(Vec3::new(
                rng.random_range(-3.0..3.0),
                rng.random_range(-3.0..3.0),
                rng.random_range(-3.0..3.0),
            ));
            let noise = 10f64.powf(rng.random_range(-6.0..-0.5));
            let (sx, sy) = match case % 3 {
                0 => (1.0, rng.random_range(0.2..1.0)),
                1 => (1.0, noise),
                _ => (noise, noise),
            };
            let offset = Vec3::new(rng.random_range(-20.0..20.0), rng.random_range(-20.0..20.0), 0.0);
            let points: Vec<Vec3> = (0..40)
                .map(|_| {
                    let local = Vec3::new(
                        sx * rng.random_range(-1.0..1.0),
                        sy * rng.random_range(-1.0..1.0),
                        noise * rng.random_range(-1.0..1.0),
                    );
                    rotation * local + offset
                })
                .collect();
            let mean = points.iter().sum::<Vec3>() / points.len() as f64;
            let covariance = points.iter().fold(Mat3::zeros(), |c, p| c + (p - mean) * (p - mean).transpose());
            let (closed, curvature) = smallest_eigenvector(&covariance);
            let (reference, reference_curvature) = iterative_smallest_eigenvector(&covariance, covariance.trace());
            assert!((closed.norm() - 1.0).abs() < 1e-12);
            assert!(
                (curvature - reference_curvature).abs() < 1e-10,
                "case {case}: curvature {curvature} against {reference_curvature}"
            );
            if case % 3 == 0 {
                // A plane's normal, to within a microradian.
                let angle = closed.dot(&reference).abs().min(1.0).acos();
                assert!(angle < 1e-6, "case {case}: normals {angle} rad apart (noise {noise})");
            }
        }
        assert_eq!(smallest_eigenvector(&Mat3::zeros()), (Vec3::z(), 1.0 / 3.0));
        let isotropic = smallest_eigenvector(&Mat3::identity());
        assert!((isotropic.1 - 1.0 / 3.0).abs() < 1e-12 && (isotropic.0.norm() - 1.0).abs() < 1e-12);
    }
}
