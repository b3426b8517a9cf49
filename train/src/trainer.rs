//! The training loop: mini-batches, the optimizer and its learning-rate
//! schedule, the loss log, a resumable state after every epoch, an
//! inference checkpoint, and the final evaluation on the test split.
//!
//! A run folder holds:
//! - `train_config.json`: the resolved settings;
//! - `losses.csv`: `kind,epoch,iteration,loss,<4 parts>,lr,elapsed_s` where
//!   `kind` is `train` (one row per iteration), `train_epoch` or
//!   `valid_epoch` (means over an epoch);
//! - `resume/`: model, optimizer and progress after the last full epoch;
//! - `checkpoint/`: the folder `infer` and `localize` load;
//! - `metrics.json`: AP@0.5, precision, recall, pixel error on the test split;
//! - `pretrained.json`: with `--pretrained`, what was loaded from where.

use std::fmt::Write as _;
use std::path::Path;
use std::time::Instant;

use burn::grad_clipping::GradientClippingConfig;
use burn::optim::decay::WeightDecayConfig;
use burn::optim::momentum::MomentumConfig;
use burn::optim::{GradientsParams, ModuleOptimizer, SgdConfig};

use crate::fused_adamw::FusedAdamW;
use burn::prelude::*;
use indicatif::{ProgressBar, ProgressStyle};
use rand::SeedableRng;
use rand::rngs::ChaCha8Rng;
use rand::seq::SliceRandom;
use serde::{Deserialize, Serialize};

use crate::config::{OptimizerKind, Start, TrainConfig};
use crate::error::{Result, TrainError, parse_json, read_json};
use crate::feature_cache::{FeatureCache, MAX_CACHE_BYTES};
use crate::losses::{FASTER_RCNN_PARTS, GRID_PARTS};
use crate::step::batch_losses;
use infer::checkpoint::{self, CheckpointMeta};
use infer::config::Backbone;
use infer::labeled::{LabeledImage, load_coco_set};
use infer::metrics::EvalMetrics;
use infer::network::Network;
use infer::pretrained::load_trunk;
use infer::{Detector, eval};

pub const CONFIG_FILE: &str = "train_config.json";
pub const LOSSES_FILE: &str = "losses.csv";
pub const RESUME_DIR: &str = "resume";
pub const CHECKPOINT_DIR: &str = "checkpoint";
pub const METRICS_FILE: &str = "metrics.json";
/// What `--pretrained` loaded: tensors, unused ones, the input convention.
pub const PRETRAINED_FILE: &str = "pretrained.json";
const STATE_FILE: &str = "state.json";
const OPTIMIZER_STEM: &str = "optimizer";

/// Progress after a completed epoch.
#[derive(Debug, Clone, Serialize, Deserialize)]
struct ResumeState {
    epochs_done: usize,
    elapsed_s: f64,
    csv: String,
}

#[derive(Debug, Clone)]
pub struct TrainSummary {
    pub metrics: EvalMetrics,
    pub final_train_loss: f64,
    pub final_valid_loss: Option<f64>,
    pub seconds: f64,
}

fn mix(a: u64, b: u64) -> u64 {
    datasets::world::layout::mix(a ^ datasets::world::layout::mix(b))
}

fn optimizer(config: &TrainConfig) -> ModuleOptimizer {
    let clip = Some(GradientClippingConfig::Norm(10.0));
    match config.optimizer {
        OptimizerKind::Adam => FusedAdamW::new(config.weight_decay as f32).init(clip),
        OptimizerKind::Sgd => SgdConfig::new()
            .with_momentum(Some(MomentumConfig::new().with_momentum(0.9).with_dampening(0.0)))
            .with_weight_decay(Some(WeightDecayConfig::new(config.weight_decay as f32)))
            .with_gradient_clipping(clip)
            .init(),
    }
}

/// One optimizer step on whichever network it is.
pub fn apply(network: Network, optim: &mut ModuleOptimizer, lr: f64, grads: burn::tensor::Gradients) -> Network {
    match network {
        Network::FasterRcnn(m) => {
            let g = GradientsParams::from_grads(grads, &m);
            Network::FasterRcnn(optim.step(lr, m, g))
        }
        Network::Grid(m) => {
            let g = GradientsParams::from_grads(grads, &m);
            Network::Grid(optim.step(lr, m, g))
        }
    }
}

fn csv_header(backbone: Backbone) -> String {
    let parts = if backbone == Backbone::FasterRcnn { FASTER_RCNN_PARTS } else { GRID_PARTS };
    format!("kind,epoch,iteration,loss,{},lr,elapsed_s\n", parts.join(","))
}

