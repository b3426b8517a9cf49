//! The pinhole camera model shared by the renderer, the labels and the
//! localization's ray casting.
//!
//! Two pixel conventions meet here. Intrinsics use OpenCV's (the centre of
//! pixel `(i, j)` is at `(i, j)`); images, COCO boxes and network inputs use
//! continuous coordinates (pixel `(i, j)` covers `[i, i+1) x [j, j+1)`), the
//! convention under which resizing is a plain scale. So a point projected
//! through `K` lands at `K p + 0.5` in image coordinates, and
//! [`PinholeCamera::project`] / [`PinholeCamera::ray`] speak image
//! coordinates.

use serde::{Deserialize, Serialize};

use crate::InvalidSetting;
use crate::math::{Point3, Vec3};

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PinholeCamera {
    pub width: u32,
    pub height: u32,
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
}

impl PinholeCamera {
    /// A Kinect-like RGB camera: 640 x 480, 525 px focal length.
    pub fn kinect() -> Self {
        Self { width: 640, height: 480, fx: 525.0, fy: 525.0, cx: 319.5, cy: 239.5 }
    }

    /// A camera that can exist: its size within the image bound, focal
    /// lengths from one pixel to a hundred image widths (a long telephoto
    /// lens is about ten), the principal point no farther than an image size
    /// outside the image.
    pub fn validate(&self) -> Result<(), InvalidSetting> {
        crate::image_size::check(self.width, self.height).map_err(InvalidSetting::between)?;
        let longest = f64::from(self.width.max(self.height));
        for (field, focal) in [("fx", self.fx), ("fy", self.fy)] {
            if !(focal.is_finite() && (1.0..=100.0 * longest).contains(&focal)) {
                return Err(InvalidSetting::field(
                    field,
                    format!("focal length {} px outside [1, {}] (100 image widths)", readable(focal), 100.0 * longest),
                ));
            }
        }
        for (field, centre, size) in [("cx", self.cx, self.width), ("cy", self.cy, self.height)] {
            let size = f64::from(size);
            if !(centre.is_finite() && (-size..=2.0 * size).contains(&centre)) {
                return Err(InvalidSetting::field(
                    field,
                    format!(
                        "principal point {} outside [-{size}, {}] (an image size beyond the image)",
                        readable(centre),
                        2.0 * size
                    ),
                ));
            }
        }
        Ok(())
    }

    /// Projects a point of the camera frame (x right, y down, z forward) to
    /// image coordinates; `None` behind or on the image plane.
    pub fn project(&self, p_cam: &Point3) -> Option<[f64; 2]> {
        if p_cam.z <= 1e-9 {
            return None;
        }
        Some([self.fx * p_cam.x / p_cam.z + self.cx + 0.5, self.fy * p_cam.y / p_cam.z + self.cy + 0.5])
    }

    /// The viewing ray through image coordinates `(u, v)`, in the camera
    /// frame, with unit z component (so `t` along it is depth).
    pub fn ray(&self, u: f64, v: f64) -> Vec3 {
        Vec3::new((u - 0.5 - self.cx) / self.fx, (v - 0.5 - self.cy) / self.fy, 1.0)
    }

    pub fn contains(&self, uv: [f64; 2]) -> bool {
        uv[0] >= 0.0 && uv[1] >= 0.0 && uv[0] < self.width as f64 && uv[1] < self.height as f64
    }
}

/// A number as a person reads it: exponent notation when huge.
fn readable(value: f64) -> String {
    if value.abs() < 1e6 { format!("{value}") } else { format!("{value:e}") }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn project_and_ray_are_inverse() {
        let cam = PinholeCamera::kinect();
        let p = Point3::new(0.3, -0.2, 2.5);
        let uv = cam.project(&p).unwrap();
        let back = cam.ray(uv[0], uv[1]) * p.z;
        assert!((back - p.coords).norm() < 1e-12);
        // The optical axis hits the middle of the image.
        let centre = cam.project(&Point3::new(0.0, 0.0, 1.0)).unwrap();
        assert_eq!(centre, [320.0, 240.0]);
        assert!(cam.project(&Point3::new(0.0, 0.0, -1.0)).is_none());
    }
}
