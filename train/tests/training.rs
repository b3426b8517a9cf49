//! Training evidence on tiny generated data: the loss of each network falls
//! well below its start when it overfits a few images, a saved checkpoint
//! reloads to the figures its network scored in memory, and bad checkpoints are named.

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
fn a_checkpoint_reloads_to_what_its_network_scored_and_bad_ones_are_named() {
    let _turn = one_at_a_time();
    let run = tempfile::tempdir().unwrap();
    train::train(Some(tiny_config(Backbone::FasterRcnn, 4)), run.path(), false).unwrap();
    let dir = run.path().join("checkpoint");
    // The trainer scored the network in memory on the test split and wrote
    // the figures beside the weights; the weights read back must score the
    // same, to the last bit, with detections to score.
    let loaded = Detector::load(&dir, burn::prelude::Device::flex()).unwrap();
    let saved = loaded.meta.metrics.clone().expect("the final evaluation is in meta.json");
    assert!(saved.detections > 0 && saved.ground_truths > 0, "{saved:?}");
    let test = infer::labeled::load_coco_set(&tiny_data().join("test.json"), &loaded.config.preprocess).unwrap();
    assert_eq!(infer::eval::evaluate_set(&loaded, &test, 2), saved);
    assert_eq!(loaded.meta.backbone, Backbone::FasterRcnn);

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