/// Splits the training set into (train, validation) deterministically.
fn split(all: &[LabeledImage], fraction: f32, seed: u64) -> (Vec<&LabeledImage>, Vec<&LabeledImage>) {
    let mut order: Vec<usize> = (0..all.len()).collect();
    order.shuffle(&mut ChaCha8Rng::seed_from_u64(mix(seed, 0x5417)));
    let n_val = (all.len() as f32 * fraction).round() as usize;
    let valid = order[..n_val].iter().map(|&i| &all[i]).collect();
    let train = order[n_val..].iter().map(|&i| &all[i]).collect();
    (train, valid)
}

/// Trains into `run`: a new run from `config`, or, with `None`, the run
/// found there continued from its last completed epoch.
pub fn train(config: Option<TrainConfig>, run: &Path, show_progress: bool) -> Result<TrainSummary> {
    train_until(config, run, show_progress, None).map(|s| s.expect("runs to the end without a stop"))
}

/// Like [`train`], but stops after `stop_after` epochs as an interruption
/// would (no final evaluation), returning `None` then.
pub fn train_until(
    config: Option<TrainConfig>,
    run: &Path,
    show_progress: bool,
    stop_after: Option<usize>,
) -> Result<Option<TrainSummary>> {
    let resume_dir = run.join(RESUME_DIR);
    let (config, state) = match config {
        Some(c) => {
            c.validate().map_err(TrainError::Settings)?;
            (c, None)
        }
        None => {
            // A kill can leave temporary files, and the resume state renamed
            // aside between the two renames of its replacement.
            datasets::atomic::remove_leftovers(run)?;
            datasets::atomic::recover_dir(&resume_dir)?;
            let path = run.join(CONFIG_FILE);
            let text = datasets::atomic::read_text(&path).map_err(TrainError::NothingToResume)?;
            let c: TrainConfig = parse_json(&path, "settings", &text)?;
            let state_path = resume_dir.join(STATE_FILE);
            let state = if state_path.is_file() { Some(read_json::<ResumeState>(&state_path, "state")?) } else { None };
            (c, state)
        }
    };
    let device = config.backend.device().autodiff();
    let inner = device.clone().without_autodiff();
    let det = &config.detector;
    let train_json = config.data.join("train.json");
    let test_json = config.data.join("test.json");
    for p in [&train_json, &test_json] {
        if !p.is_file() {
            return Err(TrainError::Folder {
                path: p.clone(),
                what: "missing (--data must be a datagen detection folder with train.json and test.json)".into(),
            });
        }
    }
    let all = load_coco_set(&train_json, &det.preprocess)?;
    let test = load_coco_set(&test_json, &det.preprocess)?;
    if all.is_empty() {
        return Err(TrainError::Folder { path: train_json, what: "no training images".into() });
    }
    let (train_set, valid_set) = split(&all, config.val_fraction, config.seed);

    // Flex keeps one global RNG: seed it before the weights are drawn.
    device.seed(config.seed);
    let mut network = Network::new(det, &device);
    let mut optim = optimizer(&config);
    let (mut epochs_done, mut elapsed, mut csv) = (0, 0.0, csv_header(det.backbone));
    let mut pretrained_report = None;
    if let Some(s) = state {
        network = checkpoint::load_weights(&resume_dir, det, &device).map_err(TrainError::ResumeWeights)?;
        optim = optim
            .load(resume_dir.join(format!("{OPTIMIZER_STEM}.bpk")))
            .map_err(|source| TrainError::Optimizer { what: "loading", source })?;
        (epochs_done, elapsed, csv) = (s.epochs_done, s.elapsed_s, s.csv);
        eprintln!("resuming {} after epoch {epochs_done} of {}", run.display(), config.epochs);
    } else if let Start::Detector(path) = &config.start {
        network = checkpoint::load_for_fine_tuning(path, det, &device)?;
        if show_progress {
            eprintln!("{}: whole detector loaded (trunk, heads)", path.display());
        }
    } else if let Start::Trunk(path) = &config.start {
        let report = load_trunk(&mut network, det, path, config.pretrained_input, config.pretrained_prune)?;
        if show_progress {
            eprintln!(
                "{}: {} tensors loaded ({:?} input convention); unused: {}",
                path.display(),
                report.loaded.len() * 2,
                report.convention,
                if report.unused.is_empty() { "none".to_string() } else { report.unused.join(", ") }
            );
            for s in &report.skipped {
                eprintln!("  not loaded: {s}");
            }
        }
        pretrained_report = Some(report);
    }
    // Written once the settings proved usable (data read, weights loaded).
    std::fs::create_dir_all(run).map_err(|source| TrainError::Create { path: run.to_path_buf(), source })?;
    datasets::atomic::write_json(&run.join(CONFIG_FILE), &config)?;
    if let Some(report) = &pretrained_report {
        datasets::atomic::write_json(&run.join(PRETRAINED_FILE), report)?;
    }
    network = network.freeze_convs(config.freeze);
    let started_caching = Instant::now();
    let caches = frozen_feature_caches(&config, &network, &train_set, &valid_set, &inner, show_progress);
    // Caching is part of what the run costs.
    elapsed += started_caching.elapsed().as_secs_f64();
    if caches.is_some() && show_progress {
        eprintln!(
            "cached the outputs of the {} frozen convolutions in {:.0} s",
            config.freeze,
            started_caching.elapsed().as_secs_f64()
        );
    }

    let per_epoch = train_set.len().div_ceil(config.batch_size);
    let total = per_epoch * config.epochs;
    let size = det.preprocess.size;
    let mut last_train = f64::NAN;
    let mut last_valid = None;
    for epoch in epochs_done..config.epochs {
        let started = Instant::now();
        device.seed(mix(config.seed, epoch as u64 + 1));
        let mut rng = ChaCha8Rng::seed_from_u64(mix(config.seed, 1000 + epoch as u64));
        let mut order: Vec<usize> = (0..train_set.len()).collect();
        order.shuffle(&mut rng);
        let bar = if show_progress { ProgressBar::new(per_epoch as u64) } else { ProgressBar::hidden() };
        bar.set_style(
            ProgressStyle::with_template("epoch {prefix} [{bar:30}] {pos}/{len} {msg} ({eta})")
                .expect("template")
                .progress_chars("=> "),
        );
        bar.set_prefix(format!("{}/{}", epoch + 1, config.epochs));
        let mut sums = [0.0f64; 5];
        for (k, chunk) in order.chunks(config.batch_size).enumerate() {
            let iteration = epoch * per_epoch + k;
            let images: Vec<&LabeledImage> = chunk.iter().map(|&i| train_set[i]).collect();
            let flips: Vec<bool> = images.iter().map(|_| config.augment && crate::targets::coin(&mut rng)).collect();
            let batch =
                FeatureCache::batch_of(caches.as_ref().map(|(t, _)| t), &train_set, chunk, &flips, size, &device);
            let losses = batch_losses(&network, det, &batch, &mut rng);
            let values: Vec<f64> = std::iter::once(&losses.total)
                .chain(losses.parts.iter().map(|(_, t)| t))
                .map(|t| infer::host(t.clone())[0] as f64)
                .collect();
            if !values[0].is_finite() {
                return Err(TrainError::Diverged { loss: values[0], epoch: epoch + 1, iteration });
            }
            let lr = config.lr_at(iteration, total);
            network = apply(network, &mut optim, lr, losses.total.backward());
            for (s, v) in sums.iter_mut().zip(&values) {
                *s += v;
            }
            let now = elapsed + started.elapsed().as_secs_f64();
            let _ = writeln!(csv, "train,{},{iteration},{}", epoch + 1, row(&values, lr, now));
            bar.set_message(format!("loss {:.4}", values[0]));
            bar.inc(1);
        }
        bar.finish_and_clear();
        let n = per_epoch as f64;
        let means: Vec<f64> = sums.iter().map(|s| s / n).collect();
        last_train = means[0];
        let end_iteration = (epoch + 1) * per_epoch - 1;
        elapsed += started.elapsed().as_secs_f64();
        let lr = config.lr_at(end_iteration, total);
        let _ = writeln!(csv, "train_epoch,{},{end_iteration},{}", epoch + 1, row(&means, lr, elapsed));
        if !valid_set.is_empty() {
            let v = validation_loss(&network, &config, &valid_set, caches.as_ref().map(|(_, v)| v), &inner);
            last_valid = Some(v[0]);
            let _ = writeln!(csv, "valid_epoch,{},{end_iteration},{}", epoch + 1, row(&v, lr, elapsed));
        }
        if show_progress {
            eprintln!(
                "epoch {}/{}: train loss {:.4}{} ({:.0} s)",
                epoch + 1,
                config.epochs,
                last_train,
                last_valid.map(|v| format!(", valid loss {v:.4}")).unwrap_or_default(),
                elapsed
            );
        }
        datasets::atomic::write_bytes(&run.join(LOSSES_FILE), csv.as_bytes())?;
        save_resume(
            &resume_dir,
            &network,
            &optim,
            &ResumeState { epochs_done: epoch + 1, elapsed_s: elapsed, csv: csv.clone() },
        )?;
        let meta = meta_for(&config, &network, epoch + 1, elapsed);
        checkpoint::save(&run.join(CHECKPOINT_DIR), det, &network, &meta)?;
        if stop_after == Some(epoch + 1) {
            return Ok(None);
        }
    }

    // Final evaluation on the test split.
    let meta = meta_for(&config, &network, config.epochs, elapsed);
    let detector = Detector::from_network(det.clone(), meta.clone(), &network, inner.clone());
    let metrics = eval::evaluate_set(&detector, &test, config.batch_size);
    datasets::atomic::write_json(&run.join(METRICS_FILE), &metrics)?;
    let meta = CheckpointMeta { metrics: Some(metrics.clone()), ..meta };
    checkpoint::save(&run.join(CHECKPOINT_DIR), det, &network, &meta)?;
    if last_train.is_nan() {
        // Resumed after the last epoch: report the logged final losses.
        last_train = final_value(&csv, "train_epoch").unwrap_or(f64::NAN);
        last_valid = final_value(&csv, "valid_epoch");
    }
    Ok(Some(TrainSummary { metrics, final_train_loss: last_train, final_valid_loss: last_valid, seconds: elapsed }))
}

