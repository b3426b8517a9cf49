//! The LIDAR half of a frame: normals, planes and 3D corners of one cloud.

use std::time::Instant;

use datasets::math::Vec3;
use nalgebra::Point3;

use crate::error::{LocalizeError, Result};
use crate::scan::corners::{CornerConfig, CornerExtractor, CornerSet};
use crate::scan::normals::{NormalConfig, NormalEstimator, PointNormal};
use crate::scan::planes::{PlaneConfig, PlaneExtractor, PlaneSet};
use crate::scan::scan_grid::ScanGrid;
use crate::scan::voxel::{VoxelConfig, VoxelFilter};

pub struct GeometryStages {
    voxel: VoxelFilter,
    normals: NormalEstimator,
    planes: PlaneExtractor,
    corners: CornerExtractor,
}

/// What the geometry stages found, with the milliseconds each took. Plane
/// inlier indices refer to `points`, the (possibly down-sampled) cloud.
pub struct Geometry {
    pub points: Vec<Point3<f32>>,
    /// One per point of `points`.
    pub normals: Vec<PointNormal>,
    pub planes: PlaneSet,
    pub corners: CornerSet,
    pub normals_ms: f64,
    pub planes_ms: f64,
    pub corners_ms: f64,
}

fn ms_since(start: Instant) -> f64 {
    start.elapsed().as_secs_f64() * 1e3
}

impl GeometryStages {
    /// The stages of these settings (`LocalizeConfig::geometry_stages` takes
    /// them from a whole configuration).
    pub fn new(
        voxel: &VoxelConfig,
        normals: &NormalConfig,
        planes: &PlaneConfig,
        corners: &CornerConfig,
    ) -> Result<Self> {
        Ok(Self {
            voxel: VoxelFilter::new(voxel.clone())?,
            normals: NormalEstimator::new(normals.clone())?,
            planes: PlaneExtractor::new(planes.clone())?,
            corners: CornerExtractor::new(corners.clone())?,
        })
    }

    /// `points` in the sensor's frame, `sensor` its origin there.
    pub fn run(&self, points: &[Point3<f32>], sensor: &Vec3) -> Result<Geometry> {
        if points.is_empty() {
            return Err(LocalizeError::Cloud("no finite points".into()));
        }
        // Down-sampling is counted with the normals it serves.
        let start = Instant::now();
        let points = self.voxel.downsample(points);
        let grid = ScanGrid::new(&points, sensor);
        let normals = self.normals.estimate(&points, &grid)?;
        let normals_ms = ms_since(start);
        let start = Instant::now();
        let planes = self.planes.extract(&points, &normals);
        let planes_ms = ms_since(start);
        let start = Instant::now();
        let corners = self.corners.extract(&planes, &points, &grid);
        let corners_ms = ms_since(start);
        Ok(Geometry { points, normals, planes, corners, normals_ms, planes_ms, corners_ms })
    }
}
