//! Pretraining on a generated corpus: the transfer source when no external
//! weights are at hand. Many synthetic worlds unlike the evaluation data
//! (`DIR/corpus`), a training run on them (`DIR/run`, resumable), the trunk
//! in torchvision's naming (`DIR/trunk.safetensors` + `DIR/meta.json`) that
//! `train --pretrained` accepts like external weights, and the whole network
//! as a checkpoint (`DIR/detector/`) that `train --pretrained` fine-tunes.

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

use datasets::simulator::corpus::{CorpusConfig, generate_corpus};
use datasets::simulator::generate::DatagenConfig;
use infer::config::{Backbone, DetectorConfig};
use infer::pretrained::save_trunk;
use serde::{Deserialize, Serialize};

use crate::error::{Result, TrainError, read_json};
use crate::{Start, TrainConfig};

pub const TRUNK_FILE: &str = "trunk.safetensors";
pub const META_FILE: &str = "meta.json";
/// The whole pretrained network, as a checkpoint folder.
pub const DETECTOR_DIR: &str = "detector";

/// What to pretrain, on what.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PretrainConfig {
    /// The network trained on the corpus; its trunk is kept.
    pub detector: DetectorConfig,
    pub corpus: CorpusConfig,
    pub epochs: usize,
    pub lr: Option<f64>,
    pub seed: u64,
    /// Where the pretraining itself starts (as `train --pretrained`; the
    /// peak LR stays the corpus's, also from a whole detector).
    #[serde(default)]
    pub start: Start,
}

impl PretrainConfig {
    pub fn new(backbone: Backbone, width: f32) -> Self {
        Self {
            detector: DetectorConfig::new(backbone, width),
            corpus: CorpusConfig::default(),
            epochs: if backbone == Backbone::FasterRcnn { 4 } else { 8 },
            lr: None,
            seed: 42,
            start: Start::Scratch,
        }
    }
}

/// Written beside the trunk: where it came from and how well it did.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct TrunkMeta {
    pub backbone: Backbone,
    pub width: f32,
    pub corpus: CorpusConfig,
    pub corpus_images: usize,
    pub epochs: usize,
    /// AP@0.5 etc. of the pretraining network on the corpus's test split.
    pub corpus_test: infer::metrics::EvalMetrics,
    pub final_train_loss: f64,
    pub train_seconds: f64,
    /// Rendering time; near zero when an existing corpus was reused.
    pub corpus_seconds: f64,
    #[serde(default)]
    pub corpus_reused: bool,
}

/// Generates (or reuses) the corpus, trains (or continues training) on it
/// and writes the trunk. Returns the trunk's path and its metadata.
pub fn pretrain(out: &Path, config: &PretrainConfig, show_progress: bool) -> Result<(PathBuf, TrunkMeta)> {
    std::fs::create_dir_all(out).map_err(|source| TrainError::Create { path: out.to_path_buf(), source })?;
    let corpus_dir = out.join("corpus");
    let started = Instant::now();
    let corpus = generate_corpus(&corpus_dir, &config.corpus, &DatagenConfig::default())?;
    let corpus_seconds = started.elapsed().as_secs_f64();
    eprintln!(
        "corpus: {} images, {} labels from {} worlds and {} generated buildings in {}{}",
        corpus.images,
        corpus.labels,
        config.corpus.worlds,
        config.corpus.buildings,
        corpus_dir.display(),
        if corpus.reused { " (reused)".to_string() } else { format!(" ({corpus_seconds:.0} s)") }
    );
    let run = out.join("run");
    let folder = crate::RunFolder::new(&run);
    let train_config = if folder.holds_run() {
        eprintln!("continuing the pretraining run in {}", run.display());
        None
    } else {
        let mut c = TrainConfig::new(config.detector.backbone, config.detector.width, corpus_dir.clone());
        c.detector = config.detector.clone();
        c.epochs = config.epochs;
        if let Some(lr) = config.lr {
            c.lr = lr;
        }
        c.seed = config.seed;
        c.start = config.start.clone();
        // The corpus's own test split measures the pretraining; no validation split needed.
        c.val_fraction = 0.0;
        Some(c)
    };
    let summary = crate::train(train_config, &run, show_progress)?;
    let used: TrainConfig = read_json(&folder.config_path(), "settings")?;
    let (det, network, checkpoint_meta) =
        infer::checkpoint::load(&folder.checkpoint_dir(), &burn::prelude::Device::flex())?;
    infer::checkpoint::save(&out.join(DETECTOR_DIR), &det, &network, &checkpoint_meta)?;
    let meta = TrunkMeta {
        backbone: det.backbone,
        width: det.width,
        corpus: config.corpus.clone(),
        corpus_images: corpus.images,
        epochs: used.epochs,
        corpus_test: summary.metrics.clone(),
        final_train_loss: summary.final_train_loss,
        train_seconds: summary.seconds,
        corpus_seconds,
        corpus_reused: corpus.reused,
    };
    let header = HashMap::from([
        ("format".to_string(), "torchvision-named trunk".to_string()),
        ("meta".to_string(), serde_json::to_string(&meta).expect("a struct of numbers and strings serialises")),
    ]);
    let trunk = out.join(TRUNK_FILE);
    save_trunk(&network, det.backbone, &trunk, header)?;
    datasets::atomic::write_json(&out.join(META_FILE), &meta)?;
    Ok((trunk, meta))
}
