//! The point map: every planar surface point the run has placed in the
//! world, kept in a voxel hash (a bounded number per cube, as KISS-ICP's
//! local map keeps them) with the surface normal it was seen with, and the
//! plane fitted to each voxel's points. Scans register against those planes:
//! a fit over many scans' points is steadier than one point's normal under
//! centimetres of range noise. Unlike KISS-ICP's map, far voxels are not
//! dropped, so a route that comes back finds what it saw before.

use datasets::math::{Mat3, Pose3, Vec3};
use rustc_hash::FxHashMap;

use crate::scan::normals::smallest_eigenvector;

/// A map point and the unit normal of the surface it lies on (world frame).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MapPoint {
    pub position: Vec3,
    pub normal: Vec3,
}

/// The plane through a voxel's points: unit normal (pointing as its points'
/// normals do) and centroid.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VoxelPlane {
    pub normal: Vec3,
    pub centroid: Vec3,
}

#[derive(Default)]
struct Voxel {
    points: Vec<MapPoint>,
    plane: Option<VoxelPlane>,
}

/// Fewest points a voxel's plane is fitted to.
const PLANE_MIN_POINTS: usize = 5;
/// Largest surface variation of a voxel that still counts as a plane.
const PLANE_MAX_CURVATURE: f64 = 0.01;
/// Least spread across a voxel's points (middle over largest eigenvalue):
/// a sparse LIDAR's ring leaves a strip, whose fitted normal may lie
/// anywhere around the strip's axis.
const PLANE_MIN_SPREAD: f64 = 0.05;

impl Voxel {
    fn fit(&mut self) {
        self.plane = None;
        if self.points.len() < PLANE_MIN_POINTS {
            return;
        }
        let n = self.points.len() as f64;
        let centroid = self.points.iter().fold(Vec3::zeros(), |a, p| a + p.position) / n;
        let mut covariance = Mat3::zeros();
        for p in &self.points {
            let d = p.position - centroid;
            covariance += d * d.transpose();
        }
        let (mut normal, curvature) = smallest_eigenvector(&covariance);
        let eigenvalues = covariance.symmetric_eigenvalues();
        let (largest, smallest) = (eigenvalues.max(), eigenvalues.min());
        let middle = eigenvalues.sum() - largest - smallest;
        if curvature > PLANE_MAX_CURVATURE || !(middle >= PLANE_MIN_SPREAD * largest) {
            return;
        }
        let facing: Vec3 = self.points.iter().map(|p| p.normal).sum();
        if normal.dot(&facing) < 0.0 {
            normal = -normal;
        }
        self.plane = Some(VoxelPlane { normal, centroid });
    }
}

/// The voxel of edge `voxel_m` that holds `p` (also the edge map's).
pub(crate) fn voxel_key(p: &Vec3, voxel_m: f64) -> [i32; 3] {
    let k = |v: f64| (v / voxel_m).floor() as i32;
    [k(p.x), k(p.y), k(p.z)]
}

pub struct PointMap {
    voxel_m: f64,
    points_per_voxel: usize,
    /// Closer than this to a point already in its voxel, a new point adds nothing.
    min_spacing_m: f64,
    voxels: FxHashMap<[i32; 3], Voxel>,
    len: usize,
}

