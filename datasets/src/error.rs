//! The one error type of the data layer: every variant names the file and,
//! where it applies, the line or byte offset, so a user can find the problem.

use std::path::{Path, PathBuf};

#[derive(Debug, thiserror::Error)]
pub enum DataError {
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{path}:{line}: {message}")]
    Line { path: PathBuf, line: usize, message: String },
    #[error("{path}: byte {offset}: {message}")]
    Byte { path: PathBuf, offset: u64, message: String },
    #[error("{path}: {message}")]
    Invalid { path: PathBuf, message: String },
    /// A settings file, or the settings of the run that writes `path`, that
    /// the code cannot run with.
    #[error("{path}: {source}")]
    Setting {
        path: PathBuf,
        #[source]
        source: crate::InvalidSetting,
    },
    /// A message of a recording: `index` counts the topic's messages from 0.
    #[error("{path}: topic {topic}, message {index}: {message}")]
    Message { path: PathBuf, topic: String, index: u64, message: String },
    #[error("{path}: {source}")]
    Json {
        path: PathBuf,
        #[source]
        source: serde_json::Error,
    },
    #[error("{path}: {source}")]
    Image {
        path: PathBuf,
        #[source]
        source: image::ImageError,
    },
}

pub type Result<T, E = DataError> = std::result::Result<T, E>;

impl DataError {
    pub fn io(path: &Path, source: std::io::Error) -> Self {
        Self::Io { path: path.to_path_buf(), source }
    }
    pub fn line(path: &Path, line: usize, message: impl Into<String>) -> Self {
        Self::Line { path: path.to_path_buf(), line, message: message.into() }
    }
    pub fn byte(path: &Path, offset: u64, message: impl Into<String>) -> Self {
        Self::Byte { path: path.to_path_buf(), offset, message: message.into() }
    }
    pub fn invalid(path: &Path, message: impl Into<String>) -> Self {
        Self::Invalid { path: path.to_path_buf(), message: message.into() }
    }
    pub fn setting(path: &Path, source: crate::InvalidSetting) -> Self {
        Self::Setting { path: path.to_path_buf(), source }
    }
    pub fn message(path: &Path, topic: &str, index: u64, message: impl Into<String>) -> Self {
        Self::Message { path: path.to_path_buf(), topic: topic.to_string(), index, message: message.into() }
    }
    pub fn json(path: &Path, source: serde_json::Error) -> Self {
        Self::Json { path: path.to_path_buf(), source }
    }
    pub fn image(path: &Path, source: image::ImageError) -> Self {
        Self::Image { path: path.to_path_buf(), source }
    }
}
