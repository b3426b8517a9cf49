//! `pretrain --backbone faster-rcnn|vgg16|alexnet --out DIR` makes a trunk
//! to transfer from when no external weights are at hand: it generates a
//! corpus from many synthetic worlds unlike the evaluation data
//! (`DIR/corpus`), trains the network on it (`DIR/run`, resumable: run the
//! same command again), and writes the trunk as `DIR/trunk.safetensors` in
//! torchvision's naming with `DIR/meta.json`, and the whole network as the
//! checkpoint folder `DIR/detector/`. `train --pretrained
//! DIR/trunk.safetensors` starts the trunk from it; `train --pretrained
//! DIR/detector` fine-tunes the whole network. A faster-rcnn or vgg16 trunk
//! is VGG16-shaped and serves both.

use std::path::PathBuf;

use anyhow::{Result, bail};
use clap::Parser;
use datasets::simulator::corpus::CorpusConfig;
use infer::config::{Backbone, DEFAULT_WIDTH};
use train::pretrain::{PretrainConfig, pretrain};

#[derive(Debug, Parser)]
#[command(name = "pretrain", version, allow_negative_numbers = true)]
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
    #[arg(long, default_value_t = CorpusConfig::default().worlds, value_parser = datasets::cli::count)]
    worlds: usize,
    /// Generated buildings in the corpus besides the worlds (`datagen --building N`).
    #[arg(long, default_value_t = CorpusConfig::default().buildings, value_parser = datasets::cli::count)]
    buildings: usize,
    /// The number of the corpus's first generated building (6 or more: 1-5 are the benchmark's).
    #[arg(long, default_value_t = CorpusConfig::default().first_building)]
    first_building: u32,
    #[arg(long, default_value_t = CorpusConfig::default().images_per_world, value_parser = datasets::cli::positive_count)]
    images_per_world: usize,
    #[arg(long, default_value_t = CorpusConfig::default().seed)]
    corpus_seed: u64,
    /// Epochs over the corpus (default: 4 for faster-rcnn, 8 for the grid networks).
    #[arg(long, value_parser = datasets::cli::positive_count)]
    epochs: Option<usize>,
    #[arg(long, value_parser = datasets::cli::positive)]
    lr: Option<f64>,
    #[arg(long, default_value_t = 42)]
    seed: u64,
    /// The grayscale image as a second input channel beside the edges (as
    /// `train --gray-channel`).
    #[arg(long)]
    gray_channel: bool,
    /// Start the pretraining from these weights (a trunk file or a
    /// checkpoint folder, as `train --pretrained`) instead of from scratch.
    #[arg(long)]
    pretrained: Option<PathBuf>,
}

fn main() -> std::process::ExitCode {
    // Training and detection free and reallocate the same large buffers.
    infer::kernels::allocator::keep_freed_memory();
    datasets::cli::exit_code(run_main())
}

fn run_main() -> Result<()> {
    let args = Args::parse();
    if args.out.exists() && !args.out.is_dir() {
        bail!("--out {}: not a folder", args.out.display());
    }
    let mut config = PretrainConfig::new(args.backbone, args.width);
    config.detector.set_gray_channel(args.gray_channel);
    config.corpus = CorpusConfig {
        seed: args.corpus_seed,
        worlds: args.worlds,
        buildings: args.buildings,
        first_building: args.first_building,
        images_per_world: args.images_per_world,
        ..CorpusConfig::default()
    };
    if let Some(e) = args.epochs {
        config.epochs = e;
    }
    config.lr = args.lr;
    config.seed = args.seed;
    if let Some(p) = &args.pretrained
        && !p.exists()
    {
        bail!("--pretrained {}: no such file or checkpoint folder", p.display());
    }
    if let Some(p) = &args.pretrained {
        config.start = train::Start::from_path(p.clone());
    }
    let (trunk, meta) = pretrain(&args.out, &config, true)?;
    println!(
        "trunk in {}; corpus test AP@0.5 {:.3}; {:.0} s of training",
        trunk.display(),
        meta.corpus_test.ap50,
        meta.train_seconds
    );
    Ok(())
}
