//! `train --backbone faster-rcnn|vgg16|alexnet --data DIR --out RUN_DIR`
//! trains a detector; `train --resume RUN_DIR` continues an interrupted run.

use std::path::PathBuf;

use anyhow::{Result, bail};
use clap::Parser;
use infer::backend::ComputeBackend;
use infer::config::{Backbone, DEFAULT_WIDTH, GridHead};
use infer::pretrained::InputConvention;
use train::{OptimizerKind, TrainConfig};

#[derive(Debug, Parser)]
#[command(name = "train", version, allow_negative_numbers = true)]
struct Args {
    #[arg(long, value_enum, required_unless_present = "resume")]
    backbone: Option<Backbone>,
    /// A `datagen` detection folder (train.json, test.json, images/).
    #[arg(long, required_unless_present = "resume")]
    data: Option<PathBuf>,
    /// Run folder: settings, loss log, checkpoints, metrics.
    #[arg(long, required_unless_present = "resume")]
    out: Option<PathBuf>,
    /// Continue the run in this folder from its last completed epoch, with
    /// the settings in its config.json (flags that would change them are
    /// refused: a resumed run ends as the uninterrupted one would).
    #[arg(long, conflicts_with_all = [
        "backbone", "data", "out", "epochs", "batch_size", "optimizer", "lr", "seed", "width", "no_augment",
        "adaptive_canny", "gray_channel", "backend", "hidden", "grid_head", "pretrained", "pretrained_input", "pretrained_prune", "freeze", "no_cache",
    ])]
    resume: Option<PathBuf>,
    /// Epochs (default: 24 for faster-rcnn and vgg16, 40 for alexnet).
    #[arg(long, value_parser = datasets::cli::positive_count)]
    epochs: Option<usize>,
    #[arg(long, default_value_t = 8, value_parser = datasets::cli::positive_count)]
    batch_size: usize,
    #[arg(long, value_enum, default_value_t = OptimizerKind::Adam)]
    optimizer: OptimizerKind,
    /// Peak learning rate (default: 1e-3 for faster-rcnn and vgg16, 2e-3 for
    /// alexnet; 2e-4 when --pretrained is a whole checkpoint).
    #[arg(long, value_parser = datasets::cli::positive)]
    lr: Option<f64>,
    #[arg(long, default_value_t = 42)]
    seed: u64,
    /// Channel multiplier; 1.0 is torchvision's full network.
    #[arg(long, default_value_t = DEFAULT_WIDTH)]
    width: f32,
    /// Turn off the random left-right flips.
    #[arg(long)]
    no_augment: bool,
    /// Canny thresholds from each image's own gradients (a quantile of its
    /// gradient magnitudes, calibrated to match the fixed 15/40 on rendered
    /// rooms) instead of the paper's fixed ones; the checkpoint keeps the
    /// choice, so inference preprocesses the same way.
    #[arg(long)]
    adaptive_canny: bool,
    /// Give the network the grayscale image as a second input channel beside
    /// the Canny edges (the paper's network sees the edges alone); a
    /// --pretrained detector of the edges alone starts it with the new
    /// channel's weights at zero.
    #[arg(long)]
    gray_channel: bool,
    #[arg(long, value_enum, default_value_t)]
    backend: ComputeBackend,
    /// Width of the fully connected layers (default: 4096 x width^2, at least 64).
    #[arg(long, value_parser = datasets::cli::positive_count)]
    hidden: Option<usize>,
    /// Head of vgg16 and alexnet: convolutional (one output per cell), or
    /// torchvision's fully connected classifier with its last layer replaced.
    #[arg(long, value_enum, default_value_t)]
    grid_head: GridHead,
    /// Start from these weights. A file starts the trunk: torchvision-named
    /// `.pth`/`.pt` or `.safetensors` (VGG16, AlexNet, HED), or a trunk
    /// written by `pretrain`. A checkpoint folder of the same backbone and
    /// width starts every layer, trunk and heads (fine-tuning a detector,
    /// e.g. `pretrain`'s `detector/`).
    #[arg(long)]
    pretrained: Option<PathBuf>,
    /// How the pretrained network expected its input.
    #[arg(long, value_enum, default_value_t, requires = "pretrained")]
    pretrained_input: InputConvention,
    /// When the pretrained trunk is wider than --width, keep each layer's
    /// strongest filters (largest L1 norm) instead of refusing it.
    #[arg(long, requires = "pretrained")]
    pretrained_prune: bool,
    /// Keep the first N trunk convolutions at their starting weights.
    #[arg(long, default_value_t = 0, value_parser = datasets::cli::count)]
    freeze: usize,
    /// Run the frozen layers on every step instead of caching their outputs.
    #[arg(long)]
    no_cache: bool,
}

