//! The LIDAR half of a frame: normals, planes and 3D corners of one cloud.

use std::time::Instant;

use datasets::math::Vec3;
use nalgebra::Point3;

use crate::error::{LocalizeError, Result};
use crate::scan::corners::{CornerConfig, CornerExtractor, CornerSet};
use crate::scan::normals::{NormalConfig, NormalEstimator, PointNormal};
use crate::scan::organised_normals::organised_normals;
use crate::scan::planes::{PlaneConfig, PlaneExtractor, PlaneSet};
use crate::scan::range_image::{Projection, RangeImage, Recovery};
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
    /// The range image's projection where the normals came from one; None:
    /// the exact k nearest neighbours.
    pub organised: Option<Projection>,
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

    /// The rows and columns of `points` seen from `sensor`, and the
    /// milliseconds their recovery took; None where the organised normals
    /// are off, the cloud is thinned before them, it has no rows and
    /// columns, or its rows lie too far apart. Recover them from a sweep
    /// before deskewing it (deskewing moves each point off its beam) and
    /// pass them to `run_on`.
    pub fn range_image(&self, points: &[Point3<f32>], sensor: &Vec3) -> Option<(RangeImage, f64)> {
        let config = self.normals.config();
        // A thinned cloud has lost its rows and columns.
        if !(config.organised.enabled && self.voxel.keeps_every_point()) {
            return None;
        }
        let start = Instant::now();
        let image = RangeImage::recover(points, sensor, &Recovery::default()).ok()?;
        (image.row_pitch.abs() <= config.organised.max_row_pitch_deg.to_radians()).then(|| (image, ms_since(start)))
    }

    /// `points` in the sensor's frame, `sensor` its origin there.
    pub fn run(&self, points: &[Point3<f32>], sensor: &Vec3) -> Result<Geometry> {
        self.run_on(points, sensor, self.range_image(points, sensor))
    }

    /// As `run`, with the rows and columns `range_image` recovered (from
    /// these points, or from the same sweep before deskewing); they count
    /// in the normals' milliseconds.
    pub fn run_on(&self, points: &[Point3<f32>], sensor: &Vec3, image: Option<(RangeImage, f64)>) -> Result<Geometry> {
        if points.is_empty() {
            return Err(LocalizeError::Cloud("no finite points".into()));
        }
        // Down-sampling is counted with the normals it serves.
        let start = Instant::now();
        let points = self.voxel.downsample(points);
        let config = self.normals.config();
        let (image, image_ms) = match image {
            Some((image, ms)) if image.len() == points.len() => (Some(image), ms),
            _ => (None, 0.0),
        };
        let (normals, grid, organised) = match &image {
            Some(image) => {
                let normals = organised_normals(&points, image, sensor, config.neighbours, &config.organised);
                (normals, None, Some(image.projection))
            }
            None => {
                let grid = ScanGrid::new(&points, sensor);
                (self.normals.estimate(&points, &grid)?, Some(grid), None)
            }
        };
        let normals_ms = ms_since(start) + image_ms;
        let start = Instant::now();
        let planes = self.planes.extract(&points, &normals);
        let planes_ms = ms_since(start);
        // The corners' radius searches need the grid; on the organised path
        // it is built here, for them.
        let start = Instant::now();
        let grid = grid.unwrap_or_else(|| ScanGrid::new(&points, sensor));
        let corners = self.corners.extract(&planes, &points, &grid);
        let corners_ms = ms_since(start);
        Ok(Geometry { points, normals, planes, corners, organised, normals_ms, planes_ms, corners_ms })
    }
}
