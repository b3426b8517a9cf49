//! `pretrain --backbone faster-rcnn|vgg16|alexnet --out DIR` makes a trunk
//! to transfer from when no external weights are at hand: it generates a
//! corpus from many synthetic worlds unlike the evaluation data
//! (`DIR/corpus`), trains the network on it (`DIR/run`, resumable: run the
//! same command again), and writes the trunk as `DIR/trunk.safetensors` in
//! torchvision's naming with `DIR/meta.json`. `train --pretrained
//! DIR/trunk.safetensors` starts from it. A faster-rcnn or vgg16 trunk is
//! VGG16-shaped and serves both.

use std::collections::HashMap;
use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, Result, bail};
use clap::Parser;
use datasets::corpus::{CorpusConfig, generate_corpus};
use datasets::generate::DatagenConfig;
use infer::config::{Backbone, DEFAULT_WIDTH};
use infer::pretrained::save_trunk;
use serde::Serialize;
use train::TrainConfig;

#[derive(Debug, Parser)]
#[command(name = "pretrain", version)]
struct Args {
    /// The network trained on the corpus; its trunk is kept.
    #[arg(long, value_enum)]
    backbone: Backbone,
    /// Folder for the corpus, the training run and the trunk.
    #[arg(long)]
    out: PathBuf,
    #[arg(long, default_value_t = DEFAULT_WIDTH)]
    width: f32,
    /// Worlds of the corpus, each with its own geometry and appearance.
    #[arg(long, default_value_t = CorpusConfig::default().worlds)]
    worlds: usize,
    #[arg(long, default_value_t = CorpusConfig::default().images_per_world)]
    images_per_world: usize,
    #[arg(long, default_value_t = CorpusConfig::default().seed)]
    corpus_seed: u64,
    /// Epochs over the corpus (default: 4 for faster-rcnn, 8 for the grid networks).
    #[arg(long)]
    epochs: Option<usize>,
    #[arg(long)]
    lr: Option<f64>,
    #[arg(long, default_value_t = 42)]
    seed: u64,
}

#[derive(Debug, Serialize)]
struct TrunkMeta {
    backbone: Backbone,
    width: f32,
    corpus: CorpusConfig,
    corpus_images: usize,
    epochs: usize,
    /// AP@0.5 etc. of the pretraining network on the corpus's test split.
    corpus_test: infer::metrics::EvalMetrics,
    final_train_loss: f64,
    train_seconds: f64,
    corpus_seconds: f64,
}

pub const TRUNK_FILE: &str = "trunk.safetensors";

fn main() -> Result<()> {
    let args = Args::parse();
    if args.out.exists() && !args.out.is_dir() {
        bail!("--out {}: not a folder", args.out.display());
    }
    std::fs::create_dir_all(&args.out)?;
    let corpus_config = CorpusConfig {
        seed: args.corpus_seed,
        worlds: args.worlds,
        images_per_world: args.images_per_world,
        ..CorpusConfig::default()
    };
    let corpus_dir = args.out.join("corpus");
    let started = Instant::now();
    let corpus = generate_corpus(&corpus_dir, &corpus_config, &DatagenConfig::default())?;
    let corpus_seconds = started.elapsed().as_secs_f64();
    eprintln!(
        "corpus: {} images, {} labels from {} worlds in {}{}",
        corpus.images,
        corpus.labels,
        corpus_config.worlds,
        corpus_dir.display(),
        if corpus.reused { " (reused)".to_string() } else { format!(" ({corpus_seconds:.0} s)") }
    );

    let run = args.out.join("run");
    let config = if run.join(train::trainer::CONFIG_FILE).is_file() {
        eprintln!("continuing the pretraining run in {}", run.display());
        None
    } else {
        let mut c = TrainConfig::new(args.backbone, args.width, corpus_dir.clone());
        c.epochs = args.epochs.unwrap_or(if args.backbone == Backbone::FasterRcnn { 4 } else { 8 });
        if let Some(lr) = args.lr {
            c.lr = lr;
        }
        c.seed = args.seed;
        // The corpus's own test split measures the pretraining; no validation split needed.
        c.val_fraction = 0.0;
        Some(c)
    };
    let summary = train::train(config, &run, true)?;
    let text = datasets::atomic::read_text(&run.join(train::trainer::CONFIG_FILE))?;
    let config: TrainConfig = serde_json::from_str(&text).context("reading the run's settings")?;
    let (det, network, _) =
        infer::checkpoint::load(&run.join(train::trainer::CHECKPOINT_DIR), &burn::prelude::Device::flex())?;
    let meta = TrunkMeta {
        backbone: det.backbone,
        width: det.width,
        corpus: corpus_config,
        corpus_images: corpus.images,
        epochs: config.epochs,
        corpus_test: summary.metrics.clone(),
        final_train_loss: summary.final_train_loss,
        train_seconds: summary.seconds,
        corpus_seconds,
    };
    let header = HashMap::from([
        ("format".to_string(), "torchvision-named trunk".to_string()),
        ("meta".to_string(), serde_json::to_string(&meta)?),
    ]);
    save_trunk(&network, det.backbone, &args.out.join(TRUNK_FILE), header)?;
    datasets::atomic::write_json(&args.out.join("meta.json"), &meta)?;
    println!(
        "trunk in {}; corpus test AP@0.5 {:.3}; {:.0} s of training",
        args.out.join(TRUNK_FILE).display(),
        summary.metrics.ap50,
        summary.seconds
    );
    Ok(())
}
