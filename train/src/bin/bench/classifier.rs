//! `bench train-step`: whole training steps of the torchvision classifiers
//! (AlexNet, VGG16 at width 1/4, full VGG16; one input channel, two classes,
//! batch 8 of 224x224) with Burn's flex convolution kernels and with the
//! project's GEMM kernels: images per second and the CPU cores in use. The
//! models, batch, loss and optimizer are those of the PyTorch script the
//! speed page (docs/speed.md) compares against (forward + cross-entropy + backward + Adam 1e-4).
//! "Burn" is Burn 0.22.1 as it comes (flex convolutions, Burn's Adam);
//! "project" adds the GEMM convolution kernels and the fused AdamW (weight
//! decay 0, which is Adam).

use std::time::Instant;

use anyhow::Result;
use burn::module::Module;
use burn::nn::loss::CrossEntropyLossConfig;
use burn::nn::pool::{AdaptiveAvgPool2d, AdaptiveAvgPool2dConfig};
use burn::nn::{Dropout, DropoutConfig, Linear, LinearConfig, Relu};
use burn::optim::{AdamConfig, GradientsParams};
use burn::prelude::*;
use infer::trunk::{Architecture, Trunk, TrunkConfig};
use rand::rngs::ChaCha8Rng;
use rand::{RngExt, SeedableRng};
use train::fused_adamw::FusedAdamW;

#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Model {
    Alexnet,
    Vgg16w4,
    Vgg16,
}

#[derive(Module, Debug)]
struct Classifier {
    trunk: Trunk,
    avgpool: AdaptiveAvgPool2d,
    fc: Vec<Linear>,
    dropout: Dropout,
    act: Relu,
}

impl Classifier {
    fn new(model: Model, device: &Device) -> Self {
        let (architecture, width, grid) = match model {
            Model::Alexnet => (Architecture::Alexnet, 1.0, 6),
            Model::Vgg16w4 => (Architecture::Vgg16, 0.25, 7),
            Model::Vgg16 => (Architecture::Vgg16, 1.0, 7),
        };
        let config = TrunkConfig::new(architecture).with_width(width);
        let hidden = config.channels(4096);
        let sizes = [(config.out_channels() * grid * grid, hidden), (hidden, hidden), (hidden, 2)];
        Self {
            trunk: config.init(device),
            avgpool: AdaptiveAvgPool2dConfig::new([grid, grid]).init(),
            fc: sizes.iter().map(|&(i, o)| LinearConfig::new(i, o).init(device)).collect(),
            dropout: DropoutConfig::new(0.5).init(),
            act: Relu::new(),
        }
    }

    fn forward(&self, x: Tensor<4>) -> Tensor<2> {
        let x = self.trunk.forward_all(x, true);
        let x: Tensor<2> = self.avgpool.forward(x).flatten(1, 3);
        let x = self.dropout.forward(self.act.forward(self.fc[0].forward(x)));
        let x = self.dropout.forward(self.act.forward(self.fc[1].forward(x)));
        self.fc[2].forward(x)
    }
}

#[derive(serde::Serialize)]
pub struct StepFigures {
    model: Model,
    batch: usize,
    /// `None` where Burn's kernels were not timed.
    burn_images_per_s: Option<f64>,
    gemm_images_per_s: f64,
    burn_cores: Option<f64>,
    gemm_cores: f64,
    /// Seconds of the median step with the project's kernels: forward + loss,
    /// backward, optimizer.
    gemm_phases_s: [f64; 3],
}

/// CPU seconds this process has used (user + system).
fn cpu_seconds() -> f64 {
    let stat = std::fs::read_to_string("/proc/self/stat").unwrap_or_default();
    // Fields after the parenthesised command name; utime and stime are 14 and 15.
    let after = stat.rsplit_once(')').map_or("", |(_, rest)| rest);
    let fields: Vec<&str> = after.split_whitespace().collect();
    let ticks = |i: usize| fields.get(i - 3).and_then(|v| v.parse::<f64>().ok()).unwrap_or(f64::NAN);
    (ticks(14) + ticks(15)) / 100.0
}

