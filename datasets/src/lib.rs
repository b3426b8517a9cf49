//! The data layer of the corner-fusion localization project, in three layers
//! that depend one way (a test in `datasets/tests/layers.rs` keeps them so):
//!
//! - the shared layer at the root: errors, atomic writes, the camera model,
//!   the Canny preprocessing, seeded hashing, geometry helpers, plotting and
//!   the command-line edges every crate uses;
//! - [`io`]: the files of other tools, read and written (point clouds,
//!   trajectories, COCO, calibration, ROS 1 bags, rosbag2, MCAP);
//! - [`simulator`]: the synthetic multilevel world, its sensors, and the
//!   writers of the default data made from it (`datagen`).

pub mod atomic;
pub mod bbox;
pub mod camera;
pub mod canny;
pub mod cli;
pub mod error;
pub mod fingerprint;
pub mod image_size;
pub mod invalid_setting;
pub mod math;
pub mod plot;
pub mod preprocess;
pub mod seed;
pub mod settings_file;
pub mod undistort;

pub mod io;
pub mod simulator;

pub use error::{DataError, Result};
pub use invalid_setting::InvalidSetting;
