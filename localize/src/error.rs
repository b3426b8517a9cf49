//! The error type of localization. Data-file problems keep the file name and
//! line of the data layer's error, checkpoint problems the detector's error;
//! the others say which input or setting is wrong.

use std::path::PathBuf;

#[derive(Debug, thiserror::Error)]
pub enum LocalizeError {
    #[error(transparent)]
    Data(#[from] datasets::DataError),
    /// A setting the stages cannot run with.
    #[error("invalid setting: {0}")]
    Setting(#[from] datasets::InvalidSetting),
    /// A recording with nothing to localize, or whose sensor logs do not
    /// cover its scans.
    #[error("{0}")]
    Recording(String),
    #[error("point cloud: {0}")]
    Cloud(String),
    /// The first scan could not be placed in the given map.
    #[error("placing the first scan (at {stamp:.3} s) in the map: {why}")]
    Relocalize { stamp: f64, why: String },
    #[error("{path}: {message}")]
    Sequence { path: PathBuf, message: String },
    #[error(transparent)]
    Detector(#[from] infer::checkpoint::CheckpointError),
    /// A trajectory that cannot be compared with its reference.
    #[error("{path}: {source}")]
    Compare {
        path: PathBuf,
        #[source]
        source: crate::evaluation::eval::EvalError,
    },
}

pub type Result<T, E = LocalizeError> = std::result::Result<T, E>;