fn final_value(csv: &str, kind: &str) -> Option<f64> {
    csv.lines().rfind(|l| l.starts_with(&format!("{kind},")))?.split(',').nth(3)?.parse().ok()
}

fn row(values: &[f64], lr: f64, elapsed: f64) -> String {
    let mut parts: Vec<String> = values.iter().map(|v| format!("{v:.6}")).collect();
    parts.resize(5, "0".into());
    format!("{},{lr:.6e},{elapsed:.2}", parts.join(","))
}

/// Checkpoint metadata without metrics (added after the final evaluation).
fn meta_for(config: &TrainConfig, network: &Network, epochs: usize, seconds: f64) -> CheckpointMeta {
    CheckpointMeta {
        format_version: checkpoint::FORMAT_VERSION,
        backbone: config.detector.backbone,
        width: config.detector.width,
        dataset: config.data.display().to_string(),
        epochs,
        metrics: None,
        pretrained: config.start.path().map(|p| p.display().to_string()),
        train_seconds: seconds,
        parameters: network.num_params(),
    }
}

/// Mean loss over the validation images, without dropout or gradients and
/// with a fixed sampling seed, so epochs compare.
fn validation_loss(
    network: &Network,
    config: &TrainConfig,
    valid: &[&LabeledImage],
    cache: Option<&FeatureCache>,
    device: &Device,
) -> Vec<f64> {
    let model = network.valid();
    let mut rng = ChaCha8Rng::seed_from_u64(mix(config.seed, 0xda7a));
    let mut sums = [0.0f64; 5];
    let mut batches = 0;
    let ids: Vec<usize> = (0..valid.len()).collect();
    for ids in ids.chunks(config.batch_size) {
        let flips = vec![false; ids.len()];
        let size = config.detector.preprocess.size;
        let batch = FeatureCache::batch_of(cache, valid, ids, &flips, size, device);
        let losses = batch_losses(&model, &config.detector, &batch, &mut rng);
        for (s, t) in sums.iter_mut().zip(std::iter::once(&losses.total).chain(losses.parts.iter().map(|(_, t)| t))) {
            *s += infer::host(t.clone())[0] as f64;
        }
        batches += 1;
    }
    sums.iter().map(|s| s / batches.max(1) as f64).collect()
}

