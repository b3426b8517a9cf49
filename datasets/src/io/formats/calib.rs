//! `calib.json`: the camera intrinsics and the rigid transforms between the
//! LIDAR, the camera and the robot base.
//!
//! ```json
//! { "camera": { "width": 640, "height": 480, "fx": 525.0, "fy": 525.0, "cx": 319.5, "cy": 239.5 },
//!   "camera_from_lidar": [[...4 rows of 4...]],
//!   "robot_from_lidar": [[...]] }
//! ```
//! Intrinsics follow the OpenCV convention (pixel centres at integers).
//! Matrices map points of the right-hand frame into the left-hand frame.

use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::camera::PinholeCamera;
use crate::error::{DataError, Result};
use crate::math::{Pose3, RowsMat4, pose_from_rows, pose_to_rows};

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct CalibFile {
    camera: PinholeCamera,
    camera_from_lidar: RowsMat4,
    #[serde(default = "identity_rows")]
    robot_from_lidar: RowsMat4,
}

fn identity_rows() -> RowsMat4 {
    pose_to_rows(&Pose3::identity())
}

/// A validated calibration.
#[derive(Debug, Clone, PartialEq)]
pub struct Calibration {
    pub camera: PinholeCamera,
    pub camera_from_lidar: Pose3,
    pub robot_from_lidar: Pose3,
}

impl Calibration {
    pub fn robot_from_camera(&self) -> Pose3 {
        self.robot_from_lidar * self.camera_from_lidar.inverse()
    }
}

pub fn read_calibration(path: &Path) -> Result<Calibration> {
    parse_calibration(path, &crate::atomic::read_text(path)?)
}

/// A calibration from the text of `path`.
pub fn parse_calibration(path: &Path, text: &str) -> Result<Calibration> {
    let file: CalibFile = serde_json::from_str(text).map_err(|e| DataError::json(path, e))?;
    file.camera.validate().map_err(|e| DataError::setting(path, e.within("camera")))?;
    let pose = |rows: &RowsMat4, name: &str| {
        pose_from_rows(rows).ok_or_else(|| {
            DataError::invalid(
                path,
                format!("{name} is not a rigid transform (finite, orthonormal rotation, last row 0 0 0 1)"),
            )
        })
    };
    Ok(Calibration {
        camera: file.camera,
        camera_from_lidar: pose(&file.camera_from_lidar, "camera_from_lidar")?,
        robot_from_lidar: pose(&file.robot_from_lidar, "robot_from_lidar")?,
    })
}

pub fn write_calibration(path: &Path, calib: &Calibration) -> Result<()> {
    let file = CalibFile {
        camera: calib.camera.clone(),
        camera_from_lidar: pose_to_rows(&calib.camera_from_lidar),
        robot_from_lidar: pose_to_rows(&calib.robot_from_lidar),
    };
    crate::atomic::write_json(path, &file)
}