fn main() -> std::process::ExitCode {
    // Training and detection free and reallocate the same large buffers.
    infer::allocator::keep_freed_memory();
    datasets::cli::exit_code(run_main())
}

fn run_main() -> Result<()> {
    let args = Args::parse();
    let (config, run) = match (&args.resume, args.backbone, &args.data, &args.out) {
        (Some(run), ..) => (None, run.clone()),
        (None, Some(backbone), Some(data), Some(out)) => {
            if !data.is_dir() {
                bail!("--data {}: not a folder", data.display());
            }
            if train::RunFolder::new(out).holds_run() {
                bail!(
                    "--out {} already holds a run: use --resume {} to continue it, or another folder",
                    out.display(),
                    out.display()
                );
            }
            // Another command's folder (a localization run, a dataset) would lose its files to ours.
            if let Ok(entries) = std::fs::read_dir(out) {
                let mut names: Vec<String> =
                    entries.filter_map(|e| e.ok()).map(|e| e.file_name().to_string_lossy().into_owned()).collect();
                if !names.is_empty() {
                    names.sort();
                    names.truncate(3);
                    bail!(
                        "--out {}: not empty (it holds {}, ...): give a new or empty folder",
                        out.display(),
                        names.join(", ")
                    );
                }
            }
            // Kept absolute: `--resume` may run from another working directory.
            let data = std::path::absolute(data).map_err(|e| datasets::DataError::io(data, e))?;
            let mut c = TrainConfig::new(backbone, args.width, data);
            if let Some(e) = args.epochs {
                c.epochs = e;
            }
            c.batch_size = args.batch_size;
            c.optimizer = args.optimizer;
            c.seed = args.seed;
            c.augment = !args.no_augment;
            if args.adaptive_canny {
                c.detector.preprocess.adaptive_canny = Some(Default::default());
            }
            c.detector.set_gray_channel(args.gray_channel);
            c.backend = args.backend;
            if let Some(h) = args.hidden {
                c.detector.hidden = h;
            }
            c.detector.grid_head = args.grid_head;
            if let Some(p) = &args.pretrained
                && !p.exists()
            {
                bail!("--pretrained {}: no such file or checkpoint folder", p.display());
            }
            if let Some(p) = &args.pretrained {
                c.start_from(train::Start::from_path(p.clone()));
            }
            // An explicit --lr wins over the start's default.
            if let Some(lr) = args.lr {
                c.lr = lr;
            }
            c.pretrained_input = args.pretrained_input;
            c.pretrained_prune = args.pretrained_prune;
            c.freeze = args.freeze;
            c.cache_frozen = !args.no_cache;
            // Settings are checked before the run folder exists.
            c.validate().map_err(train::TrainError::Settings)?;
            (Some(c), out.clone())
        }
        _ => bail!("give --backbone, --data and --out, or --resume RUN_DIR"),
    };
    std::fs::create_dir_all(&run).map_err(|e| datasets::DataError::io(&run, e))?;
    let summary = train::train(config, &run, true)?;
    let m = &summary.metrics;
    println!(
        "final train loss {:.4}{}; test AP@0.5 {:.3}, precision {:.3}, recall {:.3}, pixel error {:.2} px; {:.0} s; run in {}",
        summary.final_train_loss,
        summary.final_valid_loss.map(|v| format!(", valid loss {v:.4}")).unwrap_or_default(),
        m.ap50,
        m.precision,
        m.recall,
        m.mean_pixel_error.unwrap_or(f64::NAN),
        summary.seconds,
        run.display()
    );
    Ok(())
}
