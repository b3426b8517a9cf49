//! Transfer learning: a trunk file written by one network starts another;
//! frozen convolutions stay bit-identical through training while the rest
//! trains; cached frozen features give the same losses as running the
//! frozen layers on every step; a file of another network is refused.

mod common;

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use burn::prelude::*;
use common::{tiny_config, tiny_data, train_losses};
use infer::checkpoint;
use infer::config::{Backbone, DetectorConfig};
use infer::network::Network;
use infer::pretrained::{read_tensors, save_trunk};
use train::Start;

fn one_at_a_time() -> std::sync::MutexGuard<'static, ()> {
    static TURN: std::sync::Mutex<()> = std::sync::Mutex::new(());
    TURN.lock().unwrap_or_else(|poisoned| poisoned.into_inner())
}

/// A trunk file from a freshly drawn network of the tiny config's shape.
fn trunk_file(backbone: Backbone, dir: &Path, seed: u64) -> PathBuf {
    let config = tiny_config(backbone, 1).detector;
    let device = Device::flex();
    device.seed(seed);
    let network = Network::new(&config, &device);
    let path = dir.join(format!("{backbone}-trunk.safetensors"));
    save_trunk(&network, backbone, &path, HashMap::from([("note".into(), "test".into())])).unwrap();
    path
}

fn conv_weights(run: &Path) -> Vec<Vec<f32>> {
    let config = checkpoint::read_config(&run.join("checkpoint")).unwrap();
    let network = checkpoint::load_weights(&run.join("checkpoint"), &config, &Device::flex()).unwrap();
    network.trunk_convs().iter().map(|c| infer::host(c.weight.val())).collect()
}

#[test]
fn frozen_convolutions_stay_bit_identical_and_the_rest_trains() {
    let _turn = one_at_a_time();
    let dir = tempfile::tempdir().unwrap();
    let file = trunk_file(Backbone::Vgg16, dir.path(), 7);
    let start = read_tensors(&file).unwrap();
    let run = dir.path().join("run");
    let mut config = tiny_config(Backbone::Vgg16, 2);
    config.start = Start::Trunk(file.clone());
    config.freeze = 4;
    train::train(Some(config), &run, false).unwrap();
    let trained = conv_weights(&run);
    for (i, w) in trained.iter().enumerate() {
        let index = infer::pretrained::VGG16_FEATURE_INDEX[i];
        let before = &start[&format!("features.{index}.weight")].values;
        if i < 4 {
            assert_eq!(w, before, "frozen convolution {i} changed");
        } else {
            assert_ne!(w, before, "convolution {i} did not train");
        }
    }
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(run.join("pretrained.json")).unwrap()).unwrap();
    // The 13 convolutions; the conv grid head has no hidden layers to fill.
    assert_eq!(report["loaded"].as_array().unwrap().len(), 13);
    let meta = checkpoint::read_meta(&run.join("checkpoint")).unwrap();
    assert_eq!(meta.pretrained.as_deref(), Some(file.to_str().unwrap()));
}

#[test]
fn cached_frozen_features_give_the_losses_of_running_the_layers() {
    let _turn = one_at_a_time();
    let dir = tempfile::tempdir().unwrap();
    let file = trunk_file(Backbone::FasterRcnn, dir.path(), 9);
    let mut losses = Vec::new();
    for cache in [true, false] {
        let run = dir.path().join(format!("run-{cache}"));
        let mut config = tiny_config(Backbone::FasterRcnn, 2);
        config.start = Start::Trunk(file.clone());
        config.freeze = 7;
        config.cache_frozen = cache;
        // Flips on: the cache must hold both orientations.
        config.augment = true;
        config.val_fraction = 0.25;
        train::train(Some(config), &run, false).unwrap();
        losses.push(train_losses(&run));
    }
    assert_eq!(losses[0].len(), losses[1].len());
    for (a, b) in losses[0].iter().zip(&losses[1]) {
        assert!((a - b).abs() <= 1e-4 * a.abs().max(1.0), "cached {a} vs uncached {b}");
    }
}

#[test]
fn a_trunk_of_another_network_is_refused_before_training() {
    let _turn = one_at_a_time();
    let dir = tempfile::tempdir().unwrap();
    let file = trunk_file(Backbone::Alexnet, dir.path(), 3);
    let mut config = tiny_config(Backbone::Vgg16, 1);
    config.start = Start::Trunk(file);
    let err = train::train(Some(config), &dir.path().join("run"), false).unwrap_err();
    let text = format!("{err:#}");
    assert!(text.contains("alexnet-trunk.safetensors") && text.contains("missing: features.12.weight"), "{text}");
    assert!(!dir.path().join("run/losses.csv").exists());
}

