//! The training loop: mini-batches, the optimizer and its learning-rate
//! schedule, the loss log, a resumable state after every epoch, an
//! inference checkpoint, and the final evaluation on the test split. What
//! lands where in the run's folder is [`RunFolder`]'s business.

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

use crate::config::{OptimizerKind, Start, TrainConfig};
use crate::error::{Result, TrainError};
use crate::feature_cache::{FeatureCache, MAX_CACHE_BYTES};
use crate::loss_log::{LOSS_VALUES, LossLog, RowKind};
use crate::run_folder::{Progress, RunFolder};
use crate::step::batch_losses;
use infer::checkpoint::{self, CheckpointMeta};
use infer::labeled::{LabeledImage, load_coco_set};
use infer::metrics::EvalMetrics;
use infer::network::Network;
use infer::pretrained::{ImportReport, load_trunk};
use infer::{Detector, eval};
#[derive(Debug, Clone)]
pub struct TrainSummary {
    pub metrics: EvalMetrics,
    pub final_train_loss: f64,
    pub final_valid_loss: Option<f64>,
    pub seconds: f64,
}

fn mix(a: u64, b: u64) -> u64 {
    datasets::seed::mix(a ^ datasets::seed::mix(b))
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

/// Splits the training set into (train, validation) deterministically.
fn split(all: Vec<LabeledImage>, fraction: f32, seed: u64) -> (Vec<LabeledImage>, Vec<LabeledImage>) {
    let mut order: Vec<usize> = (0..all.len()).collect();
    order.shuffle(&mut ChaCha8Rng::seed_from_u64(mix(seed, 0x5417)));
    let n_val = (all.len() as f32 * fraction).round() as usize;
    let mut slots: Vec<Option<LabeledImage>> = all.into_iter().map(Some).collect();
    let mut take = |ids: &[usize]| -> Vec<LabeledImage> {
        ids.iter().map(|&i| slots[i].take().expect("each image once")).collect()
    };
    let valid = take(&order[..n_val]);
    let train = take(&order[n_val..]);
    (train, valid)
}

/// Trains into `run`: a new run from `config`, or, with `None`, the run
/// found there continued from its last completed epoch.
pub fn train(config: Option<TrainConfig>, run: &std::path::Path, show_progress: bool) -> Result<TrainSummary> {
    train_until(config, run, show_progress, None).map(|s| s.expect("runs to the end without a stop"))
}

/// Like [`train`], but stops after `stop_after` epochs as an interruption
/// would (no final evaluation), returning `None` then.
pub fn train_until(
    config: Option<TrainConfig>,
    run: &std::path::Path,
    show_progress: bool,
    stop_after: Option<usize>,
) -> Result<Option<TrainSummary>> {
    let folder = RunFolder::new(run);
    let (config, progress) = match config {
        Some(c) => {
            c.validate().map_err(TrainError::Settings)?;
            (c, None)
        }
        None => folder.read_for_resume()?,
    };
    let data = Splits::load(&config)?;
    let device = config.backend.device()?.autodiff();
    let (network, mut optim, mut progress, pretrained) = start(&config, &folder, progress, &device, show_progress)?;
    // Written once the settings proved usable (data read, weights loaded).
    folder.write_settings(&config, pretrained.as_ref())?;
    let network = network.freeze_convs(config.freeze);
    let started_caching = Instant::now();
    let caches = frozen_feature_caches(&config, &network, &data, &device, show_progress);
    // Caching is part of what the run costs.
    progress.elapsed_s += started_caching.elapsed().as_secs_f64();
    if caches.is_some() && show_progress {
        let seconds = started_caching.elapsed().as_secs_f64();
        eprintln!("cached the outputs of the {} frozen convolutions in {seconds:.0} s", config.freeze);
    }

    let epochs = Epochs { config: &config, data: &data, caches, device, show_progress };
    let mut network = network;
    let mut last_epoch = None;
    for epoch in progress.epochs_done..config.epochs {
        let started = Instant::now();
        network = epochs.train(network, &mut optim, epoch, &mut progress)?;
        progress.elapsed_s += started.elapsed().as_secs_f64();
        let (train_loss, valid_loss) = epochs.close(&network, epoch, &mut progress);
        if show_progress {
            eprintln!(
                "epoch {}/{}: train loss {train_loss:.4}{} ({:.0} s)",
                epoch + 1,
                config.epochs,
                valid_loss.map(|v| format!(", valid loss {v:.4}")).unwrap_or_default(),
                progress.elapsed_s
            );
        }
        progress.epochs_done = epoch + 1;
        let meta = meta_for(&config, &network, epoch + 1, progress.elapsed_s);
        folder.save_epoch(&config.detector, &network, &optim, &progress, &meta)?;
        last_epoch = Some((train_loss, valid_loss));
        if stop_after == Some(epoch + 1) {
            return Ok(None);
        }
    }
    let inner = epochs.device.clone().without_autodiff();
    let metrics = evaluate(&folder, &config, &network, &data.test, &inner, progress.elapsed_s)?;
    // Resumed after the last epoch: the logged final losses.
    let (final_train_loss, final_valid_loss) = last_epoch.unwrap_or_else(|| {
        (progress.log.last(RowKind::TrainEpoch).unwrap_or(f64::NAN), progress.log.last(RowKind::ValidEpoch))
    });
    Ok(Some(TrainSummary { metrics, final_train_loss, final_valid_loss, seconds: progress.elapsed_s }))
}

/// The images of a run: training and validation (split from `train.json`)
/// and test (`test.json`).
struct Splits {
    train: Vec<LabeledImage>,
    valid: Vec<LabeledImage>,
    test: Vec<LabeledImage>,
}

impl Splits {
    fn load(config: &TrainConfig) -> Result<Self> {
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
        let all = load_coco_set(&train_json, &config.detector.preprocess)?;
        let test = load_coco_set(&test_json, &config.detector.preprocess)?;
        if all.is_empty() {
            return Err(TrainError::Folder { path: train_json, what: "no training images".into() });
        }
        let (train, valid) = split(all, config.val_fraction, config.seed);
        Ok(Self { train, valid, test })
    }

    fn train_refs(&self) -> Vec<&LabeledImage> {
        self.train.iter().collect()
    }

    fn valid_refs(&self) -> Vec<&LabeledImage> {
        self.valid.iter().collect()
    }
}

/// The network, optimizer and progress a run starts from: its resume state,
/// or a fresh network (its weights drawn from the run's seed, then
/// overwritten by a whole detector or a trunk file if the run starts from
/// one). A trunk file's import report comes back to be written.
fn start(
    config: &TrainConfig,
    folder: &RunFolder,
    progress: Option<Progress>,
    device: &Device,
    show_progress: bool,
) -> Result<(Network, ModuleOptimizer, Progress, Option<ImportReport>)> {
    let det = &config.detector;
    // Flex keeps one global RNG: seed it before the weights are drawn.
    device.seed(config.seed);
    let network = Network::new(det, device);
    let optim = optimizer(config);
    if let Some(progress) = progress {
        let (network, optim) = folder.load_resume(det, optim, device)?;
        eprintln!("resuming {} after epoch {} of {}", folder.root().display(), progress.epochs_done, config.epochs);
        return Ok((network, optim, progress, None));
    }
    let fresh = Progress { epochs_done: 0, elapsed_s: 0.0, log: LossLog::new(det.backbone) };
    match &config.start {
        Start::Scratch => Ok((network, optim, fresh, None)),
        Start::Detector(path) => {
            let network = checkpoint::load_for_fine_tuning(path, det, device)?;
            if show_progress {
                eprintln!("{}: whole detector loaded (trunk, heads)", path.display());
            }
            Ok((network, optim, fresh, None))
        }
        Start::Trunk(path) => {
            let mut network = network;
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
            Ok((network, optim, fresh, Some(report)))
        }
    }
}

/// The epochs of a run, over its data and the frozen layers' cached outputs.
struct Epochs<'a> {
    config: &'a TrainConfig,
    data: &'a Splits,
    caches: Option<(FeatureCache, FeatureCache)>,
    /// The training device (with autodiff).
    device: Device,
    show_progress: bool,
}

