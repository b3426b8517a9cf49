//! What can stop training, pretraining or the reading of a run: each error
//! names the file or setting it concerns and keeps its cause as the source.

use std::path::{Path, PathBuf};

use datasets::DataError;
use infer::checkpoint::CheckpointError;
use infer::pretrained::PretrainedError;

#[derive(Debug, thiserror::Error)]
pub enum TrainError {
    /// Settings that cannot train.
    #[error("invalid setting: {0}")]
    Settings(#[from] datasets::InvalidSetting),
    /// A run or data folder that is not what the command needs.
    #[error("{}: {what}", path.display())]
    Folder { path: PathBuf, what: String },
    #[error("{}: cannot create the folder", path.display())]
    Create {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// `--resume` of a folder without a run.
    #[error("nothing to resume")]
    NothingToResume(#[source] DataError),
    /// A JSON file the run wrote (settings, state, metrics) that does not read back.
    #[error("{}: invalid {what}", path.display())]
    Json {
        path: PathBuf,
        what: &'static str,
        #[source]
        source: serde_json::Error,
    },
    /// A loss log that is not `train`'s.
    #[error("{}: {what}", path.display())]
    LossLog { path: PathBuf, what: String },
    #[error("the loss became {loss} at epoch {epoch} iteration {iteration}: lower --lr")]
    Diverged { loss: f64, epoch: usize, iteration: usize },
    #[error("{what} the optimizer state")]
    Optimizer {
        what: &'static str,
        #[source]
        source: burn::store::RecordError,
    },
    #[error(transparent)]
    Data(#[from] DataError),
    #[error("loading the resume weights")]
    ResumeWeights(#[source] CheckpointError),
    #[error(transparent)]
    Checkpoint(#[from] CheckpointError),
    #[error(transparent)]
    Pretrained(#[from] PretrainedError),
    #[error(transparent)]
    Backend(#[from] infer::backend::BackendError),
}

pub type Result<T, E = TrainError> = std::result::Result<T, E>;

/// Parses `text`, read from the JSON file at `path` that holds the run's `what`.
pub(crate) fn parse_json<T: serde::de::DeserializeOwned>(path: &Path, what: &'static str, text: &str) -> Result<T> {
    serde_json::from_str(text).map_err(|source| TrainError::Json { path: path.to_path_buf(), what, source })
}

/// Reads and parses the JSON file at `path` that holds the run's `what`.
pub(crate) fn read_json<T: serde::de::DeserializeOwned>(path: &Path, what: &'static str) -> Result<T> {
    parse_json(path, what, &datasets::atomic::read_text(path)?)
}
