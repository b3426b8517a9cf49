//! The data layer of the corner-fusion localization project: file formats,
//! the shared preprocessing, the camera model and the synthetic multilevel
//! world with its sensors.

pub mod atomic;
pub mod bbox;
pub mod camera;
pub mod error;
pub mod formats;
pub mod generate;
pub mod math;
pub mod preprocess;
pub mod world;

pub use error::{DataError, Result};
