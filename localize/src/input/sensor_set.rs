//! Which sensors a recording has, found from the recording itself, and the
//! settings that follow from them. The paper's rig (LIDAR, IMU, wheels,
//! camera) keeps every default. Height, roll and pitch are held by gravity
//! and by wheels on their floor together; without either, the scan
//! registration measures all six directions. Without wheels no floor is
//! known to be level under the sensor. A depth camera sees metres, not tens
//! of metres, so its scans are thinned and mapped at a finer scale.

use std::fmt;

use serde::{Deserialize, Serialize};

use crate::config::LocalizeConfig;
pub use crate::input::sequence::RangeSensor;
use crate::input::sequence::SensorSequence;

/// The sensors a run uses.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct SensorSet {
    pub range: RangeSensor,
    pub imu: bool,
    pub wheels: bool,
    pub camera: bool,
}

impl SensorSet {
    /// The sensors of `sequence`; `camera` whether its images are used.
    pub fn of(sequence: &dyn SensorSequence, camera: bool) -> Self {
        Self {
            range: sequence.range_sensor(),
            imu: !sequence.imu().is_empty(),
            wheels: !sequence.odometry().is_empty(),
            camera,
        }
    }

    /// The default settings for these sensors, before a `--config` file.
    pub fn default_config(&self) -> LocalizeConfig {
        let mut config = LocalizeConfig::default();
        self.adapt(&mut config);
        config
    }

    /// Changes the settings that these sensors decide (`config` is left as
    /// it is for the paper's rig).
    pub fn adapt(&self, config: &mut LocalizeConfig) {
        if !(self.imu && self.wheels) {
            // Height, roll and pitch are held by gravity and by wheels on
            // their floor together; without either, the registration
            // measures them too.
            config.scan_match.horizontal_only = false;
        }
        if !self.wheels {
            // A level floor under the sensor is a ground robot's.
            config.level_floor.enabled = false;
        }
        if self.range == RangeSensor::DepthCamera {
            let s = &mut config.scan_match;
            s.source_voxel_m = 0.05;
            s.map_voxel_m = 0.2;
            s.map_spacing_m = 0.02;
            s.max_distance_m = 0.1;
            // A handheld camera's motion is not the last frame's carried
            // on: across a wide baseline the correspondences are searched
            // wide first.
            s.wide_baseline_distance_m = Some(0.2);
            s.iterations = 20;
            s.point_sigma_m = 0.01;
            // Kinect-like depth is noisy beyond a metre or two: only the
            // flattest patches (edges and clutter give wrong normals).
            s.max_curvature = 0.02;
            s.floor_m = 0.002;
            s.floor_rad = 0.001;
            // A handheld camera has no building axis to square walls with.
            config.plane_landmarks.rectilinear_gate_deg = 0.0;
        }
    }
}

impl fmt::Display for SensorSet {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let range = match self.range {
            RangeSensor::Lidar => "3D LIDAR",
            RangeSensor::DepthCamera => "depth camera",
        };
        let mut parts = vec![range];
        parts.extend(
            [(self.imu, "IMU"), (self.wheels, "wheel odometry"), (self.camera, "camera")]
                .iter()
                .filter_map(|&(on, name)| on.then_some(name)),
        );
        let missing: Vec<&str> = [(self.imu, "IMU"), (self.wheels, "wheels")]
            .iter()
            .filter_map(|&(on, name)| (!on).then_some(name))
            .collect();
        write!(f, "{}", parts.join(" + "))?;
        if !missing.is_empty() {
            write!(f, " (no {}: the previous motion carries on)", missing.join(", no "))?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_papers_rig_keeps_every_default_and_the_others_say_what_changes() {
        let full = SensorSet { range: RangeSensor::Lidar, imu: true, wheels: true, camera: true };
        assert_eq!(full.default_config(), LocalizeConfig::default());
        assert_eq!(full.to_string(), "3D LIDAR + IMU + wheel odometry + camera");
        let with_imu = SensorSet { wheels: false, ..full };
        assert!(!with_imu.default_config().scan_match.horizontal_only, "no wheels on the floor: z is the scan's");
        let lidar_only = SensorSet { imu: false, wheels: false, camera: false, ..full };
        let config = lidar_only.default_config();
        assert!(!config.scan_match.horizontal_only && !config.level_floor.enabled);
        assert_eq!(lidar_only.to_string(), "3D LIDAR (no IMU, no wheels: the previous motion carries on)");
        let rgbd = SensorSet { range: RangeSensor::DepthCamera, ..lidar_only };
        let config = rgbd.default_config();
        config.validate().unwrap();
        assert!(config.scan_match.source_voxel_m < LocalizeConfig::default().scan_match.source_voxel_m);
    }
}