#[test]
fn corpus_worlds_differ_and_are_valid() {
    let c = datasets::simulator::corpus::CorpusConfig::default();
    let worlds: Vec<_> = (0..c.worlds).map(|k| c.world(k)).collect();
    for w in &worlds {
        w.validate().unwrap();
    }
    assert_ne!(worlds[0], worlds[1]);
    // None is the evaluation data's geometry.
    assert!(worlds.iter().all(|w| *w != datasets::simulator::world::WorldConfig::default()));
}

#[test]
fn pretrain_writes_a_trunk_that_train_accepts() {
    let _turn = one_at_a_time();
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("pre");
    let run = |extra: &[&str]| {
        let status = std::process::Command::new(env!("CARGO_BIN_EXE_pretrain"))
            .args(["--backbone", "alexnet", "--width", "0.125", "--worlds", "2", "--images-per-world", "5"])
            .args(["--epochs", "1", "--out"])
            .arg(&out)
            .args(extra)
            .output()
            .unwrap();
        assert!(status.status.success(), "{}", String::from_utf8_lossy(&status.stderr));
        String::from_utf8_lossy(&status.stderr).into_owned()
    };
    run(&[]);
    let meta: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("meta.json")).unwrap()).unwrap();
    assert_eq!(meta["corpus_images"], 10);
    assert_eq!(meta["backbone"], "alexnet");
    // Run again: the corpus is reused, the finished run is not retrained.
    let second = run(&[]);
    assert!(second.contains("(reused)"), "{second}");

    let mut config = tiny_config(Backbone::Alexnet, 1);
    config.start = Start::Trunk(out.join("trunk.safetensors"));
    let detector = config.detector.clone();
    let mut network = Network::new(&detector, &Device::flex());
    let report = infer::pretrained::load_trunk(
        &mut network,
        &detector,
        &out.join("trunk.safetensors"),
        config.pretrained_input,
        false,
    )
    .unwrap();
    assert_eq!(report.loaded.len(), 5, "{report:?}");
    assert!(report.unused.iter().all(|k| !k.starts_with("features.")), "{report:?}");
}

/// A tiny faster-rcnn trained into `out`: its checkpoint folder, config and weights.
fn a_trained_checkpoint(out: &Path, device: &Device) -> (PathBuf, DetectorConfig, Network) {
    train::train(Some(tiny_config(Backbone::FasterRcnn, 1)), out, false).unwrap();
    let saved_dir = out.join("checkpoint");
    let config = checkpoint::read_config(&saved_dir).unwrap();
    let saved = checkpoint::load_weights(&saved_dir, &config, device).unwrap();
    (saved_dir, config, saved)
}

#[test]
fn a_checkpoint_folder_starts_every_layer_and_one_of_another_width_is_refused() {
    let _turn = one_at_a_time();
    let dir = tempfile::tempdir().unwrap();
    let device = Device::flex();
    let first = dir.path().join("first");
    let (saved_dir, _, saved) = a_trained_checkpoint(&first, &device);

    // The heads come from the folder too, not from a fresh draw.
    let config = tiny_config(Backbone::FasterRcnn, 1).detector;
    let loaded = checkpoint::load_for_fine_tuning(&saved_dir, &config, &device).unwrap();
    device.seed(99);
    let fresh = Network::new(&config, &device);
    let heads = |n: &Network| match n {
        Network::FasterRcnn(m) => [
            infer::host(m.rpn.cls.weight.val()),
            infer::host(m.box_head.fc6.weight.val()),
            infer::host(m.box_head.bbox_pred.weight.val()),
        ],
        Network::Grid(_) => unreachable!("a faster-rcnn checkpoint"),
    };
    assert_eq!(heads(&loaded), heads(&saved));
    assert_ne!(heads(&fresh), heads(&saved));

    // Through `train`: with the whole trunk frozen, its convolutions end
    // the run exactly as the folder had them.
    let second = dir.path().join("second");
    let mut fine_tune = tiny_config(Backbone::FasterRcnn, 1);
    fine_tune.start = Start::Detector(saved_dir.clone());
    fine_tune.freeze = Backbone::FasterRcnn.trunk_convs();
    train::train(Some(fine_tune), &second, false).unwrap();
    assert_eq!(conv_weights(&second), conv_weights(&first));

    // Another width has other layers: refused, naming the folder's config.
    let mut wider = tiny_config(Backbone::FasterRcnn, 1);
    wider.detector = infer::config::DetectorConfig::new(Backbone::FasterRcnn, 0.25);
    wider.start = Start::Detector(saved_dir);
    let err = train::train(Some(wider), &dir.path().join("third"), false).unwrap_err();
    let text = format!("{err:#}");
    assert!(text.contains("config.json") && text.contains("the layers differ"), "{text}");
    assert!(!dir.path().join("third/losses.csv").exists());
}

