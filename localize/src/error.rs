//! The error type of localization. Data-file problems keep the file name and
//! line of the data layer's error; the others say which input or setting is wrong.

use std::path::PathBuf;

#[derive(Debug, thiserror::Error)]
pub enum LocalizeError {
    #[error(transparent)]
    Data(#[from] datasets::DataError),
    #[error("invalid setting: {0}")]
    Config(String),
    #[error("point cloud: {0}")]
    Cloud(String),
    #[error("{path}: {message}")]
    Sequence { path: PathBuf, message: String },
    #[error("detector checkpoint {path}: {message}")]
    Detector { path: PathBuf, message: String },
}

pub type Result<T, E = LocalizeError> = std::result::Result<T, E>;