impl PointMap {
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
        voxel_key(p, self.voxel_m)
    }

    /// Adds robot-frame points and normals placed in the world by `pose`;
    /// a full voxel, or a point too close to one kept, is skipped. The
    /// voxels that took points are refitted.
    pub fn insert(&mut self, points: &[Vec3], normals: &[Vec3], pose: &Pose3) {
        let spacing2 = self.min_spacing_m * self.min_spacing_m;
        let mut changed = Vec::new();
        for (p, n) in points.iter().zip(normals) {
            let position = (pose * nalgebra::Point3::from(*p)).coords;
            let normal = pose.rotation * n;
            let key = self.key(&position);
            let voxel = self.voxels.entry(key).or_default();
            if voxel.points.len() >= self.points_per_voxel
                || voxel.points.iter().any(|q| (q.position - position).norm_squared() < spacing2)
            {
                continue;
            }
            voxel.points.push(MapPoint { position, normal });
            self.len += 1;
            changed.push(key);
        }
        changed.sort_unstable();
        changed.dedup();
        for key in changed {
            self.voxels.get_mut(&key).expect("just filled").fit();
        }
    }

    /// The plane of the voxel holding the map point nearest to `query`
    /// within `max_distance_m`; where that voxel has no plane of its own,
    /// the one through the point with its own normal (`None` without such a
    /// point).
    pub fn nearest_plane(&self, query: &Vec3, max_distance_m: f64) -> Option<VoxelPlane> {
        let key = self.nearest_key(query, max_distance_m)?;
        let voxel = &self.voxels[&key];
        voxel.plane.or_else(|| {
            let point = nearest_in(&voxel.points, query)?;
            Some(VoxelPlane { normal: point.normal, centroid: point.position })
        })
    }

    /// The map point nearest to `query` within `max_distance_m` (at most one
    /// voxel edge: only the 27 voxels around the query are searched). The
    /// registration asks for planes; this checks the search under them.
    #[cfg(test)]
    fn nearest(&self, query: &Vec3, max_distance_m: f64) -> Option<&MapPoint> {
        let key = self.nearest_key(query, max_distance_m)?;
        nearest_in(&self.voxels[&key].points, query)
    }

    /// The voxel of the map point nearest to `query` within `max_distance_m`.
    fn nearest_key(&self, query: &Vec3, max_distance_m: f64) -> Option<[i32; 3]> {
        let [x, y, z] = self.key(query);
        let mut best = None;
        let mut limit = max_distance_m * max_distance_m;
        for dx in -1..=1 {
            for dy in -1..=1 {
                for dz in -1..=1 {
                    let key = [x + dx, y + dy, z + dz];
                    let Some(voxel) = self.voxels.get(&key) else { continue };
                    for point in &voxel.points {
                        let d = (point.position - query).norm_squared();
                        if d <= limit {
                            limit = d;
                            best = Some(key);
                        }
                    }
                }
            }
        }
        best
    }

    /// Every map point, in no particular order.
    pub fn points(&self) -> impl Iterator<Item = &MapPoint> {
        self.voxels.values().flat_map(|v| &v.points)
    }
}

fn nearest_in<'a>(points: &'a [MapPoint], query: &Vec3) -> Option<&'a MapPoint> {
    points.iter().min_by(|a, b| (a.position - query).norm_squared().total_cmp(&(b.position - query).norm_squared()))
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::rngs::ChaCha8Rng;
    use rand::{RngExt, SeedableRng};

    #[test]
    fn nearest_agrees_with_brute_force_and_voxels_stay_bounded() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let mut map = PointMap::new(0.5, 6, 0.02);
        let points: Vec<Vec3> = (0..3000)
            .map(|_| Vec3::new(rng.random_range(-2.0..2.0), rng.random_range(-2.0..2.0), rng.random_range(0.0..1.0)))
            .collect();
        let normals = vec![Vec3::z(); points.len()];
        let pose = Pose3::new(Vec3::new(1.0, -2.0, 0.5), Vec3::new(0.0, 0.0, 0.7));
        map.insert(&points, &normals, &pose);
        assert!(map.len() < points.len(), "full voxels take no more points");
        let mut per_voxel: FxHashMap<[i32; 3], usize> = FxHashMap::default();
        for p in map.points() {
            *per_voxel.entry(map.key(&p.position)).or_default() += 1;
            assert!((p.normal - Vec3::z()).norm() < 1e-12, "a yaw keeps +z");
        }
        assert!(per_voxel.values().all(|&n| n <= 6));
        let kept: Vec<MapPoint> = map.points().copied().collect();
        for _ in 0..500 {
            let q = Vec3::new(rng.random_range(-2.0..4.0), rng.random_range(-5.0..1.0), rng.random_range(0.0..1.5));
            let brute = kept
                .iter()
                .map(|p| (p, (p.position - q).norm()))
                .filter(|(_, d)| *d <= 0.4)
                .min_by(|a, b| a.1.total_cmp(&b.1))
                .map(|(p, _)| *p);
            assert_eq!(map.nearest(&q, 0.4).copied(), brute, "at {q:?}");
        }
    }
}
