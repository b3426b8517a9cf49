//! The training settings, written to the run folder as `train_config.json`
//! so that a run can be resumed and reproduced.

use std::path::{Path, PathBuf};

use datasets::InvalidSetting;
use infer::backend::ComputeBackend;
use infer::config::{Backbone, DetectorConfig};
use infer::pretrained::InputConvention;
use serde::{Deserialize, Serialize};

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "kebab-case")]
pub enum OptimizerKind {
    /// Adam with decoupled weight decay (AdamW).
    Adam,
    /// SGD with momentum 0.9 (no dampening, as PyTorch).
    Sgd,
}

/// Where a run's weights start.
#[derive(Debug, Clone, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Start {
    /// Every layer from its random initialisation.
    #[default]
    Scratch,
    /// The trunk from a weights file (torchvision-named `.pth` or
    /// `.safetensors`, HED, or a `pretrain` trunk); the heads from scratch.
    Trunk(PathBuf),
    /// Every layer from a checkpoint folder of the same network
    /// (fine-tuning a detector).
    Detector(PathBuf),
}

impl Start {
    /// What `--pretrained PATH` names: a folder is a checkpoint, a file a trunk.
    pub fn from_path(path: PathBuf) -> Self {
        if path.is_dir() { Self::Detector(path) } else { Self::Trunk(path) }
    }

    pub fn path(&self) -> Option<&Path> {
        match self {
            Self::Scratch => None,
            Self::Trunk(p) | Self::Detector(p) => Some(p),
        }
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TrainConfig {
    pub detector: DetectorConfig,
    /// A `datagen` detection folder with `train.json` and `test.json`.
    pub data: PathBuf,
    pub epochs: usize,
    pub batch_size: usize,
    pub optimizer: OptimizerKind,
    /// Peak learning rate; a linear warm-up leads to it, a cosine decays it to 1% by the end.
    pub lr: f64,
    pub weight_decay: f64,
    pub warmup_iterations: usize,
    pub seed: u64,
    /// Share of the training split held out for the validation loss.
    pub val_fraction: f32,
    /// Random left-right flips of the training images.
    pub augment: bool,
    pub backend: ComputeBackend,
    /// Where the weights start.
    #[serde(default)]
    pub start: Start,
    /// How the pretrained network expected its input (see `infer::pretrained`).
    #[serde(default)]
    pub pretrained_input: InputConvention,
    /// Keep each layer's strongest filters when the pretrained trunk is
    /// wider than ours (magnitude pruning).
    #[serde(default)]
    pub pretrained_prune: bool,
    /// The first this many trunk convolutions keep their starting weights.
    #[serde(default)]
    pub freeze: usize,
    /// Compute the frozen layers' outputs once instead of on every step.
    #[serde(default = "yes")]
    pub cache_frozen: bool,
}

fn yes() -> bool {
    true
}

/// Peak learning rate when every layer starts from a trained detector (a
/// checkpoint folder as `pretrained`): a fifth of the from-trunk default,
/// because the from-trunk rate moves a detector that already fits away from
/// what it knows (the validation losses of both are in docs/detectors.md,
/// Transfer learning and comparing runs).
pub const WHOLE_NETWORK_LR: f64 = 2e-4;

/// The most epochs a run may ask for.
pub const MAX_EPOCHS: usize = 10_000;
/// The largest batch (images a step).
pub const MAX_BATCH: usize = 4096;

impl TrainConfig {
    /// Defaults measured to work on the default data (see docs/detectors.md).
    pub fn new(backbone: Backbone, width: f32, data: PathBuf) -> Self {
        let (epochs, lr) = match backbone {
            Backbone::FasterRcnn => (24, 1e-3),
            Backbone::Vgg16 => (24, 1e-3),
            Backbone::Alexnet => (40, 2e-3),
        };
        Self {
            detector: DetectorConfig::new(backbone, width),
            data,
            epochs,
            batch_size: 8,
            optimizer: OptimizerKind::Adam,
            lr,
            weight_decay: 1e-4,
            warmup_iterations: 50,
            seed: 42,
            val_fraction: 0.1,
            augment: true,
            backend: ComputeBackend::Flex,
            start: Start::Scratch,
            pretrained_input: InputConvention::Auto,
            pretrained_prune: false,
            freeze: 0,
            cache_frozen: true,
        }
    }

    /// Starts from `start`; a whole detector lowers the peak LR to
    /// [`WHOLE_NETWORK_LR`].
    pub fn start_from(&mut self, start: Start) {
        if matches!(start, Start::Detector(_)) {
            self.lr = WHOLE_NETWORK_LR;
        }
        self.start = start;
    }

    pub fn validate(&self) -> Result<(), InvalidSetting> {
        self.detector.validate().map_err(|e| e.within("detector"))?;
        // Bounds a run can reach: a typo of a few zeros would never end.
        InvalidSetting::count("epochs", self.epochs, 1, MAX_EPOCHS)?;
        InvalidSetting::count("batch_size", self.batch_size, 1, MAX_BATCH)?;
        if !(self.lr > 0.0 && self.lr < 1.0) {
            return Err(InvalidSetting::field("lr", format!("{} outside (0, 1)", self.lr)));
        }
        if !(self.weight_decay.is_finite() && self.weight_decay >= 0.0) {
            return Err(InvalidSetting::field(
                "weight_decay",
                format!("{} must be finite and >= 0", self.weight_decay),
            ));
        }
        let convs = self.detector.backbone.trunk_convs();
        if self.freeze > convs {
            let problem = format!("{} but the {} trunk has {convs} convolutions", self.freeze, self.detector.backbone);
            return Err(InvalidSetting::field("freeze", problem));
        }
        if self.pretrained_prune && matches!(self.start, Start::Detector(_)) {
            return Err(InvalidSetting::field(
                "pretrained_prune",
                "applies to trunk files, not to a checkpoint folder",
            ));
        }
        if !(0.0..0.9).contains(&self.val_fraction) {
            return Err(InvalidSetting::field("val_fraction", format!("{} outside [0, 0.9)", self.val_fraction)));
        }
        Ok(())
    }

    /// The learning rate at `iteration` of `total`: linear warm-up (cut to a
    /// fifth of short runs), then a cosine decay to 1% of the peak.
    pub fn lr_at(&self, iteration: usize, total: usize) -> f64 {
        let warmup = self.warmup_iterations.min(total / 5);
        let warm = if warmup > 0 { ((iteration + 1) as f64 / warmup as f64).min(1.0) } else { 1.0 };
        let progress = iteration as f64 / total.max(1) as f64;
        let cosine = 0.01 + 0.99 * 0.5 * (1.0 + (std::f64::consts::PI * progress).cos());
        self.lr * warm * cosine
    }
}
