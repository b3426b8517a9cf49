//! The in-memory point cloud, and loading one by file extension (PCD, PLY,
//! KITTI `.bin`).

use std::path::Path;

use nalgebra::Point3;

use crate::error::{DataError, Result};
use crate::math::Pose3;

/// A point cloud in its sensor's frame, in metres.
#[derive(Debug, Clone, PartialEq)]
pub struct PointCloud {
    pub points: Vec<Point3<f32>>,
    /// One value per point, when the file had an intensity field.
    pub intensity: Option<Vec<f32>>,
    /// The sensor pose the file declares (PCD `VIEWPOINT`); identity otherwise.
    pub viewpoint: Pose3,
    /// Points with a NaN or infinite coordinate that were dropped on reading.
    pub dropped_non_finite: usize,
    /// Each point's time after the cloud's stamp (seconds), when the sensor
    /// gives it (a spinning LIDAR's points over its sweep).
    pub times: Option<Vec<f32>>,
}

impl PointCloud {
    pub fn new(points: Vec<Point3<f32>>, intensity: Option<Vec<f32>>) -> Self {
        Self { points, intensity, viewpoint: Pose3::identity(), dropped_non_finite: 0, times: None }
    }
    pub fn len(&self) -> usize {
        self.points.len()
    }
    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }
}

/// What a reader does with points that have a NaN or infinite coordinate
/// (organized Kinect clouds mark missing depth that way).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum NonFinite {
    /// Drop them and count them in `PointCloud::dropped_non_finite`.
    #[default]
    Drop,
    /// Fail with an error naming the first such point.
    Reject,
}

/// Points reserved ahead at most; more grow the vectors as they come.
const MAX_RESERVED_POINTS: usize = 1 << 22;

/// Collects points while applying the non-finite policy.
pub(crate) struct CloudBuilder<'a> {
    path: &'a Path,
    policy: NonFinite,
    points: Vec<Point3<f32>>,
    intensity: Option<Vec<f32>>,
    times: Option<Vec<f32>>,
    dropped: usize,
}

impl<'a> CloudBuilder<'a> {
    /// `capacity` is what the file declares: it is reserved only up to a
    /// bound, so a header that claims 10^12 points is a truncated-data
    /// error when the points run out, not an allocation that aborts.
    pub fn new(path: &'a Path, policy: NonFinite, capacity: usize, with_intensity: bool) -> Self {
        let capacity = capacity.min(MAX_RESERVED_POINTS);
        Self {
            path,
            policy,
            points: Vec::with_capacity(capacity),
            intensity: with_intensity.then(|| Vec::with_capacity(capacity)),
            times: None,
            dropped: 0,
        }
    }

    /// Keeps a time per point (seconds after the cloud's stamp).
    pub fn with_times(mut self) -> Self {
        self.times = Some(Vec::with_capacity(self.points.capacity()));
        self
    }

    /// Adds point number `index` (0-based, for the error message).
    pub fn push(&mut self, index: usize, xyz: [f32; 3], intensity: f32) -> Result<()> {
        self.push_timed(index, xyz, intensity, 0.0)
    }

    /// Adds a point with its time (kept when the builder keeps times).
    pub fn push_timed(&mut self, index: usize, xyz: [f32; 3], intensity: f32, time: f32) -> Result<()> {
        if xyz.iter().any(|v| !v.is_finite()) {
            return match self.policy {
                NonFinite::Drop => {
                    self.dropped += 1;
                    Ok(())
                }
                NonFinite::Reject => {
                    Err(DataError::invalid(self.path, format!("point {index} has a non-finite coordinate {xyz:?}")))
                }
            };
        }
        self.points.push(Point3::from(xyz));
        if let Some(values) = &mut self.intensity {
            values.push(intensity);
        }
        if let Some(values) = &mut self.times {
            values.push(time);
        }
        Ok(())
    }

    pub fn finish(self, viewpoint: Pose3) -> PointCloud {
        PointCloud {
            points: self.points,
            intensity: self.intensity,
            viewpoint,
            dropped_non_finite: self.dropped,
            times: self.times,
        }
    }
}

/// Loads a cloud by extension: `.pcd`, `.ply`, or KITTI `.bin`.
pub fn read_cloud(path: &Path, policy: NonFinite) -> Result<PointCloud> {
    let ext = path.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase);
    match ext.as_deref() {
        Some("pcd") => super::pcd::read_pcd(path, policy),
        Some("ply") => super::ply::read_ply(path, policy),
        Some("bin") => read_kitti_bin(path, policy),
        _ => Err(DataError::invalid(path, "unknown point cloud extension (expected .pcd, .ply or .bin)")),
    }
}

/// KITTI Velodyne scans: float32 records `x y z reflectance`, little endian.
pub fn read_kitti_bin(path: &Path, policy: NonFinite) -> Result<PointCloud> {
    parse_kitti_bin(path, &crate::atomic::read_bytes(path)?, policy)
}

/// A KITTI scan from the bytes of `path`.
pub fn parse_kitti_bin(path: &Path, bytes: &[u8], policy: NonFinite) -> Result<PointCloud> {
    if !bytes.len().is_multiple_of(16) {
        return Err(DataError::byte(
            path,
            (bytes.len() - bytes.len() % 16) as u64,
            format!("file size {} is not a multiple of 16 bytes (x y z i float32 records)", bytes.len()),
        ));
    }
    let n = bytes.len() / 16;
    let mut cloud = CloudBuilder::new(path, policy, n, true);
    for (i, rec) in bytes.chunks_exact(16).enumerate() {
        let f = |k: usize| f32::from_le_bytes(rec[4 * k..4 * k + 4].try_into().expect("4 bytes"));
        cloud.push(i, [f(0), f(1), f(2)], f(3))?;
    }
    Ok(cloud.finish(Pose3::identity()))
}

/// Writes a KITTI `.bin` scan (intensity 0 where the cloud has none), atomically.
pub fn write_kitti_bin(path: &Path, cloud: &PointCloud) -> Result<()> {
    let mut bytes = Vec::with_capacity(cloud.len() * 16);
    for (i, p) in cloud.points.iter().enumerate() {
        let intensity = cloud.intensity.as_ref().map_or(0.0, |v| v[i]);
        for v in [p.x, p.y, p.z, intensity] {
            bytes.extend_from_slice(&v.to_le_bytes());
        }
    }
    crate::atomic::write_bytes(path, &bytes)
}