impl Epochs<'_> {
    fn batches_per_epoch(&self) -> usize {
        self.data.train.len().div_ceil(self.config.batch_size)
    }

    /// One pass over the shuffled training images: a step per mini-batch, a
    /// `train` row per step in the log.
    fn train(
        &self,
        mut network: Network,
        optim: &mut ModuleOptimizer,
        epoch: usize,
        progress: &mut Progress,
    ) -> Result<Network> {
        let (config, det) = (self.config, &self.config.detector);
        let started = Instant::now();
        let train_set = self.data.train_refs();
        let per_epoch = self.batches_per_epoch();
        let total = per_epoch * config.epochs;
        self.device.seed(mix(config.seed, epoch as u64 + 1));
        let mut rng = ChaCha8Rng::seed_from_u64(mix(config.seed, 1000 + epoch as u64));
        let mut order: Vec<usize> = (0..train_set.len()).collect();
        order.shuffle(&mut rng);
        let bar = if self.show_progress { ProgressBar::new(per_epoch as u64) } else { ProgressBar::hidden() };
        bar.set_style(
            ProgressStyle::with_template("epoch {prefix} [{bar:30}] {pos}/{len} {msg} ({eta})")
                .expect("template")
                .progress_chars("=> "),
        );
        bar.set_prefix(format!("{}/{}", epoch + 1, config.epochs));
        let cache = self.caches.as_ref().map(|(train, _)| train);
        for (k, chunk) in order.chunks(config.batch_size).enumerate() {
            let iteration = epoch * per_epoch + k;
            let flips: Vec<bool> = chunk.iter().map(|_| config.augment && crate::targets::coin(&mut rng)).collect();
            let batch = FeatureCache::batch_of(cache, &train_set, chunk, &flips, det.preprocess.size, &self.device);
            let losses = batch_losses(&network, det, &batch, &mut rng);
            let values: Vec<f64> = std::iter::once(&losses.total)
                .chain(losses.parts.iter().map(|(_, t)| t))
                .map(|t| infer::host(t.clone())[0] as f64)
                .collect();
            if !values[0].is_finite() {
                return Err(TrainError::Diverged { loss: values[0], epoch: epoch + 1, iteration });
            }
            let lr = config.lr_at(iteration, total);
            network = apply(network, optim, lr, losses.total.backward());
            let now = progress.elapsed_s + started.elapsed().as_secs_f64();
            progress.log.push(RowKind::Train, epoch + 1, iteration, &values, lr, now);
            bar.set_message(format!("loss {:.4}", values[0]));
            bar.inc(1);
        }
        bar.finish_and_clear();
        Ok(network)
    }

    /// Logs the epoch's mean training loss and, with a validation split, its
    /// validation loss; returns them as (train, valid).
    fn close(&self, network: &Network, epoch: usize, progress: &mut Progress) -> (f64, Option<f64>) {
        let per_epoch = self.batches_per_epoch();
        let end_iteration = (epoch + 1) * per_epoch - 1;
        let lr = self.config.lr_at(end_iteration, per_epoch * self.config.epochs);
        let mut sums = [0.0f64; LOSS_VALUES];
        for row in progress.log.rows().iter().filter(|r| r.kind == RowKind::Train && r.epoch == epoch + 1) {
            for (s, v) in sums.iter_mut().zip(&row.values) {
                *s += v;
            }
        }
        let means = sums.map(|s| s / per_epoch as f64);
        progress.log.push(RowKind::TrainEpoch, epoch + 1, end_iteration, &means, lr, progress.elapsed_s);
        if self.data.valid.is_empty() {
            return (means[0], None);
        }
        let inner = self.device.clone().without_autodiff();
        let cache = self.caches.as_ref().map(|(_, valid)| valid);
        let v = validation_loss(network, self.config, &self.data.valid_refs(), cache, &inner);
        progress.log.push(RowKind::ValidEpoch, epoch + 1, end_iteration, &v, lr, progress.elapsed_s);
        (means[0], Some(v[0]))
    }
}