/// Images per second and cores in use over `steps` timed steps (median step
/// time), after `warmup` steps.
fn time_steps(model: Model, batch: usize, warmup: usize, steps: usize, gemm: bool) -> Timing {
    infer::kernels::cpu_kernels::set_enabled(gemm);
    let device = Device::flex().autodiff();
    device.seed(1);
    let mut net = Classifier::new(model, &device);
    let mut optim = if gemm { FusedAdamW::new(0.0).init(None) } else { AdamConfig::new().init() };
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let values: Vec<f32> = (0..batch * 224 * 224).map(|_| rng.random_range(0.0..1.0)).collect();
    let x = Tensor::<4>::from_data(TensorData::new(values, [batch, 1, 224, 224]), &device);
    let labels: Vec<i64> = (0..batch as i64).map(|i| i % 2).collect();
    let y = Tensor::<1, Int>::from_data(TensorData::new(labels, [batch]), &device);
    let loss_fn = CrossEntropyLossConfig::new().init(&device);
    // Each phase timed on its own (flex runs eagerly, so an op's time is
    // spent when it returns): [forward + loss, backward, optimizer].
    let mut one_step = |net: Classifier| -> (Classifier, [f64; 3]) {
        let t0 = Instant::now();
        let loss = loss_fn.forward(net.forward(x.clone()), y.clone());
        let t1 = Instant::now();
        let grads = GradientsParams::from_grads(loss.backward(), &net);
        let t2 = Instant::now();
        let net = optim.step(1e-4, net, grads);
        let t3 = Instant::now();
        (net, [t1 - t0, t2 - t1, t3 - t2].map(|d| d.as_secs_f64()))
    };
    for _ in 0..warmup {
        net = one_step(net).0;
    }
    let (cpu_start, wall_start) = (cpu_seconds(), Instant::now());
    let mut times: Vec<[f64; 3]> = Vec::new();
    for _ in 0..steps {
        let (next, phases) = one_step(net);
        net = next;
        times.push(phases);
    }
    let cores = (cpu_seconds() - cpu_start) / wall_start.elapsed().as_secs_f64();
    infer::kernels::cpu_kernels::set_enabled(true);
    times.sort_by(|a, b| a.iter().sum::<f64>().total_cmp(&b.iter().sum::<f64>()));
    let median = times[times.len() / 2];
    Timing { images_per_s: batch as f64 / median.iter().sum::<f64>(), cores, phases_s: median }
}

struct Timing {
    images_per_s: f64,
    cores: f64,
    /// Seconds of the median step: forward + loss, backward, optimizer.
    phases_s: [f64; 3],
}

pub fn run(models: &[Model], batch: usize, warmup: usize, steps: usize, with_burn: bool, json: bool) -> Result<()> {
    if !json {
        println!("Training step, batch {batch} of 1x224x224, median of {steps} steps after {warmup} warm-up\n");
        println!(
            "| model | Burn img/s | project img/s | speed-up | cores used (Burn / project) | project step: forward / backward / optimizer s |"
        );
        println!("|---|---|---|---|---|---|");
    }
    for &model in models {
        let burn = with_burn.then(|| time_steps(model, batch, warmup, steps, false));
        let gemm = time_steps(model, batch, warmup, steps, true);
        let f = StepFigures {
            model,
            batch,
            burn_images_per_s: burn.as_ref().map(|b| b.images_per_s),
            gemm_images_per_s: gemm.images_per_s,
            burn_cores: burn.as_ref().map(|b| b.cores),
            gemm_cores: gemm.cores,
            gemm_phases_s: gemm.phases_s,
        };
        if json {
            println!("{}", serde_json::to_string(&f)?);
        } else {
            let or_dash = |v: Option<f64>, suffix: &str| v.map_or("-".to_string(), |v| format!("{v:.2}{suffix}"));
            println!(
                "| {:?} | {} | {:.2} | {} | {} / {:.2} | {:.2} / {:.2} / {:.2} |",
                f.model,
                or_dash(f.burn_images_per_s, ""),
                f.gemm_images_per_s,
                or_dash(f.burn_images_per_s.map(|b| f.gemm_images_per_s / b), "x"),
                or_dash(f.burn_cores, ""),
                f.gemm_cores,
                f.gemm_phases_s[0],
                f.gemm_phases_s[1],
                f.gemm_phases_s[2]
            );
        }
    }
    Ok(())
}
