//! A Quanergy M8-like spinning LIDAR: 8 beams between -17 and +3 degrees of
//! elevation, a full turn of azimuth, Gaussian range noise and random
//! dropouts. Points are returned in the LIDAR frame (x forward, y left, z up).
//!
//! A scan is either instantaneous (the paper's setting) or a sweep: the head
//! turns once over `sweep_period_s`, each firing in the LIDAR frame of its
//! own moment and stamped with its time after the sweep's start, so the
//! robot's motion during the turn distorts the cloud as on a real robot.

use nalgebra::Point3 as P3;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::render::gaussian;
use super::surface::SurfaceKind;
use super::{Seen, World};
use crate::InvalidSetting;
use crate::io::formats::PointCloud;
use crate::math::{Point3, Pose3, Vec3};
use crate::seed::{mix, unit};

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
    /// Time of one turn of the head; 0 fires every azimuth at once.
    pub sweep_period_s: f64,
    /// Fraction of the beams that meet glass and pass through it.
    pub glass_pass: f64,
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
            sweep_period_s: 0.0,
            glass_pass: 0.7,
        }
    }
}

impl LidarConfig {
    pub fn validate(&self) -> Result<(), InvalidSetting> {
        if self.beams == 0 || self.beams > 256 {
            return Err(InvalidSetting::field("beams", format!("{} outside 1..=256", self.beams)));
        }
        if !(self.min_elevation_deg >= -90.0 && self.min_elevation_deg <= self.max_elevation_deg) {
            let problem =
                format!("{} deg outside [-90, max_elevation_deg {}]", self.min_elevation_deg, self.max_elevation_deg);
            return Err(InvalidSetting::field("min_elevation_deg", problem));
        }
        if !(self.max_elevation_deg <= 90.0) {
            return Err(InvalidSetting::field(
                "max_elevation_deg",
                format!("{} deg is above 90", self.max_elevation_deg),
            ));
        }
        if !(self.azimuth_step_deg > 0.01 && self.azimuth_step_deg <= 10.0) {
            return Err(InvalidSetting::field(
                "azimuth_step_deg",
                format!("{} outside (0.01, 10]", self.azimuth_step_deg),
            ));
        }
        if !(self.range_noise_m >= 0.0 && self.range_noise_m.is_finite()) {
            return Err(InvalidSetting::field(
                "range_noise_m",
                format!("{} must be finite and >= 0", self.range_noise_m),
            ));
        }
        if !(0.0..1.0).contains(&self.dropout) {
            return Err(InvalidSetting::field("dropout", format!("{} outside [0, 1)", self.dropout)));
        }
        if !(self.min_range_m >= 0.0 && self.min_range_m < self.max_range_m && self.max_range_m.is_finite()) {
            let problem = format!(
                "min_range_m {} and max_range_m {} must satisfy 0 <= min < max",
                self.min_range_m, self.max_range_m
            );
            return Err(InvalidSetting::between(problem));
        }
        if !(0.0..=1.0).contains(&self.sweep_period_s) {
            return Err(InvalidSetting::field("sweep_period_s", format!("{} s outside [0, 1]", self.sweep_period_s)));
        }
        if !(0.0..=1.0).contains(&self.glass_pass) {
            return Err(InvalidSetting::field("glass_pass", format!("{} outside [0, 1]", self.glass_pass)));
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

/// One instantaneous scan from `world_from_lidar` at world time `time`;
/// `key` seeds its noise and dropouts.
pub fn scan(world: &World, config: &LidarConfig, world_from_lidar: &Pose3, time: f64, key: u64) -> PointCloud {
    fire(world, config, &|_| (*world_from_lidar, time), key, false)
}

/// One sweep that starts at world time `start`: the firing at azimuth step
/// `k` of `n` happens at `start + k / n * sweep_period_s`, from
/// `world_from_lidar(that time)`, and its point keeps that time after
/// `start` (`PointCloud::times`).
pub fn sweep(
    world: &World,
    config: &LidarConfig,
    world_from_lidar: &(dyn Fn(f64) -> Pose3 + Sync),
    start: f64,
    key: u64,
) -> PointCloud {
    let steps = (360.0 / config.azimuth_step_deg).round() as usize;
    let period = config.sweep_period_s;
    let column_time = |k: usize| period * k as f64 / steps as f64;
    fire(world, config, &|k| (world_from_lidar(start + column_time(k)), start + column_time(k)), key, true)
}

/// Fires every azimuth step `k` from the pose and world time `at(k)` gives;
/// a `timed` cloud keeps each point's time after the first firing.
fn fire(
    world: &World,
    config: &LidarConfig,
    at: &(dyn Fn(usize) -> (Pose3, f64) + Sync),
    key: u64,
    timed: bool,
) -> PointCloud {
    let elevations: Vec<f64> = config.elevations_deg().iter().map(|e| e.to_radians()).collect();
    let steps = (360.0 / config.azimuth_step_deg).round() as usize;
    let start = at(0).1;
    let returns: Vec<(P3<f32>, f32, f32)> = (0..steps)
        .into_par_iter()
        .flat_map_iter(|k| {
            let azimuth = (k as f64 * config.azimuth_step_deg).to_radians();
            let (world_from_lidar, time) = at(k);
            let origin = nalgebra::Point3::from(world_from_lidar.translation.vector);
            elevations.iter().enumerate().filter_map(move |(b, &el)| {
                let id = mix(key ^ ((k * 1024 + b) as u64));
                if unit(id) < config.dropout {
                    return None;
                }
                let dir_lidar = Vec3::new(el.cos() * azimuth.cos(), el.cos() * azimuth.sin(), el.sin());
                let dir = world_from_lidar.rotation * dir_lidar;
                let (t, intensity) = first_return(world, config, &origin, &dir, time, id)?;
                let range = t + config.range_noise_m * gaussian(id ^ 0x1d) as f64;
                let p = dir_lidar * range;
                Some((P3::new(p.x as f32, p.y as f32, p.z as f32), intensity as f32, (time - start) as f32))
            })
        })
        .collect();
    let mut points = Vec::with_capacity(returns.len());
    let mut intensity = Vec::with_capacity(returns.len());
    let mut times = Vec::with_capacity(returns.len());
    for (p, i, t) in returns {
        points.push(p);
        intensity.push(i);
        times.push(t);
    }
    let mut cloud = PointCloud::new(points, Some(intensity));
    cloud.times = timed.then_some(times);
    cloud
}

/// The range and intensity of a beam's return: glass lets `glass_pass` of
/// the beams through, people return like clothing.
fn first_return(
    world: &World,
    config: &LidarConfig,
    origin: &Point3,
    dir: &Vec3,
    time: f64,
    id: u64,
) -> Option<(f64, f64)> {
    let mut t_min = config.min_range_m;
    for layer in 0..4u64 {
        let hit = world.sense(origin, dir, t_min, config.max_range_m, time)?;
        let (base, normal) = match hit.seen {
            Seen::Person(_) => (0.3, hit.normal),
            Seen::Surface(index) => {
                let surface = &world.layout.surfaces[index];
                if surface.kind == SurfaceKind::Glass && unit(id ^ (0x61a55 + layer)) < config.glass_pass {
                    t_min = hit.t + 1e-4;
                    continue;
                }
                // Reflectivity by material, dimmed at grazing incidence.
                let base = match surface.kind {
                    SurfaceKind::Floor | SurfaceKind::Ramp => 0.35,
                    SurfaceKind::Wall => 0.6,
                    SurfaceKind::Ceiling => 0.7,
                    SurfaceKind::BoxSide | SurfaceKind::BoxTop => 0.45,
                    SurfaceKind::Furniture => 0.4,
                    SurfaceKind::Glass => 0.15,
                };
                (base, surface.normal)
            }
        };
        return Some((hit.t, base * normal.dot(dir).abs().max(0.05)));
    }
    None
}