/// The frozen layers' outputs for the training images (both orientations
/// when flips are on) and the validation images, when something is frozen,
/// caching is on and the cache fits in memory.
fn frozen_feature_caches(
    config: &TrainConfig,
    network: &Network,
    train_set: &[&LabeledImage],
    valid_set: &[&LabeledImage],
    device: &Device,
    show_progress: bool,
) -> Option<(FeatureCache, FeatureCache)> {
    if config.freeze == 0 || !config.cache_frozen {
        return None;
    }
    let size = config.detector.preprocess.size;
    let entries = train_set.len() * if config.augment { 2 } else { 1 } + valid_set.len();
    let bytes = FeatureCache::estimate_bytes(network, config.freeze, size, entries, device);
    if bytes > MAX_CACHE_BYTES {
        eprintln!(
            "not caching the frozen features: {:.1} GiB is too much memory; freeze more layers to cache",
            bytes as f64 / (1u64 << 30) as f64
        );
        return None;
    }
    let build = |images: &[&LabeledImage], flips| {
        FeatureCache::build(network, images, flips, config.freeze, config.batch_size, device, show_progress)
    };
    Some((build(train_set, config.augment), build(valid_set, false)))
}

/// Writes the resume state atomically (a new folder renamed into place).
fn save_resume(dir: &Path, network: &Network, optim: &ModuleOptimizer, state: &ResumeState) -> Result<()> {
    datasets::atomic::write_dir(dir, |tmp| -> Result<()> {
        checkpoint::save_weights(network, &tmp.join(checkpoint::WEIGHTS_STEM))?;
        optim.save(tmp.join(OPTIMIZER_STEM)).map_err(|source| TrainError::Optimizer { what: "writing", source })?;
        datasets::atomic::write_json(&tmp.join(STATE_FILE), state)?;
        Ok(())
    })
}
