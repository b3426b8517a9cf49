//! What can stop the experiment: each error names the folder or file of the
//! stage it concerns and keeps the stage's own error as its source.

use std::path::PathBuf;

#[derive(Debug, thiserror::Error)]
pub enum ReproduceError {
    /// A folder or file the experiment needs that is not there or not usable.
    #[error("{}: {what}", path.display())]
    Missing { path: PathBuf, what: String },
    /// A file-system step (creating, clearing, reading) that failed.
    #[error("{}: cannot {what}", path.display())]
    Io {
        path: PathBuf,
        what: &'static str,
        #[source]
        source: std::io::Error,
    },
    #[error("recording a stage's inputs and outputs")]
    Record(#[from] serde_json::Error),
    #[error(transparent)]
    Data(#[from] datasets::DataError),
    #[error(transparent)]
    Train(#[from] train::TrainError),
    #[error(transparent)]
    Checkpoint(#[from] infer::checkpoint::CheckpointError),
    #[error(transparent)]
    Backend(#[from] infer::backend::BackendError),
    #[error(transparent)]
    Localize(#[from] localize::error::LocalizeError),
}

pub type Result<T, E = ReproduceError> = std::result::Result<T, E>;
