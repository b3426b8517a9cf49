//! An interrupted run resumes to the same losses as an uninterrupted one.
//! Alone in its test binary: Burn's CPU backend draws weights and dropout
//! masks from one process-wide generator, which parallel tests would share.

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use datasets::generate::{DatagenConfig, generate};
use infer::backend::CpuBackend;
use infer::config::Backbone;
use train::TrainConfig;

/// Four training images and two test images, generated once.
fn tiny_data() -> &'static PathBuf {
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

fn tiny_config(backbone: Backbone, epochs: usize) -> TrainConfig {
    let mut c = TrainConfig::new(backbone, 0.125, tiny_data().clone());
    c.epochs = epochs;
    c.batch_size = 2;
    c.val_fraction = 0.0;
    c.augment = false;
    c.warmup_iterations = 3;
    c.backend = CpuBackend::Flex;
    c
}

/// The per-iteration training losses of a run.
fn train_losses(run: &Path) -> Vec<f64> {
    let csv = std::fs::read_to_string(run.join("losses.csv")).unwrap();
    csv.lines().filter(|l| l.starts_with("train,")).map(|l| l.split(',').nth(3).unwrap().parse().unwrap()).collect()
}

#[test]
fn an_interrupted_run_resumes_to_the_same_losses() {
    let whole = tempfile::tempdir().unwrap();
    train::train(Some(tiny_config(Backbone::Alexnet, 3)), whole.path(), false).unwrap();
    // The same run interrupted after its first epoch, then resumed.
    let parts = tempfile::tempdir().unwrap();
    let stopped =
        train::trainer::train_until(Some(tiny_config(Backbone::Alexnet, 3)), parts.path(), false, Some(1)).unwrap();
    assert!(stopped.is_none());
    assert_eq!(train_losses(parts.path()).len(), 2, "one epoch of two iterations logged");
    train::train(None, parts.path(), false).unwrap();
    let (a, b) = (train_losses(whole.path()), train_losses(parts.path()));
    assert_eq!(a.len(), b.len());
    for (k, (x, y)) in a.iter().zip(&b).enumerate() {
        assert_eq!(x, y, "iteration {k}: uninterrupted vs resumed (the log keeps 6 decimals)");
    }
}
