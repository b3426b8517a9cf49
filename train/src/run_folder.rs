//! The folder of a training run and its layout:
//! - `train_config.json`: the resolved settings;
//! - `losses.csv`: the loss log ([`LossLog`]);
//! - `resume/`: model, optimizer and progress after the last full epoch;
//! - `checkpoint/`: the folder `infer` and `localize` load;
//! - `metrics.json`: AP@0.5, precision, recall, pixel error on the test split;
//! - `pretrained.json`: with a trunk file to start from, what was loaded.
//!
//! Every file is replaced atomically, so a run killed at any moment resumes
//! from its last completed epoch.

use std::path::{Path, PathBuf};

use burn::optim::ModuleOptimizer;
use burn::prelude::Device;
use infer::checkpoint::{self, CheckpointMeta};
use infer::config::DetectorConfig;
use infer::metrics::EvalMetrics;
use infer::network::Network;
use infer::pretrained::ImportReport;
use serde::{Deserialize, Serialize};

use crate::config::TrainConfig;
use crate::error::{Result, TrainError, parse_json, read_json};
use crate::loss_log::LossLog;

pub const CONFIG_FILE: &str = "train_config.json";
pub const LOSSES_FILE: &str = "losses.csv";
pub const RESUME_DIR: &str = "resume";
pub const CHECKPOINT_DIR: &str = "checkpoint";
pub const METRICS_FILE: &str = "metrics.json";
/// What a trunk file gave: tensors, unused ones, the input convention.
pub const PRETRAINED_FILE: &str = "pretrained.json";
const STATE_FILE: &str = "state.json";
const OPTIMIZER_STEM: &str = "optimizer";

/// How far a run has come: completed epochs, training time, the loss log.
#[derive(Debug, Clone)]
pub struct Progress {
    pub epochs_done: usize,
    pub elapsed_s: f64,
    pub log: LossLog,
}

/// `resume/state.json` as written (the log as its CSV text).
#[derive(Serialize, Deserialize)]
struct ResumeState {
    epochs_done: usize,
    elapsed_s: f64,
    csv: String,
}

#[derive(Debug, Clone)]
pub struct RunFolder {
    root: PathBuf,
}

impl RunFolder {
    pub fn new(root: &Path) -> Self {
        Self { root: root.to_path_buf() }
    }

    pub fn root(&self) -> &Path {
        &self.root
    }

    pub fn config_path(&self) -> PathBuf {
        self.root.join(CONFIG_FILE)
    }

    pub fn losses_path(&self) -> PathBuf {
        self.root.join(LOSSES_FILE)
    }

    pub fn checkpoint_dir(&self) -> PathBuf {
        self.root.join(CHECKPOINT_DIR)
    }

    pub fn metrics_path(&self) -> PathBuf {
        self.root.join(METRICS_FILE)
    }

    fn resume_dir(&self) -> PathBuf {
        self.root.join(RESUME_DIR)
    }

    /// Whether the folder holds a run (its settings were written).
    pub fn holds_run(&self) -> bool {
        self.config_path().is_file()
    }

    /// The settings of the run in the folder, and its progress if an epoch
    /// completed, after clearing what a kill can leave behind: temporary
    /// files, and the resume state renamed aside between the two renames of
    /// its replacement.
    pub fn read_for_resume(&self) -> Result<(TrainConfig, Option<Progress>)> {
        datasets::atomic::remove_leftovers(&self.root)?;
        datasets::atomic::recover_dir(&self.resume_dir())?;
        let path = self.config_path();
        let text = datasets::atomic::read_text(&path).map_err(TrainError::NothingToResume)?;
        let config: TrainConfig = parse_json(&path, "settings", &text)?;
        // A settings file edited by hand is checked as the command line is.
        config.validate().map_err(|e| datasets::DataError::setting(&path, e))?;
        let state_path = self.resume_dir().join(STATE_FILE);
        if !state_path.is_file() {
            return Ok((config, None));
        }
        let state: ResumeState = read_json(&state_path, "state")?;
        // A state is written after a completed epoch, and a run stops after its last.
        if !(1..=config.epochs).contains(&state.epochs_done) {
            return Err(TrainError::Folder {
                path: state_path,
                what: format!(
                    "says {} epochs are done of the {} the settings ask for: not a state this run wrote",
                    state.epochs_done, config.epochs
                ),
            });
        }
        let log = LossLog::parse(&state.csv).map_err(|what| TrainError::LossLog { path: state_path, what })?;
        Ok((config, Some(Progress { epochs_done: state.epochs_done, elapsed_s: state.elapsed_s, log })))
    }

    /// The network and optimizer state saved after the last completed epoch.
    pub fn load_resume(
        &self,
        det: &DetectorConfig,
        optim: ModuleOptimizer,
        device: &Device,
    ) -> Result<(Network, ModuleOptimizer)> {
        let dir = self.resume_dir();
        let network = checkpoint::load_weights(&dir, det, device).map_err(TrainError::ResumeWeights)?;
        let optim = optim
            .load(dir.join(format!("{OPTIMIZER_STEM}.bpk")))
            .map_err(|source| TrainError::Optimizer { what: "loading", source })?;
        Ok((network, optim))
    }

    /// Creates the folder with the run's settings (and what a trunk file
    /// gave), once they proved usable.
    pub fn write_settings(&self, config: &TrainConfig, pretrained: Option<&ImportReport>) -> Result<()> {
        std::fs::create_dir_all(&self.root).map_err(|source| TrainError::Create { path: self.root.clone(), source })?;
        datasets::atomic::write_json(&self.config_path(), config)?;
        if let Some(report) = pretrained {
            datasets::atomic::write_json(&self.root.join(PRETRAINED_FILE), report)?;
        }
        Ok(())
    }

    /// After an epoch: the loss log, the resume state and the checkpoint.
    pub fn save_epoch(
        &self,
        det: &DetectorConfig,
        network: &Network,
        optim: &ModuleOptimizer,
        progress: &Progress,
        meta: &CheckpointMeta,
    ) -> Result<()> {
        let csv = progress.log.to_csv();
        datasets::atomic::write_bytes(&self.losses_path(), csv.as_bytes())?;
        let state = ResumeState { epochs_done: progress.epochs_done, elapsed_s: progress.elapsed_s, csv };
        datasets::atomic::write_dir(&self.resume_dir(), |tmp| -> Result<()> {
            checkpoint::save_weights(network, &tmp.join(checkpoint::WEIGHTS_STEM))?;
            optim.save(tmp.join(OPTIMIZER_STEM)).map_err(|source| TrainError::Optimizer { what: "writing", source })?;
            datasets::atomic::write_json(&tmp.join(STATE_FILE), &state)?;
            Ok(())
        })?;
        checkpoint::save(&self.checkpoint_dir(), det, network, meta)?;
        Ok(())
    }

    /// At the end: the test metrics, and the checkpoint that carries them.
    pub fn save_result(
        &self,
        det: &DetectorConfig,
        network: &Network,
        metrics: &EvalMetrics,
        meta: &CheckpointMeta,
    ) -> Result<()> {
        datasets::atomic::write_json(&self.metrics_path(), metrics)?;
        checkpoint::save(&self.checkpoint_dir(), det, network, meta)?;
        Ok(())
    }
}
