//! Tiny generated data and settings shared by the training test binaries.

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use datasets::simulator::generate::{DatagenConfig, generate};
use infer::backend::ComputeBackend;
use infer::config::Backbone;
use train::TrainConfig;

/// Four training images and two test images, generated once.
pub fn tiny_data() -> &'static PathBuf {
    static DATA: OnceLock<PathBuf> = OnceLock::new();
    DATA.get_or_init(|| {
        let dir = tempfile::tempdir().unwrap().keep();
        let mut c = DatagenConfig::default();
        c.detection.images = 6;
        c.detection.train = 4;
        c.sequence.frames = Some(1);
        generate(&dir, &c).unwrap();
        dir.join("detection")
    })
}

#[allow(dead_code)] // not every test binary uses it
pub fn tiny_config(backbone: Backbone, epochs: usize) -> TrainConfig {
    let mut c = TrainConfig::new(backbone, 0.125, tiny_data().clone());
    c.epochs = epochs;
    c.batch_size = 2;
    c.val_fraction = 0.0;
    c.augment = false;
    c.warmup_iterations = 3;
    c.backend = ComputeBackend::Flex;
    c
}

/// The per-iteration training losses of a run.
#[allow(dead_code)] // not every test binary uses it
pub fn train_losses(run: &Path) -> Vec<f64> {
    let csv = std::fs::read_to_string(run.join("losses.csv")).unwrap();
    csv.lines().filter(|l| l.starts_with("train,")).map(|l| l.split(',').nth(3).unwrap().parse().unwrap()).collect()
}
