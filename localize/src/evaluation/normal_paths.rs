//! The organised normals measured against the exact k-nearest ones on the
//! same cloud: the planes and 3D corners each path finds, matched one to
//! one, their differences in degrees and millimetres, and the milliseconds
//! of each. What `localize bench` reports for its scans and for real clouds.

use datasets::math::{Vec3, median};
use nalgebra::Point3;
use serde::Serialize;

use crate::config::LocalizeConfig;
use crate::error::Result;
use crate::scan::geometry::Geometry;
use crate::scan::planes::Plane;

/// Two planes are the same surface within these.
const PLANE_MATCH_DEG: f64 = 10.0;
const PLANE_MATCH_M: f64 = 0.3;
/// Two corners are the same within this.
const CORNER_MATCH_M: f64 = 0.3;

#[derive(Debug, Clone, Serialize)]
pub struct PathComparison {
    pub points: usize,
    /// The range image's projection ("spherical", "pinhole"); None: the
    /// cloud has no rows and columns, and both paths are the exact one.
    pub organised: Option<String>,
    pub exact_normals_ms: f64,
    pub organised_normals_ms: f64,
    pub exact_planes: usize,
    pub organised_planes: usize,
    pub matched_planes: usize,
    /// Largest and median angle between matched planes' normals (degrees),
    /// and their offsets' largest difference (mm).
    pub plane_max_deg: f64,
    pub plane_median_deg: f64,
    pub plane_max_offset_mm: f64,
    pub exact_corners: usize,
    pub organised_corners: usize,
    pub matched_corners: usize,
    /// Largest and median distance between matched corners (mm).
    pub corner_max_mm: f64,
    pub corner_median_mm: f64,
}

/// Runs the geometry stages of `config` on `points` (seen from `sensor`)
/// with its organised normals (wherever the cloud has rows and columns,
/// however far apart) and with the exact ones, `repeats` times each for the
/// milliseconds.
pub fn compare_paths(
    points: &[Point3<f32>],
    sensor: &Vec3,
    config: &LocalizeConfig,
    repeats: usize,
) -> Result<PathComparison> {
    let run = |organised: bool| -> Result<(Geometry, f64)> {
        let mut c = config.clone();
        c.normals.organised.enabled = organised;
        // Measured wherever the cloud has rows and columns, however sparse.
        c.normals.organised.max_row_pitch_deg = 90.0;
        let stages = c.geometry_stages()?;
        let mut geometry = stages.run(points, sensor)?;
        let mut ms = geometry.normals_ms;
        for _ in 1..repeats.max(1) {
            geometry = stages.run(points, sensor)?;
            ms += geometry.normals_ms;
        }
        Ok((geometry, ms / repeats.max(1) as f64))
    };
    let (exact, exact_ms) = run(false)?;
    let (organised, organised_ms) = run(true)?;
    let plane_pairs = match_planes(&exact.planes.planes, &organised.planes.planes);
    let angles: Vec<f64> = plane_pairs.iter().map(|p| p.0).collect();
    let offsets: Vec<f64> = plane_pairs.iter().map(|p| p.1 * 1e3).collect();
    let corner_distances = match_corners(
        &exact.corners.corners.iter().map(|c| c.position).collect::<Vec<_>>(),
        &organised.corners.corners.iter().map(|c| c.position).collect::<Vec<_>>(),
    );
    let corner_mm: Vec<f64> = corner_distances.iter().map(|d| d * 1e3).collect();
    Ok(PathComparison {
        points: points.len(),
        organised: organised.organised.map(|p| format!("{p:?}").to_lowercase()),
        exact_normals_ms: exact_ms,
        organised_normals_ms: organised_ms,
        exact_planes: exact.planes.planes.len(),
        organised_planes: organised.planes.planes.len(),
        matched_planes: plane_pairs.len(),
        plane_max_deg: max(&angles),
        plane_median_deg: median(angles.clone()).unwrap_or(0.0),
        plane_max_offset_mm: max(&offsets),
        exact_corners: exact.corners.corners.len(),
        organised_corners: organised.corners.corners.len(),
        matched_corners: corner_mm.len(),
        corner_max_mm: max(&corner_mm),
        corner_median_mm: median(corner_mm.clone()).unwrap_or(0.0),
    })
}

