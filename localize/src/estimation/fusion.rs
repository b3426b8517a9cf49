//! 2D-3D fusion: each detected image corner is cast as a ray from the camera
//! into the extracted planes; where the ray first meets a plane that has
//! points there, the nearest 3D corner within a gate is the match. When the
//! cloud's own corner search found none there (a LIDAR with few beams often
//! sees the floor only metres from a wall), the corner is built from the
//! planes that pass by the hit point: the detector says where to look, the
//! planes say exactly where the corner is.

use datasets::InvalidSetting;
use datasets::camera::PinholeCamera;
use datasets::math::{Pose3, Vec3};
use serde::{Deserialize, Serialize};

use crate::error::Result;
use crate::scan::corners::{CornerSet, intersect_three};
use crate::scan::planes::PlaneSet;

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct FusionConfig {
    /// A ray's hit point and a 3D corner farther apart than this do not match.
    pub gate_m: f64,
    /// A ray hits a plane only where the plane has an inlier this close
    /// (planes are infinite; surfaces are not).
    pub surface_radius_m: f64,
    /// Detections scoring lower are not used.
    pub min_score: f32,
}

impl Default for FusionConfig {
    fn default() -> Self {
        Self { gate_m: 0.35, surface_radius_m: 0.5, min_score: 0.3 }
    }
}

/// A corner seen in the image at `pixel`, found in the cloud at `position`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CornerMatch {
    pub position: Vec3,
    /// Index of the cloud corner; `None` when built from the planes at the hit.
    pub corner: Option<usize>,
    pub pixel: [f64; 2],
    /// Distance between the ray's hit point and the 3D corner.
    pub gap_m: f64,
}

/// Plane triples flatter than this (|det| of their normals) locate no corner.
const MIN_CONDITIONING: f64 = 0.15;

pub struct CornerFusion {
    config: FusionConfig,
}

impl CornerFusion {
    pub fn new(config: FusionConfig) -> Result<Self> {
        for (field, value) in [("fusion.gate_m", config.gate_m), ("fusion.surface_radius_m", config.surface_radius_m)] {
            if !(value > 0.0) {
                return Err(InvalidSetting::field(field, format!("{value} m must be > 0")).into());
            }
        }
        Ok(Self { config })
    }

    /// Matches image corners (pixels, continuous image coordinates of the
    /// camera) to the 3D corners of the cloud; one match per 3D corner, the
    /// closest.
    pub fn fuse(
        &self,
        pixels: &[[f64; 2]],
        camera: &PinholeCamera,
        lidar_from_camera: &Pose3,
        planes: &PlaneSet,
        corners: &CornerSet,
        points: &[nalgebra::Point3<f32>],
    ) -> Vec<CornerMatch> {
        let origin = lidar_from_camera.translation.vector;
        let mut found: Vec<CornerMatch> = Vec::new();
        for &pixel in pixels {
            let direction = lidar_from_camera.rotation * camera.ray(pixel[0], pixel[1]).normalize();
            let Some(hit) = self.first_surface(&origin, &direction, planes, points) else { continue };
            let nearest = corners
                .corners
                .iter()
                .enumerate()
                .map(|(k, c)| (k, (c.position - hit).norm()))
                .min_by(|a, b| a.1.total_cmp(&b.1));
            let candidate = match nearest {
                Some((k, gap_m)) if gap_m < self.config.gate_m => {
                    Some(CornerMatch { position: corners.corners[k].position, corner: Some(k), pixel, gap_m })
                }
                _ => self.corner_from_planes(&hit, planes).map(|position| CornerMatch {
                    position,
                    corner: None,
                    pixel,
                    gap_m: (position - hit).norm(),
                }),
            };
            if let Some(m) = candidate {
                // One match per corner: the closest ray wins.
                match found.iter_mut().find(|f| (f.position - m.position).norm() < 0.1) {
                    Some(f) if m.gap_m < f.gap_m => *f = m,
                    Some(_) => {}
                    None => found.push(m),
                }
            }
        }
        found
    }

    /// The best-conditioned intersection of three planes that pass within the
    /// gate of `hit` and meet within the gate of it.
    fn corner_from_planes(&self, hit: &Vec3, planes: &PlaneSet) -> Option<Vec3> {
        let near: Vec<&crate::scan::planes::Plane> =
            planes.planes.iter().filter(|p| p.signed_distance(hit).abs() < self.config.gate_m).collect();
        let mut best: Option<(f64, Vec3)> = None;
        for i in 0..near.len() {
            for j in i + 1..near.len() {
                for k in j + 1..near.len() {
                    let Some((x, conditioning)) = intersect_three([near[i], near[j], near[k]], MIN_CONDITIONING) else {
                        continue;
                    };
                    if (x - hit).norm() < self.config.gate_m && best.is_none_or(|(q, _)| conditioning > q) {
                        best = Some((conditioning, x));
                    }
                }
            }
        }
        best.map(|(_, x)| x)
    }

    /// The nearest point along the ray where it crosses a plane near one of
    /// that plane's points.
    fn first_surface(
        &self,
        origin: &Vec3,
        direction: &Vec3,
        planes: &PlaneSet,
        points: &[nalgebra::Point3<f32>],
    ) -> Option<Vec3> {
        let r2 = self.config.surface_radius_m.powi(2);
        planes
            .planes
            .iter()
            .filter_map(|plane| {
                let along = plane.normal.dot(direction);
                if along.abs() < 1e-6 {
                    return None;
                }
                let t = (plane.distance - plane.normal.dot(origin)) / along;
                let hit = origin + direction * t;
                let on_surface =
                    plane.inliers.iter().any(|&i| (points[i as usize].cast::<f64>().coords - hit).norm_squared() < r2);
                (t > 0.0 && on_surface).then_some((t, hit))
            })
            .min_by(|a, b| a.0.total_cmp(&b.0))
            .map(|(_, hit)| hit)
    }
}
