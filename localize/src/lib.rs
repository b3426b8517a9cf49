//! Localization: planes and 3D corners from LIDAR scans, 2D corners from the
//! detector cast into them, corner landmarks, the pose that aligns them with
//! an odometry/IMU prior, and trajectory metrics.

// In folders by role: recordings in, one scan's geometry, the estimator,
// the metrics, the labels; `run` ties them into `localize run`.
pub mod estimation;
pub mod evaluation;
pub mod input;
pub mod labels;
pub mod scan;

pub mod config;
pub mod error;
pub mod map_output;
pub mod run;
