//! Every setting of localization, one section per stage; `localize run
//! --config FILE` reads it as JSON (missing fields keep their defaults) and
//! the run folder keeps the resolved copy.

use datasets::InvalidSetting;
use serde::{Deserialize, Serialize};

use crate::estimation::ekf::EkfConfig;
use crate::estimation::fusion::FusionConfig;
use crate::estimation::landmarks::LandmarkConfig;
use crate::estimation::level_floor::LevelFloorConfig;
use crate::estimation::plane_landmarks::PlaneLandmarkConfig;
use crate::estimation::pose::PoseConfig;
use crate::estimation::relocalize::RelocalizeConfig;
use crate::estimation::scan_match::ScanMatchConfig;
use crate::input::rgbd_sequence::DepthOptions;
use crate::input::sequence::SyncConfig;
use crate::scan::corners::CornerConfig;
use crate::scan::normals::NormalConfig;
use crate::scan::planes::PlaneConfig;
use crate::scan::voxel::VoxelConfig;

#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct LocalizeConfig {
    pub voxel: VoxelConfig,
    pub normals: NormalConfig,
    pub planes: PlaneConfig,
    pub corners: CornerConfig,
    pub fusion: FusionConfig,
    pub landmarks: LandmarkConfig,
    pub plane_landmarks: PlaneLandmarkConfig,
    pub scan_match: ScanMatchConfig,
    pub pose: PoseConfig,
    pub ekf: EkfConfig,
    pub sync: SyncConfig,
    /// Placing a new sequence's first scan in a saved map (`localize run --map`).
    pub relocalize: RelocalizeConfig,
    /// Level floors as a roll and pitch reading.
    pub level_floor: LevelFloorConfig,
    /// Depth images as scans (RGB-D input).
    pub depth: DepthOptions,
}

/// Largest count a setting may ask for (points, votes, observations).
const MAX_COUNT: usize = 10_000_000;

impl LocalizeConfig {
    /// The paper's estimator: corners and walls with odometry/IMU, the
    /// detector on every image, without the scan-to-map registration and
    /// the level floors this project adds.
    pub fn paper_estimator() -> Self {
        let mut config = Self::default();
        config.scan_match.enabled = false;
        config.level_floor.enabled = false;
        config.sync.detector_rate_hz = 0.0;
        config
    }

    /// The per-scan geometry stages of these settings.
    pub fn geometry_stages(&self) -> crate::error::Result<crate::scan::geometry::GeometryStages> {
        crate::scan::geometry::GeometryStages::new(&self.voxel, &self.normals, &self.planes, &self.corners)
    }

    /// `self` with the settings of a `--config` file's JSON over it (fields
    /// the file leaves out keep `self`'s), checked.
    pub fn overlaid(&self, file: &serde_json::Value) -> Result<Self, String> {
        let config = datasets::settings_file::overlay(self, file)?;
        config.validate().map_err(|e| e.to_string())?;
        Ok(config)
    }

    /// Checks every setting against the range where it means something; the
    /// message names the section and field (`normals.neighbours`).
    pub fn validate(&self) -> Result<(), InvalidSetting> {
        self.validate_scan_stages()?;
        self.validate_estimator()?;
        self.scan_match.validate().map_err(|e| e.within("scan_match"))?;
        self.sync.validate().map_err(|e| e.within("sync"))?;
        self.relocalize.validate().map_err(|e| e.within("relocalize"))?;
        self.depth.validate().map_err(|e| e.within("depth"))?;
        self.level_floor.validate().map_err(|e| e.within("level_floor"))
    }

