//! `bench detectors`: training images per second, inference milliseconds per
//! image and peak memory of each backbone on the chosen CPU backend. Each
//! backbone runs in its own process so that its peak memory is its own.

use std::time::Instant;

use anyhow::{Context, Result, bail};
use infer::backend::ComputeBackend;
use infer::config::{Backbone, DetectorConfig};
use infer::network::Network;
use rand::SeedableRng;
use rand::rngs::ChaCha8Rng;
use train::step::batch_losses;

#[derive(serde::Serialize, serde::Deserialize)]
struct Figures {
    backbone: Backbone,
    backend: ComputeBackend,
    width: f32,
    batch: usize,
    train_images_per_s: f64,
    infer_ms_per_image: f64,
    peak_rss_mb: f64,
    parameters: usize,
}

pub fn run(
    backend: ComputeBackend,
    width: f32,
    batch: usize,
    steps: usize,
    only: Option<Backbone>,
    json: bool,
    burn_kernels: bool,
) -> Result<()> {
    infer::kernels::cpu_kernels::set_enabled(!burn_kernels);
    if let Some(backbone) = only {
        let f = measure(backbone, backend, width, batch, steps)?;
        println!("{}", serde_json::to_string(&f)?);
        return Ok(());
    }
    let exe = std::env::current_exe()?;
    if !json {
        println!("| backbone | backend | width | train img/s | infer ms/img | peak RSS MB | parameters |");
        println!("|---|---|---|---|---|---|---|");
    }
    for backbone in [Backbone::FasterRcnn, Backbone::Vgg16, Backbone::Alexnet] {
        let out = std::process::Command::new(&exe)
            .args(["detectors", "--backend", &format!("{backend:?}").to_lowercase(), "--width", &width.to_string()])
            .args(["--batch", &batch.to_string(), "--steps", &steps.to_string(), "--only", backbone.name()])
            .args(burn_kernels.then_some("--burn-kernels"))
            .output()
            .context("running a benchmark child")?;
        if !out.status.success() {
            bail!("{backbone}: {}", String::from_utf8_lossy(&out.stderr));
        }
        let line = String::from_utf8(out.stdout)?;
        if json {
            print!("{line}");
            continue;
        }
        let f: Figures = serde_json::from_str(line.trim())?;
        println!(
            "| {} | {:?} | {} | {:.2} | {:.1} | {:.0} | {} |",
            f.backbone, f.backend, f.width, f.train_images_per_s, f.infer_ms_per_image, f.peak_rss_mb, f.parameters
        );
    }
    Ok(())
}

fn measure(backbone: Backbone, backend: ComputeBackend, width: f32, batch: usize, steps: usize) -> Result<Figures> {
    let config = DetectorConfig::new(backbone, width);
    let device = backend.device()?.autodiff();
    let mut network = Network::new(&config, &device);
    // Burn as it comes (its AdamW) or the project's fused AdamW, as training uses.
    let mut optim = if infer::kernels::cpu_kernels::enabled() {
        train::fused_adamw::FusedAdamW::new(1e-4).init(None)
    } else {
        burn::optim::AdamWConfig::new().init()
    };
    let data = train::step::synthetic_batch(&config, batch, &device);
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    let mut step = |network: Network| -> Network {
        let losses = batch_losses(&network, &config, &data, &mut rng);
        train::trainer::apply(network, &mut optim, 1e-4, losses.total.backward())
    };
    network = step(network);
    let started = Instant::now();
    for _ in 0..steps {
        network = step(network);
    }
    // A GPU runs behind the host: the clock stops when its queue is done.
    device.sync().context("waiting for the device")?;
    let train_images_per_s = (steps * batch) as f64 / started.elapsed().as_secs_f64();

    let plain = device.without_autodiff();
    let model = network.valid();
    let inputs = train::step::synthetic_batch(&config, batch, &plain).inputs;
    let _ = model.detect(&config, inputs.clone());
    let started = Instant::now();
    for _ in 0..steps {
        let _ = model.detect(&config, inputs.clone());
    }
    plain.sync().context("waiting for the device")?;
    let infer_ms_per_image = started.elapsed().as_secs_f64() * 1e3 / (steps * batch) as f64;
    Ok(Figures {
        backbone,
        backend,
        width,
        batch,
        train_images_per_s,
        infer_ms_per_image,
        peak_rss_mb: peak_rss_mb(),
        parameters: model.num_params(),
    })
}

/// The process's peak resident memory (Linux `VmHWM`), in MB.
pub fn peak_rss_mb() -> f64 {
    let status = std::fs::read_to_string("/proc/self/status").unwrap_or_default();
    status
        .lines()
        .find(|l| l.starts_with("VmHWM:"))
        .and_then(|l| l.split_whitespace().nth(1))
        .and_then(|kb| kb.parse::<f64>().ok())
        .map_or(f64::NAN, |kb| kb / 1024.0)
}
