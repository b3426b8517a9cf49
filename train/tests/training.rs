//! Training evidence on tiny generated data: the loss of each network falls
//! well below its start when it overfits a few images, a saved checkpoint
//! reloads to the same detections, and bad checkpoints are named.

mod common;

use std::path::Path;

use common::{tiny_config, tiny_data};
use infer::Detector;
use infer::config::Backbone;

/// Burn's CPU backend draws weights from one process-wide generator: the
/// tests of this file take turns so that each run is repeatable.
fn one_at_a_time() -> std::sync::MutexGuard<'static, ()> {
    static TURN: std::sync::Mutex<()> = std::sync::Mutex::new(());
    TURN.lock().unwrap_or_else(|poisoned| poisoned.into_inner())
}

fn overfit(backbone: Backbone, epochs: usize, lr: f64) {
    let _turn = one_at_a_time();
    let run = tempfile::tempdir().unwrap();
    let mut config = tiny_config(backbone, epochs);
    config.lr = lr;
    train::train(Some(config), run.path(), false).unwrap();
    // Faster R-CNN's box loss is normalised over all sampled RoIs, so it
    // grows as more proposals become positive while the network learns:
    // its overfitting shows in the two classification parts (RPN
    // objectness, RoI classifier). The grid networks' whole loss falls.
    let csv = std::fs::read_to_string(run.path().join("losses.csv")).unwrap();
    let epochs: Vec<Vec<f64>> = csv
        .lines()
        .filter(|l| l.starts_with("train_epoch,"))
        .map(|l| l.split(',').skip(3).take(5).map(|v| v.parse().unwrap()).collect())
        .collect();
    let measure = |e: &Vec<f64>| if backbone == Backbone::FasterRcnn { e[1] + e[3] } else { e[0] };
    let (start, end) = (measure(&epochs[0]), measure(&epochs[epochs.len() - 1]));
    assert!(end < 0.5 * start, "{backbone}: loss went from {start:.4} to {end:.4}: {:?}", &epochs[epochs.len() - 3..]);
    for file in [
        "train_config.json",
        "losses.csv",
        "metrics.json",
        "checkpoint/config.json",
        "checkpoint/model.bpk",
        "checkpoint/meta.json",
    ] {
        assert!(run.path().join(file).is_file(), "{file} missing");
    }
}

#[test]
fn faster_rcnn_overfits_a_few_images() {
    overfit(Backbone::FasterRcnn, 80, 2e-3);
}

#[test]
fn vgg16_overfits_a_few_images() {
    overfit(Backbone::Vgg16, 40, 3e-3);
}

#[test]
fn alexnet_overfits_a_few_images() {
    overfit(Backbone::Alexnet, 40, 3e-3);
}

#[test]
fn a_checkpoint_reloads_to_the_same_detections_and_bad_ones_are_named() {
    let _turn = one_at_a_time();
    let run = tempfile::tempdir().unwrap();
    train::train(Some(tiny_config(Backbone::FasterRcnn, 2)), run.path(), false).unwrap();
    let dir = run.path().join("checkpoint");
    let image = datasets::atomic::read_image(&tiny_data().join("images/000004.png")).unwrap();
    let mut a = Detector::load(&dir, burn::prelude::Device::flex()).unwrap();
    let mut b = Detector::load(&dir, burn::prelude::Device::flex()).unwrap();
    // Low threshold so that an undertrained model still reports boxes.
    a.config.detection.score_threshold = 0.0;
    b.config.detection.score_threshold = 0.0;
    let (da, db) = (a.detect(&image), b.detect(&image));
    assert!(!da.is_empty());
    assert_eq!(da, db);
    assert_eq!(a.meta.backbone, Backbone::FasterRcnn);
    assert!(a.meta.metrics.is_some());

    // A config of another width than the weights: the error names the file.
    let config_path = dir.join("config.json");
    let text = std::fs::read_to_string(&config_path).unwrap();
    std::fs::write(&config_path, text.replace("\"width\": 0.125", "\"width\": 0.25")).unwrap();
    let err = Detector::load(&dir, burn::prelude::Device::flex()).err().unwrap().to_string();
    assert!(err.contains("model.bpk") && err.contains("do not fit"), "{err}");
    // Another backbone.
    std::fs::write(&config_path, text.replace("faster-rcnn", "vgg16")).unwrap();
    assert!(Detector::load(&dir, burn::prelude::Device::flex()).is_err());
    // Truncated weights.
    std::fs::write(&config_path, &text).unwrap();
    let weights = dir.join("model.bpk");
    let bytes = std::fs::read(&weights).unwrap();
    std::fs::write(&weights, &bytes[..bytes.len() / 2]).unwrap();
    let err = Detector::load(&dir, burn::prelude::Device::flex()).err().unwrap().to_string();
    assert!(err.contains("model.bpk"), "{err}");
    // Not a checkpoint at all.
    let err = Detector::load(Path::new("/nonexistent/run"), burn::prelude::Device::flex()).err().unwrap().to_string();
    assert!(err.contains("/nonexistent/run"), "{err}");
}
