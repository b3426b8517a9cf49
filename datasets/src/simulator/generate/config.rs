//! `datagen`'s settings: the world, the detection set, the sequence, the
//! sensors and their clocks, written beside the data as `datagen.json`.

use serde::{Deserialize, Serialize};

use crate::InvalidSetting;
use crate::preprocess::PreprocessConfig;
use crate::simulator::world::WorldConfig;
use crate::simulator::world::labels::LabelConfig;
use crate::simulator::world::lidar::LidarConfig;
use crate::simulator::world::motion::MotionConfig;

/// Everything `datagen` needs; written next to the results as `datagen.json`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DatagenConfig {
    pub seed: u64,
    pub world: WorldConfig,
    pub detection: DetectionConfig,
    pub sequence: SequenceConfig,
    pub labels: LabelConfig,
    pub lidar: LidarConfig,
    pub motion: MotionConfig,
    pub preprocess: PreprocessConfig,
}

impl Default for DatagenConfig {
    fn default() -> Self {
        Self {
            seed: 7,
            world: WorldConfig::default(),
            detection: DetectionConfig::default(),
            sequence: SequenceConfig::default(),
            labels: LabelConfig::default(),
            lidar: LidarConfig::default(),
            motion: MotionConfig::default(),
            preprocess: PreprocessConfig::default(),
        }
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DetectionConfig {
    /// Images in all; the first `train` form the training split, the rest the test split.
    pub images: usize,
    pub train: usize,
}

impl Default for DetectionConfig {
    fn default() -> Self {
        Self { images: 300, train: 200 }
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SequenceConfig {
    /// Robot speed along the route (the paper: 0.05 m/s).
    pub speed_mps: f64,
    /// LIDAR scan rate, and the camera's when it has none of its own (the
    /// paper: both at 1 Hz).
    pub rate_hz: f64,
    /// Frames (scans) to record; `None` drives the whole route once, up to `max_scans`.
    pub frames: Option<usize>,
    /// The most scans a whole-route sequence records: at slow speeds the
    /// sequence covers the start of the route.
    pub max_scans: Option<usize>,
    /// The camera's own frame rate; `None` takes one image per scan.
    pub camera_rate_hz: Option<f64>,
    /// Radius of the route's turns.
    pub turn_radius_m: f64,
    /// How long after each scan its image is taken, or with a camera rate
    /// of its own, the time of its first image; each image is rendered from
    /// the pose at its own time and named by it. 0, the paper's, takes scan
    /// and image together.
    pub camera_delay_s: f64,
    /// The robot starts this far along the route (a second sequence of the
    /// same building that starts elsewhere, for relocalization in a map).
    /// The ground truth stays in the building's frame.
    #[serde(skip_serializing_if = "is_zero")]
    pub start_m: f64,
}

fn is_zero(v: &f64) -> bool {
    *v == 0.0
}

impl Default for SequenceConfig {
    fn default() -> Self {
        Self {
            speed_mps: 0.05,
            rate_hz: 1.0,
            frames: None,
            max_scans: None,
            camera_rate_hz: None,
            turn_radius_m: 1.2,
            camera_delay_s: 0.0,
            start_m: 0.0,
        }
    }
}

/// The most detection images one run may write.
pub const MAX_IMAGES: usize = 100_000;
/// The most sequence frames one run may write (about three hours at 10 Hz).
pub const MAX_FRAMES: usize = 100_000;

impl DatagenConfig {
    /// The settings for building `number`: the paper's for 0; for a
    /// generated building, a robot's sensors on their own clocks: a spinning
    /// LIDAR at 10 Hz sweeping over 0.1 s, the camera at 15 Hz, odometry at
    /// 50 Hz with slip on ramps, the IMU at 200 Hz, 1 m/s, at most 3000 scans.
    pub fn for_building(number: u32) -> Self {
        let mut config = Self::default();
        config.world.building = number;
        if number == 0 {
            return config;
        }
        config.sequence = SequenceConfig {
            speed_mps: 1.0,
            rate_hz: 10.0,
            max_scans: Some(3000),
            camera_rate_hz: Some(15.0),
            camera_delay_s: 0.021,
            ..SequenceConfig::default()
        };
        config.lidar.sweep_period_s = 0.1;
        config.motion.odometry_rate_hz = 50.0;
        config.motion.imu_rate_hz = 200.0;
        config.motion.ramp_slip = 0.03;
        config
    }

    /// The long featureless corridor (`WorldConfig::corridor_m`) with a
    /// generated building's robot timing.
    pub fn for_corridor(length_m: f64) -> Self {
        let mut config = Self::for_building(1);
        config.world.building = 0;
        config.world.corridor_m = length_m;
        config
    }
}

impl DatagenConfig {
    /// Checks every section; the message names the offending field.
    pub fn validate(&self) -> Result<(), InvalidSetting> {
        self.world.validate().map_err(|e| e.within("world"))?;
        self.labels.validate().map_err(|e| e.within("labels"))?;
        self.lidar.validate().map_err(|e| e.within("lidar"))?;
        self.motion.validate().map_err(|e| e.within("motion"))?;
        self.preprocess.validate().map_err(|e| e.within("preprocess"))?;
        let d = &self.detection;
        if d.train > d.images {
            let problem = format!("{} is larger than the {} images", d.train, d.images);
            return Err(InvalidSetting::field("detection.train", problem));
        }
        let s = &self.sequence;
        if !(s.speed_mps > 0.0 && s.speed_mps <= 5.0) {
            return Err(InvalidSetting::field("sequence.speed_mps", format!("{} m/s outside (0, 5]", s.speed_mps)));
        }
        if !(s.rate_hz > 0.0 && s.rate_hz <= 100.0) {
            return Err(InvalidSetting::field("sequence.rate_hz", format!("{} Hz outside (0, 100]", s.rate_hz)));
        }
        // Bounds checked before anything is written: a few zeros too many
        // would fill the disk.
        InvalidSetting::count("detection.images", d.images, 0, MAX_IMAGES)?;
        if let Some(frames) = s.frames {
            InvalidSetting::count("sequence.frames", frames, 1, MAX_FRAMES)?;
        }
        if let Some(scans) = s.max_scans {
            InvalidSetting::count("sequence.max_scans", scans, 1, MAX_FRAMES)?;
        }
        if let Some(rate) = s.camera_rate_hz
            && !(rate > 0.0 && rate <= 100.0)
        {
            return Err(InvalidSetting::field("sequence.camera_rate_hz", format!("{rate} Hz outside (0, 100]")));
        }
        if self.lidar.sweep_period_s > 1.0 / s.rate_hz + 1e-9 {
            let problem = format!(
                "a sweep of {} s is longer than the {} s between scans (sequence.rate_hz)",
                self.lidar.sweep_period_s,
                1.0 / s.rate_hz
            );
            return Err(InvalidSetting::field("lidar.sweep_period_s", problem));
        }
        if !(s.camera_delay_s.abs() <= 1.0) {
            return Err(InvalidSetting::field(
                "sequence.camera_delay_s",
                format!("{} s outside [-1, 1]", s.camera_delay_s),
            ));
        }
        if !(s.start_m >= 0.0 && s.start_m.is_finite()) {
            return Err(InvalidSetting::field(
                "sequence.start_m",
                format!("{} m is not a distance along the route", s.start_m),
            ));
        }
        if !(s.turn_radius_m > 0.1 && s.turn_radius_m < 3.0) {
            return Err(InvalidSetting::field(
                "sequence.turn_radius_m",
                format!("{} m outside (0.1, 3)", s.turn_radius_m),
            ));
        }
        Ok(())
    }
}
