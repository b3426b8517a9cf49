//! Corner labels: every world corner in front of the camera, inside the
//! image, within range and not hidden behind a surface becomes a square box
//! around its projection.

use serde::{Deserialize, Serialize};

use super::World;
use super::layout::CornerKind;
use crate::InvalidSetting;
use crate::bbox::BBox;
use crate::camera::PinholeCamera;
use crate::math::{Point3, Pose3};

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct LabelConfig {
    /// Side of the square box around a corner, in image pixels. 96 px (34 x
    /// 45 px in the 224 x 224 network input) gives the box two to three cells
    /// of a stride-16 feature map: the lines that meet at a corner, not just
    /// the point, which a region-based detector needs.
    pub box_size_px: f32,
    /// Corners farther than this (depth along the optical axis) are not labeled.
    pub max_depth_m: f64,
}

impl Default for LabelConfig {
    fn default() -> Self {
        Self { box_size_px: 96.0, max_depth_m: 10.0 }
    }
}

impl LabelConfig {
    pub fn validate(&self) -> Result<(), InvalidSetting> {
        if !(self.box_size_px >= 4.0 && self.box_size_px <= 256.0) {
            return Err(InvalidSetting::field("box_size_px", format!("{} px outside [4, 256]", self.box_size_px)));
        }
        if !(self.max_depth_m > 0.5) {
            return Err(InvalidSetting::field("max_depth_m", format!("{} m must exceed 0.5 m", self.max_depth_m)));
        }
        Ok(())
    }
}

#[derive(Debug, Clone, PartialEq)]
pub struct CornerLabel {
    /// Index into the layout's corners.
    pub corner: usize,
    pub kind: CornerKind,
    /// The projected corner, in image coordinates.
    pub point: [f64; 2],
    /// The box, clipped to the image.
    pub bbox: BBox,
    pub depth_m: f64,
}

/// The visible corners in the view of `camera` at `world_from_camera`, at
/// world time `time` (people walking in front of a corner hide it; glass
/// does not).
pub fn visible_corners(
    world: &World,
    camera: &PinholeCamera,
    world_from_camera: &Pose3,
    config: &LabelConfig,
    time: f64,
) -> Vec<CornerLabel> {
    let camera_from_world = world_from_camera.inverse();
    let eye = Point3::from(world_from_camera.translation.vector);
    let mut labels = Vec::new();
    for (index, corner) in world.layout.corners.iter().enumerate() {
        let p_world = Point3::from(corner.position);
        let p_cam = camera_from_world * p_world;
        if p_cam.z < 0.2 || p_cam.z > config.max_depth_m {
            continue;
        }
        let Some(uv) = camera.project(&p_cam) else {
            continue;
        };
        if !camera.contains(uv) {
            continue;
        }
        // Hidden if any surface lies on the sight line clearly before the corner.
        let to = p_world - eye;
        let distance = to.norm();
        let tolerance = (0.01 * distance).max(0.02);
        if world.blocked(&eye, &(to / distance), 1e-4, distance - tolerance, time) {
            continue;
        }
        let size = config.box_size_px;
        let bbox = BBox::around(uv[0] as f32, uv[1] as f32, size).clip(camera.width as f32, camera.height as f32);
        labels.push(CornerLabel { corner: index, kind: corner.kind, point: uv, bbox, depth_m: p_cam.z });
    }
    labels
}
