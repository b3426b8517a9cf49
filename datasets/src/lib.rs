//! The data layer of the corner-fusion localization project: file formats,
//! the shared preprocessing, the camera model and the synthetic multilevel
//! world with its sensors.

pub mod atomic;
pub mod bbox;
pub mod camera;
pub mod canny;
pub mod cli;
pub mod corpus;
pub mod error;
pub mod fingerprint;
pub mod formats;
pub mod generate;
pub mod image_size;
pub mod invalid_setting;
pub mod math;
pub mod plot;
pub mod preprocess;
pub mod recording;
pub mod settings_file;
pub mod undistort;
pub mod world;

pub use error::{DataError, Result};
pub use invalid_setting::InvalidSetting;
