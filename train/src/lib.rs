//! Training of the detectors: target assignment, losses, the training loop
//! with its loss log, resumable state and checkpoints.

pub mod compare;
pub mod config;
pub mod error;
pub mod feature_cache;
pub mod fused_adamw;
pub mod loss_log;
pub mod losses;
pub mod pretrain;
pub mod run_folder;
pub mod step;
pub mod targets;
pub mod trainer;

pub use config::{OptimizerKind, Start, TrainConfig};
pub use error::TrainError;
pub use loss_log::LossLog;
pub use run_folder::RunFolder;
pub use trainer::{TrainSummary, train};