    /// The per-scan stages: down-sampling, normals, planes, corners.
    fn validate_scan_stages(&self) -> Result<(), InvalidSetting> {
        let range = InvalidSetting::range;
        let (positive, non_negative, count) =
            (InvalidSetting::positive, InvalidSetting::non_negative, InvalidSetting::count);
        non_negative("voxel.size_m", self.voxel.size_m, 5.0)?;
        count("normals.neighbours", self.normals.neighbours, 3, 1000)?;
        self.normals.organised.validate().map_err(|e| e.within("normals.organised"))?;
        let p = &self.planes;
        positive("planes.angle_bin_deg", p.angle_bin_deg, 90.0)?;
        positive("planes.distance_bin_m", p.distance_bin_m, 10.0)?;
        positive("planes.max_curvature", p.max_curvature, 1.0)?;
        count("planes.min_votes", p.min_votes, 1, MAX_COUNT)?;
        count("planes.min_inliers", p.min_inliers, 3, MAX_COUNT)?;
        positive("planes.inlier_distance_m", p.inlier_distance_m, 10.0)?;
        positive("planes.inlier_angle_deg", p.inlier_angle_deg, 90.0)?;
        non_negative("planes.merge_angle_deg", p.merge_angle_deg, 90.0)?;
        non_negative("planes.merge_distance_m", p.merge_distance_m, 10.0)?;
        count("planes.max_planes", p.max_planes, 1, 1000)?;
        let c = &self.corners;
        non_negative("corners.min_conditioning", c.min_conditioning, 1.0)?;
        positive("corners.support_radius_m", c.support_radius_m, 10.0)?;
        non_negative("corners.support_range_fraction", c.support_range_fraction, 1.0)?;
        count("corners.min_support", c.min_support, 0, MAX_COUNT)?;
        non_negative("corners.merge_radius_m", c.merge_radius_m, 10.0)?;
        non_negative("corners.edge_min_angle_deg", c.edge_min_angle_deg, 180.0)?;
        range("corners.edge_max_angle_deg", c.edge_max_angle_deg, c.edge_min_angle_deg, 180.0, false)?;
        Ok(())
    }

