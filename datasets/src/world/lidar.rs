//! A Quanergy M8-like spinning LIDAR: 8 beams between -17 and +3 degrees of
//! elevation, a full turn of azimuth, Gaussian range noise and random
//! dropouts. Points are returned in the LIDAR frame (x forward, y left, z up).

use nalgebra::Point3 as P3;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::World;
use super::layout::{mix, unit};
use super::render::gaussian;
use super::surface::SurfaceKind;
use crate::formats::PointCloud;
use crate::math::{Pose3, Vec3};

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct LidarConfig {
    pub beams: usize,
    pub min_elevation_deg: f64,
    pub max_elevation_deg: f64,
    /// Azimuth step of one firing.
    pub azimuth_step_deg: f64,
    pub range_noise_m: f64,
    pub dropout: f64,
    pub min_range_m: f64,
    pub max_range_m: f64,
}

impl Default for LidarConfig {
    fn default() -> Self {
        Self {
            beams: 8,
            min_elevation_deg: -17.0,
            max_elevation_deg: 3.0,
            azimuth_step_deg: 0.25,
            range_noise_m: 0.03,
            dropout: 0.02,
            min_range_m: 0.3,
            max_range_m: 100.0,
        }
    }
}

impl LidarConfig {
    pub fn validate(&self) -> Result<(), String> {
        if self.beams == 0 || self.beams > 256 {
            return Err(format!("beams {} outside 1..256", self.beams));
        }
        if !(self.min_elevation_deg <= self.max_elevation_deg
            && self.min_elevation_deg >= -90.0
            && self.max_elevation_deg <= 90.0)
        {
            return Err("elevations must satisfy -90 <= min <= max <= 90 deg".into());
        }
        if !(self.azimuth_step_deg > 0.01 && self.azimuth_step_deg <= 10.0) {
            return Err(format!("azimuth step {} deg outside 0.01..10", self.azimuth_step_deg));
        }
        if !(self.range_noise_m >= 0.0 && (0.0..1.0).contains(&self.dropout) && self.min_range_m < self.max_range_m) {
            return Err("range noise must be >= 0, dropout in 0..1 and min range < max range".into());
        }
        Ok(())
    }

    pub fn elevations_deg(&self) -> Vec<f64> {
        let n = self.beams;
        (0..n)
            .map(|i| {
                if n == 1 {
                    self.min_elevation_deg
                } else {
                    self.min_elevation_deg
                        + (self.max_elevation_deg - self.min_elevation_deg) * i as f64 / (n - 1) as f64
                }
            })
            .collect()
    }
}

/// One scan from `world_from_lidar`; `key` seeds its noise and dropouts.
pub fn scan(world: &World, config: &LidarConfig, world_from_lidar: &Pose3, key: u64) -> PointCloud {
    let elevations: Vec<f64> = config.elevations_deg().iter().map(|e| e.to_radians()).collect();
    let steps = (360.0 / config.azimuth_step_deg).round() as usize;
    let origin = nalgebra::Point3::from(world_from_lidar.translation.vector);
    let returns: Vec<(P3<f32>, f32)> = (0..steps)
        .into_par_iter()
        .flat_map_iter(|k| {
            let azimuth = (k as f64 * config.azimuth_step_deg).to_radians();
            let origin = &origin;
            elevations.iter().enumerate().filter_map(move |(b, &el)| {
                let id = mix(key ^ ((k * 1024 + b) as u64));
                if unit(id) < config.dropout {
                    return None;
                }
                let dir_lidar = Vec3::new(el.cos() * azimuth.cos(), el.cos() * azimuth.sin(), el.sin());
                let dir = world_from_lidar.rotation * dir_lidar;
                let hit = world.cast(origin, &dir, config.min_range_m, config.max_range_m)?;
                let range = hit.t + config.range_noise_m * gaussian(id ^ 0x1d) as f64;
                let p = dir_lidar * range;
                let surface = &world.layout.surfaces[hit.surface];
                // Reflectivity by material, dimmed at grazing incidence.
                let base = match surface.kind {
                    SurfaceKind::Floor | SurfaceKind::Ramp => 0.35,
                    SurfaceKind::Wall => 0.6,
                    SurfaceKind::Ceiling => 0.7,
                    SurfaceKind::BoxSide | SurfaceKind::BoxTop => 0.45,
                };
                let intensity = base * surface.normal.dot(&dir).abs().max(0.05);
                Some((P3::new(p.x as f32, p.y as f32, p.z as f32), intensity as f32))
            })
        })
        .collect();
    let (points, intensity): (Vec<_>, Vec<_>) = returns.into_iter().unzip();
    PointCloud::new(points, Some(intensity))
}
