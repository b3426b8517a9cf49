//! Voxel-grid down-sampling: one point (the centroid) per occupied cube. A
//! dense scan has far more points than planes need; thinning it first makes
//! the normals, the slowest stage, proportionally cheaper.

use datasets::InvalidSetting;
use nalgebra::Point3;
use rustc_hash::FxHashMap;
use serde::{Deserialize, Serialize};

use crate::error::Result;

#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct VoxelConfig {
    /// Edge of a voxel; 0 keeps every point (the default: an 8-beam scan is
    /// already sparse across its rings).
    pub size_m: f64,
}

pub struct VoxelFilter {
    config: VoxelConfig,
}

impl VoxelFilter {
    pub fn new(config: VoxelConfig) -> Result<Self> {
        if !(config.size_m >= 0.0 && config.size_m.is_finite()) {
            let problem = format!("{} m must be finite and >= 0", config.size_m);
            return Err(InvalidSetting::field("voxel.size_m", problem).into());
        }
        Ok(Self { config })
    }

    /// Whether `downsample` returns its input as it is (size 0).
    pub fn keeps_every_point(&self) -> bool {
        self.config.size_m <= 0.0
    }

    /// The centroids of the occupied voxels, in first-seen order (so the
    /// result does not depend on hashing).
    pub fn downsample(&self, points: &[Point3<f32>]) -> Vec<Point3<f32>> {
        let size = self.config.size_m as f32;
        if size <= 0.0 {
            return points.to_vec();
        }
        let mut slots: FxHashMap<[i32; 3], usize> = FxHashMap::default();
        let mut sums: Vec<([f64; 3], u32)> = Vec::new();
        for p in points {
            let key = [(p.x / size).floor() as i32, (p.y / size).floor() as i32, (p.z / size).floor() as i32];
            let slot = *slots.entry(key).or_insert_with(|| {
                sums.push(([0.0; 3], 0));
                sums.len() - 1
            });
            let (sum, count) = &mut sums[slot];
            sum[0] += p.x as f64;
            sum[1] += p.y as f64;
            sum[2] += p.z as f64;
            *count += 1;
        }
        sums.into_iter()
            .map(|(s, n)| {
                let n = n as f64;
                Point3::new((s[0] / n) as f32, (s[1] / n) as f32, (s[2] / n) as f32)
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn one_centroid_per_occupied_voxel() {
        let filter = VoxelFilter::new(VoxelConfig { size_m: 1.0 }).unwrap();
        let points = [
            Point3::new(0.1, 0.1, 0.1),
            Point3::new(0.3, 0.5, 0.9),
            Point3::new(1.5, 0.0, 0.0),
            Point3::new(-0.5, 0.0, 0.0),
        ];
        let out = filter.downsample(&points);
        assert_eq!(out, vec![Point3::new(0.2, 0.3, 0.5), Point3::new(1.5, 0.0, 0.0), Point3::new(-0.5, 0.0, 0.0)]);
        let keep = VoxelFilter::new(VoxelConfig::default()).unwrap();
        assert_eq!(keep.downsample(&points), points.to_vec());
        assert!(VoxelFilter::new(VoxelConfig { size_m: f64::NAN }).is_err());
    }
}
