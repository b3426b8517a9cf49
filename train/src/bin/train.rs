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
    /// Continue the run in this folder from its last completed epoch, with
    /// the settings in its train_config.json (flags that would change them
    /// are refused: a resumed run ends as the uninterrupted one would).
    #[arg(long, conflicts_with = "settings")]
    resume: Option<PathBuf>,
    #[command(flatten)]
    settings: SettingsArgs,
}

/// A new run's settings: the defaults of the backbone (`TrainConfig::new`),
/// then the `--config` file, then these flags.
#[derive(Debug, clap::Args)]
#[group(id = "settings", multiple = true)]
struct SettingsArgs {
    #[arg(long, value_enum, required_unless_present = "resume")]
    backbone: Option<Backbone>,
    /// A `datagen` detection folder (train.json, test.json, images/).
    #[arg(long, required_unless_present = "resume")]
    data: Option<PathBuf>,
    /// Run folder: settings, loss log, checkpoints, metrics.
    #[arg(long, required_unless_present = "resume")]
    out: Option<PathBuf>,
    /// Settings as JSON: any subset of a run's train_config.json (its `data`
    /// and the detector's backbone stay those of the flags).
    #[arg(long)]
    config: Option<PathBuf>,
    /// Epochs (default: 24 for faster-rcnn and vgg16, 40 for alexnet).
    #[arg(long, value_parser = datasets::cli::positive_count)]
    epochs: Option<usize>,
    /// Images a step (default 8).
    #[arg(long, value_parser = datasets::cli::positive_count)]
    batch_size: Option<usize>,
    /// Default: adam.
    #[arg(long, value_enum)]
    optimizer: Option<OptimizerKind>,
    /// Peak learning rate (default: 1e-3 for faster-rcnn and vgg16, 2e-3 for
    /// alexnet; 2e-4 when --pretrained is a whole checkpoint).
    #[arg(long, value_parser = datasets::cli::positive)]
    lr: Option<f64>,
    /// Default 42.
    #[arg(long)]
    seed: Option<u64>,
    /// Channel multiplier; 1.0 is torchvision's full network (default 0.25).
    #[arg(long)]
    width: Option<f32>,
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
    /// Default: flex.
    #[arg(long, value_enum)]
    backend: Option<ComputeBackend>,
    /// Width of the fully connected layers (default: 4096 x width^2, at least 64).
    #[arg(long, value_parser = datasets::cli::positive_count)]
    hidden: Option<usize>,
    /// Head of vgg16 and alexnet: convolutional (one output per cell, the
    /// default), or torchvision's fully connected classifier with its last
    /// layer replaced.
    #[arg(long, value_enum)]
    grid_head: Option<GridHead>,
    /// Start from these weights. A file starts the trunk: torchvision-named
    /// `.pth`/`.pt` or `.safetensors` (VGG16, AlexNet, HED), or a trunk
    /// written by `pretrain`. A checkpoint folder of the same backbone and
    /// width starts every layer, trunk and heads (fine-tuning a detector,
    /// e.g. `pretrain`'s `detector/`).
    #[arg(long)]
    pretrained: Option<PathBuf>,
    /// How the pretrained network expected its input (default: auto).
    #[arg(long, value_enum, requires = "pretrained")]
    pretrained_input: Option<InputConvention>,
    /// When the pretrained trunk is wider than --width, keep each layer's
    /// strongest filters (largest L1 norm) instead of refusing it.
    #[arg(long, requires = "pretrained")]
    pretrained_prune: bool,
    /// Keep the first N trunk convolutions at their starting weights (default 0).
    #[arg(long, value_parser = datasets::cli::count)]
    freeze: Option<usize>,
    /// Run the frozen layers on every step instead of caching their outputs.
    #[arg(long)]
    no_cache: bool,
}

impl SettingsArgs {
    /// The run's settings: defaults, the file, the flags; checked.
    fn resolve(&self, backbone: Backbone, data: PathBuf) -> Result<TrainConfig> {
        let mut c = TrainConfig::new(backbone, self.width.unwrap_or(DEFAULT_WIDTH), data.clone());
        if let Some(p) = &self.pretrained {
            if !p.exists() {
                bail!("--pretrained {}: no such file or checkpoint folder", p.display());
            }
            c.start_from(train::Start::from_path(p.clone()));
        }
        if let Some(path) = &self.config {
            let file = datasets::settings_file::read(path)?;
            c = datasets::settings_file::overlay(&c, &file)
                .map_err(|m| anyhow::anyhow!("{}: not a training config: {m}", path.display()))?;
            if c.detector.backbone != backbone {
                bail!(
                    "{}: its detector's backbone is {}, but --backbone is {backbone}",
                    path.display(),
                    c.detector.backbone
                );
            }
            c.data = data;
        }
        if let Some(width) = self.width {
            c.detector.width = width;
        }
        if let Some(e) = self.epochs {
            c.epochs = e;
        }
        set(&mut c.batch_size, self.batch_size);
        set(&mut c.optimizer, self.optimizer);
        set(&mut c.seed, self.seed);
        set(&mut c.backend, self.backend);
        set(&mut c.detector.hidden, self.hidden);
        set(&mut c.detector.grid_head, self.grid_head);
        set(&mut c.lr, self.lr);
        set(&mut c.pretrained_input, self.pretrained_input);
        set(&mut c.freeze, self.freeze);
        c.augment &= !self.no_augment;
        c.pretrained_prune |= self.pretrained_prune;
        c.cache_frozen &= !self.no_cache;
        if self.adaptive_canny {
            c.detector.preprocess.adaptive_canny = Some(Default::default());
        }
        if self.gray_channel {
            c.detector.set_gray_channel(true);
        }
        // Settings are checked before the run folder exists.
        c.validate().map_err(train::TrainError::Settings)?;
        Ok(c)
    }
}

/// A flag given replaces the setting.
fn set<T>(slot: &mut T, flag: Option<T>) {
    if let Some(value) = flag {
        *slot = value;
    }
}

fn main() -> std::process::ExitCode {
    // Training and detection free and reallocate the same large buffers.
    infer::kernels::allocator::keep_freed_memory();
    datasets::cli::exit_code(run_main())
}

fn run_main() -> Result<()> {
    let args = Args::parse();
    let flags = &args.settings;
    let (config, run) = match (&args.resume, flags.backbone, &flags.data, &flags.out) {
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
            (Some(flags.resolve(backbone, data)?), out.clone())
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
