//! Where the sensors sit on the robot (a Kobuki-like base with a Kinect and
//! an M8 on a mast).

use nalgebra::{Matrix3, Translation3};

use crate::camera::PinholeCamera;
use crate::io::formats::Calibration;
use crate::math::{Pose3, Rot3, Vec3};

#[derive(Debug, Clone, PartialEq)]
pub struct Rig {
    pub camera: PinholeCamera,
    pub robot_from_camera: Pose3,
    pub robot_from_lidar: Pose3,
}

impl Default for Rig {
    fn default() -> Self {
        Self {
            camera: PinholeCamera::kinect(),
            robot_from_camera: optical_mount(Vec3::new(0.12, 0.0, 0.45), 8f64.to_radians()),
            robot_from_lidar: Pose3::from_parts(Translation3::new(0.0, 0.0, 0.75), Rot3::identity()),
        }
    }
}

impl Rig {
    pub fn calibration(&self) -> Calibration {
        Calibration {
            camera: self.camera.clone(),
            camera_from_lidar: self.robot_from_camera.inverse() * self.robot_from_lidar,
            robot_from_lidar: self.robot_from_lidar,
        }
    }
}

/// A camera at `position` looking forward, tilted up by `tilt_rad`, with the
/// optical frame's axes (x right, y down, z forward).
pub fn optical_mount(position: Vec3, tilt_rad: f64) -> Pose3 {
    let (s, c) = tilt_rad.sin_cos();
    let z = Vec3::new(c, 0.0, s);
    let x = Vec3::new(0.0, -1.0, 0.0);
    let y = z.cross(&x);
    let rotation = Rot3::from_matrix(&Matrix3::from_columns(&[x, y, z]));
    Pose3::from_parts(Translation3::from(position), rotation)
}