/// Planes of `a` and `b` matched one to one, largest first: (angle between
/// normals in degrees, offset difference in metres) per pair.
fn match_planes(a: &[Plane], b: &[Plane]) -> Vec<(f64, f64)> {
    let mut order: Vec<usize> = (0..a.len()).collect();
    order.sort_by_key(|&i| std::cmp::Reverse(a[i].inliers.len()));
    let mut taken = vec![false; b.len()];
    let mut pairs = Vec::new();
    for i in order {
        let p = &a[i];
        let best = b
            .iter()
            .enumerate()
            .filter(|(j, _)| !taken[*j])
            .map(|(j, q)| {
                // Same orientation convention: flip q to agree with p.
                let sign = if p.normal.dot(&q.normal) < 0.0 { -1.0 } else { 1.0 };
                let angle = p.normal.dot(&(q.normal * sign)).clamp(-1.0, 1.0).acos().to_degrees();
                // Offsets compared at p's centroid: q's distance from it.
                let offset = (q.normal.dot(&p.centroid) - q.distance).abs();
                (j, angle, offset)
            })
            .filter(|&(_, angle, offset)| angle < PLANE_MATCH_DEG && offset < PLANE_MATCH_M)
            .min_by(|x, y| {
                (x.1 / PLANE_MATCH_DEG + x.2 / PLANE_MATCH_M).total_cmp(&(y.1 / PLANE_MATCH_DEG + y.2 / PLANE_MATCH_M))
            });
        if let Some((j, angle, offset)) = best {
            taken[j] = true;
            pairs.push((angle, offset));
        }
    }
    pairs
}

/// Corners of `a` and `b` matched one to one, nearest pairs first: the
/// distance of each pair (metres).
fn match_corners(a: &[Vec3], b: &[Vec3]) -> Vec<f64> {
    let mut candidates: Vec<(f64, usize, usize)> = Vec::new();
    for (i, p) in a.iter().enumerate() {
        for (j, q) in b.iter().enumerate() {
            let d = (p - q).norm();
            if d < CORNER_MATCH_M {
                candidates.push((d, i, j));
            }
        }
    }
    candidates.sort_by(|x, y| x.0.total_cmp(&y.0));
    let (mut used_a, mut used_b) = (vec![false; a.len()], vec![false; b.len()]);
    let mut distances = Vec::new();
    for (d, i, j) in candidates {
        if !used_a[i] && !used_b[j] {
            (used_a[i], used_b[j]) = (true, true);
            distances.push(d);
        }
    }
    distances
}

fn max(values: &[f64]) -> f64 {
    values.iter().copied().fold(0.0, f64::max)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn plane(normal: Vec3, distance: f64, inliers: usize) -> Plane {
        Plane { normal, distance, centroid: normal * distance, inliers: vec![0; inliers], rms_m: 0.0 }
    }

    #[test]
    fn planes_and_corners_pair_one_to_one_by_their_differences() {
        let tilt = Vec3::new(1.0, 0.02, 0.0).normalize();
        let a = [plane(Vec3::x(), 2.0, 500), plane(Vec3::z(), -1.0, 300), plane(Vec3::y(), 4.0, 100)];
        // b: the first tilted by 1.15 degrees and 1 cm further, the second
        // flipped (same plane), a plane a has not, and none near the third.
        let b = [plane(-Vec3::z(), 1.0, 290), plane(tilt, 2.01, 480), plane(Vec3::y(), 7.0, 90)];
        let pairs = match_planes(&a, &b);
        assert_eq!(pairs.len(), 2);
        assert!((pairs[0].0 - 0.02f64.atan().to_degrees()).abs() < 1e-9, "{:?}", pairs[0]);
        assert!(pairs[1].0 < 1e-6 && pairs[1].1 < 1e-9, "{:?}", pairs[1]);
        let corners = match_corners(
            &[Vec3::zeros(), Vec3::new(1.0, 0.0, 0.0)],
            &[Vec3::new(1.0, 0.0, 0.005), Vec3::new(0.0, 0.02, 0.0), Vec3::new(5.0, 0.0, 0.0)],
        );
        assert_eq!(corners.len(), 2);
        assert!((corners[0] - 0.005).abs() < 1e-12 && (corners[1] - 0.02).abs() < 1e-12);
    }
}