#[test]
fn an_edge_detector_starts_one_that_also_sees_the_gray_image_answering_as_before() {
    let _turn = one_at_a_time();
    let dir = tempfile::tempdir().unwrap();
    let device = Device::flex();
    let (saved_dir, edges_config, saved) = a_trained_checkpoint(&dir.path().join("edges"), &device);

    let mut gray = tiny_config(Backbone::FasterRcnn, 1);
    gray.detector.set_gray_channel(true);
    let widened = checkpoint::load_for_fine_tuning(&saved_dir, &gray.detector, &device).unwrap();
    let (old, new) = (&saved.trunk_convs()[0], &widened.trunk_convs()[0]);
    let [out, _, kh, kw] = old.weight.dims();
    assert_eq!(new.weight.dims(), [out, 2, kh, kw]);
    let (old_w, new_w) = (infer::host(old.weight.val()), infer::host(new.weight.val()));
    let k = kh * kw;
    for o in 0..out {
        assert_eq!(new_w[o * 2 * k..o * 2 * k + k], old_w[o * k..(o + 1) * k]);
        assert!(new_w[o * 2 * k + k..(o + 1) * 2 * k].iter().all(|&v| v == 0.0));
    }

    // On real inputs, the gray image beside the edges changes nothing yet.
    let test = tiny_data().join("test.json");
    let plain_set = infer::labeled::load_coco_set(&test, &edges_config.preprocess).unwrap();
    let gray_set = infer::labeled::load_coco_set(&test, &gray.detector.preprocess).unwrap();
    let stack = |set: &[infer::labeled::LabeledImage]| {
        infer::detector::input_tensor(&set.iter().map(|im| im.input.clone()).collect::<Vec<_>>(), &device)
    };
    let convs = saved.trunk_convs().len();
    let before = infer::host(saved.valid().trunk_until(stack(&plain_set), convs));
    let after = infer::host(widened.valid().trunk_until(stack(&gray_set), convs));
    assert_eq!(before.len(), after.len());
    let worst = before.iter().zip(&after).map(|(a, b)| (a - b).abs()).fold(0.0f32, f32::max);
    assert!(worst <= 1e-5, "features differ by {worst}");

    // Fine-tuning teaches the new channel: its weights leave zero.
    gray.start = Start::Detector(saved_dir.clone());
    let second = dir.path().join("gray");
    train::train(Some(gray), &second, false).unwrap();
    let trained = checkpoint::read_config(&second.join("checkpoint")).unwrap();
    assert_eq!((trained.in_channels, trained.preprocess.gray_channel), (2, true));
    let w = &conv_weights(&second)[0];
    assert!((0..out).any(|o| w[o * 2 * k + k..(o + 1) * 2 * k].iter().any(|&v| v != 0.0)));

    // The other way round would drop an input the network was trained on.
    let err = checkpoint::load_for_fine_tuning(&second.join("checkpoint"), &edges_config, &device).unwrap_err();
    assert!(format!("{err}").contains("2 input channels cannot start one of 1"), "{err}");
}

#[test]
fn a_trunk_file_of_edges_starts_the_edge_channel_of_a_gray_network() {
    let dir = tempfile::tempdir().unwrap();
    let path = trunk_file(Backbone::Vgg16, dir.path(), 5);
    let mut detector = tiny_config(Backbone::Vgg16, 1).detector;
    detector.set_gray_channel(true);
    let mut network = Network::new(&detector, &Device::flex());
    let report =
        infer::pretrained::load_trunk(&mut network, &detector, &path, infer::pretrained::InputConvention::Raw, false)
            .unwrap();
    assert!(report.skipped.is_empty(), "{report:?}");
    let file = &read_tensors(&path).unwrap()["features.0.weight"];
    let [out, one, kh, kw] = [file.shape[0], file.shape[1], file.shape[2], file.shape[3]];
    assert_eq!(one, 1);
    let ours = infer::host(network.trunk_convs()[0].weight.val());
    let k = kh * kw;
    assert_eq!(ours.len(), out * 2 * k);
    for o in 0..out {
        assert_eq!(ours[o * 2 * k..o * 2 * k + k], file.values[o * k..(o + 1) * k]);
        assert!(ours[o * 2 * k + k..(o + 1) * 2 * k].iter().all(|&v| v == 0.0));
    }
}