    /// Fusion, landmarks, the pose solve and the filter.
    fn validate_estimator(&self) -> Result<(), InvalidSetting> {
        let (positive, non_negative, count) =
            (InvalidSetting::positive, InvalidSetting::non_negative, InvalidSetting::count);
        let f = &self.fusion;
        positive("fusion.gate_m", f.gate_m, 100.0)?;
        positive("fusion.surface_radius_m", f.surface_radius_m, 100.0)?;
        non_negative("fusion.min_score", f64::from(f.min_score), 1.0)?;
        let l = &self.landmarks;
        positive("landmarks.gate_m", l.gate_m, 100.0)?;
        count("landmarks.min_observations", l.min_observations as usize, 0, MAX_COUNT)?;
        positive("landmarks.max_spread_m", l.max_spread_m, 100.0)?;
        count("landmarks.max_observations", l.max_observations as usize, 1, MAX_COUNT)?;
        let w = &self.plane_landmarks;
        count("plane_landmarks.min_inliers", w.min_inliers, 3, MAX_COUNT)?;
        positive("plane_landmarks.angle_gate_deg", w.angle_gate_deg, 90.0)?;
        positive("plane_landmarks.distance_gate_m", w.distance_gate_m, 100.0)?;
        positive("plane_landmarks.distance_sigma_m", w.distance_sigma_m, 100.0)?;
        positive("plane_landmarks.normal_sigma_rad", w.normal_sigma_rad, std::f64::consts::PI)?;
        positive("plane_landmarks.range_scale_m", w.range_scale_m, 1000.0)?;
        positive("plane_landmarks.max_weight", w.max_weight, 1e6)?;
        count("plane_landmarks.min_observations", w.min_observations as usize, 0, MAX_COUNT)?;
        positive("plane_landmarks.max_offset_spread_m", w.max_offset_spread_m, 100.0)?;
        positive("plane_landmarks.max_normal_spread_deg", w.max_normal_spread_deg, 180.0)?;
        non_negative("plane_landmarks.max_wall_tilt_deg", w.max_wall_tilt_deg, 90.0)?;
        non_negative("plane_landmarks.rectilinear_gate_deg", w.rectilinear_gate_deg, 45.0)?;
        let o = &self.pose;
        positive("pose.corner_sigma_m", o.corner_sigma_m, 100.0)?;
        positive("pose.huber", o.huber, 1000.0)?;
        count("pose.iterations", o.iterations, 1, 1000)?;
        count("pose.min_matches", o.min_matches, 1, MAX_COUNT)?;
        positive("pose.seed_gate_m", o.seed_gate_m, 100.0)?;
        non_negative("pose.scan_pinned_m", o.scan_pinned_m, 100.0)?;
        non_negative("pose.scan_pinned_rad", o.scan_pinned_rad, std::f64::consts::PI)?;
        let e = &self.ekf;
        for (name, v) in [
            ("ekf.gyro_noise_rps", e.gyro_noise_rps),
            ("ekf.speed_noise_mps", e.speed_noise_mps),
            ("ekf.bias_walk", e.bias_walk),
            ("ekf.scale_walk", e.scale_walk),
            ("ekf.initial_bias_rps", e.initial_bias_rps),
            ("ekf.initial_scale", e.initial_scale),
            ("ekf.initial_accel_bias_mps2", e.initial_accel_bias_mps2),
            ("ekf.gravity_sigma_rad", e.gravity_sigma_rad),
            ("ekf.gravity_gate_mps2", e.gravity_gate_mps2),
            ("ekf.gravity_gate_chi2", e.gravity_gate_chi2),
            ("ekf.ramp_slip_per_s", e.ramp_slip_per_s),
            ("ekf.velocity_change_mps2", e.velocity_change_mps2),
            ("ekf.rate_change_rps2", e.rate_change_rps2),
            ("ekf.unknown_velocity_mps", e.unknown_velocity_mps),
            ("ekf.unknown_rate_rps", e.unknown_rate_rps),
        ] {
            non_negative(name, v, 1000.0)?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_pass_and_absurd_or_nan_settings_are_named() {
        LocalizeConfig::default().validate().unwrap();
        let with = |f: &dyn Fn(&mut LocalizeConfig)| {
            let mut c = LocalizeConfig::default();
            f(&mut c);
            c.validate().unwrap_err()
        };
        let many = with(&|c| c.normals.neighbours = 100_000);
        assert_eq!(many.to_string(), "normals.neighbours: 100000 outside 3..=1000");
        let nan = with(&|c| c.pose.huber = f64::NAN);
        assert_eq!((nan.field.as_str(), nan.problem.starts_with("NaN")), ("pose.huber", true));
        assert_eq!(with(&|c| c.voxel.size_m = -0.1).field, "voxel.size_m");
        assert_eq!(with(&|c| c.fusion.min_score = 1.5).field, "fusion.min_score");
        assert_eq!(with(&|c| c.corners.edge_max_angle_deg = 1.0).field, "corners.edge_max_angle_deg");
        assert_eq!(with(&|c| c.ekf.bias_walk = f64::INFINITY).field, "ekf.bias_walk");
        assert_eq!(with(&|c| c.sync.image_tolerance_s = -1.0).field, "sync.image_tolerance_s");
        assert_eq!(with(&|c| c.sync.detector_rate_hz = f64::NAN).field, "sync.detector_rate_hz");
        assert_eq!(with(&|c| c.scan_match.map_voxel_m = 0.0).field, "scan_match.map_voxel_m");
        assert_eq!(with(&|c| c.level_floor.max_split_sigmas = f64::NAN).field, "level_floor.max_split_sigmas");
        // A ramp cannot be less tilted than what counts as level.
        assert_eq!(with(&|c| c.level_floor.ramp_max_tilt_deg = 1.0).field, "level_floor.ramp_max_tilt_deg");
    }

    #[test]
    fn a_file_overlays_only_the_fields_it_names() {
        let mut base = LocalizeConfig::default();
        base.scan_match.source_voxel_m = 0.05;
        let file = serde_json::json!({"scan_match": {"iterations": 4}, "sync": {"deskew": false}});
        let config = base.overlaid(&file).unwrap();
        assert_eq!((config.scan_match.source_voxel_m, config.scan_match.iterations), (0.05, 4));
        assert!(!config.sync.deskew && config.sync.camera_motion);
        let unknown = base.overlaid(&serde_json::json!({"scan_match": {"iteration": 4}})).unwrap_err();
        assert!(unknown.contains("unknown field `iteration`"), "{unknown}");
        let bad = base.overlaid(&serde_json::json!({"pose": {"huber": -1.0}})).unwrap_err();
        assert!(bad.contains("pose.huber"), "{bad}");
    }
}