/// The final evaluation on the test split, written with the checkpoint.
fn evaluate(
    folder: &RunFolder,
    config: &TrainConfig,
    network: &Network,
    test: &[LabeledImage],
    device: &Device,
    seconds: f64,
) -> Result<EvalMetrics> {
    let meta = meta_for(config, network, config.epochs, seconds);
    let detector = Detector::from_network(config.detector.clone(), meta.clone(), network, device.clone());
    let metrics = eval::evaluate_set(&detector, test, config.batch_size);
    let meta = CheckpointMeta { metrics: Some(metrics.clone()), ..meta };
    folder.save_result(&config.detector, network, &metrics, &meta)?;
    Ok(metrics)
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
    let mut sums = [0.0f64; LOSS_VALUES];
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
    data: &Splits,
    device: &Device,
    show_progress: bool,
) -> Option<(FeatureCache, FeatureCache)> {
    if config.freeze == 0 || !config.cache_frozen {
        return None;
    }
    let device = &device.clone().without_autodiff();
    let (train_set, valid_set) = (data.train_refs(), data.valid_refs());
    let size = config.detector.preprocess.size as usize;
    let input = [config.detector.in_channels, size, size];
    let entries = train_set.len() * if config.augment { 2 } else { 1 } + valid_set.len();
    let bytes = FeatureCache::estimate_bytes(network, config.freeze, input, entries, device);
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
    Some((build(&train_set, config.augment), build(&valid_set, false)))
}
