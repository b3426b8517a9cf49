//! torchvision weights load into our VGG16 and AlexNet and give torchvision's
//! outputs. The fixtures are reduced-width torchvision networks with seeded
//! random weights, written by `fixtures/make_pretrained_parity.py` (VGG16 as
//! a PyTorch `.pth`, AlexNet as `.safetensors`).
//!
//! Tolerance: 1e-4 relative to the largest output magnitude (f32 sums in a
//! different order through 13 layers).

use std::path::PathBuf;

use burn::prelude::*;
use infer::config::GridHead;
use infer::network::Network;
use infer::pretrained::{InputConvention, PretrainedError, load_trunk};
use infer::{Backbone, DetectorConfig};

/// The package folder, read when the test runs (cargo sets it), so that a
/// test binary reused from another checkout still finds its files.
fn manifest_dir() -> std::path::PathBuf {
    std::env::var_os("CARGO_MANIFEST_DIR").map_or_else(|| env!("CARGO_MANIFEST_DIR").into(), Into::into)
}

const SIZE: usize = 224;

fn fixture(name: &str) -> PathBuf {
    manifest_dir().join("tests/fixtures").join(name)
}

fn reference() -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(fixture("pretrained_parity.json")).unwrap()).unwrap()
}

fn config(backbone: Backbone) -> DetectorConfig {
    let mut c = DetectorConfig::new(backbone, 0.0625);
    c.hidden = 64;
    // torchvision's classifier, whose hidden layers the fixtures hold.
    c.grid_head = GridHead::Fc;
    c
}

/// The script's input: (7 i + 13 j) mod 17, over 16.
fn input(device: &Device) -> Tensor<4> {
    let values: Vec<f32> = (0..SIZE * SIZE).map(|k| ((7 * (k / SIZE) + 13 * (k % SIZE)) % 17) as f32 / 16.0).collect();
    Tensor::from_data(TensorData::new(values, [1, 1, SIZE, SIZE]), device)
}

fn assert_close(what: &str, ours: &[f32], theirs: &serde_json::Value) {
    let theirs: Vec<f32> = theirs.as_array().unwrap().iter().map(|v| v.as_f64().unwrap() as f32).collect();
    assert_eq!(ours.len(), theirs.len(), "{what}: length");
    let scale = theirs.iter().fold(0.0f32, |m, v| m.max(v.abs()));
    assert!(scale > 1e-3, "{what}: the reference is all zeros, the test would prove nothing");
    let worst = ours.iter().zip(&theirs).map(|(a, b)| (a - b).abs()).fold(0.0f32, f32::max);
    assert!(worst <= 1e-4 * scale, "{what}: max difference {worst} (scale {scale})");
}

fn check(backbone: Backbone, file: &str, key: &str) {
    let device = Device::flex();
    let config = config(backbone);
    let mut network = Network::new(&config, &device);
    let report = load_trunk(&mut network, &config, &fixture(file), InputConvention::Raw, false).unwrap();
    // Every convolution and both hidden layers; the 10-class layer is unused.
    let convs = network.trunk_convs().len();
    assert_eq!(report.loaded.len(), convs + 2, "{report:?}");
    assert!(report.unused.iter().all(|k| k.starts_with("classifier.6")), "{:?}", report.unused);
    let Network::Grid(net) = network.valid() else { unreachable!() };
    let trunk = net.trunk(input(&device));
    let reference = reference();
    let want = &reference[key];
    let shape: Vec<usize> =
        want["trunk_shape"].as_array().unwrap().iter().map(|v| v.as_u64().unwrap() as usize).collect();
    assert_eq!(trunk.dims().to_vec(), shape);
    assert_close(&format!("{key} trunk"), &infer::host(trunk.clone()), &want["trunk"]);
    assert_close(&format!("{key} hidden"), &infer::host(net.hidden(trunk).expect("the fc head")), &want["hidden"]);
}

#[test]
fn vgg16_from_pytorch_file_matches_torchvision() {
    check(Backbone::Vgg16, "vgg16_w16.pth", "vgg16");
}

#[test]
fn alexnet_from_safetensors_matches_torchvision() {
    check(Backbone::Alexnet, "alexnet_w16.safetensors", "alexnet");
}

#[test]
fn the_conv_grid_head_takes_the_convolutions_and_the_stride_16_features() {
    let device = Device::flex();
    let mut config = config(Backbone::Vgg16);
    config.grid_head = GridHead::Conv;
    let mut network = Network::new(&config, &device);
    let report = load_trunk(&mut network, &config, &fixture("vgg16_w16.pth"), InputConvention::Raw, false).unwrap();
    assert_eq!(report.loaded.len(), 13, "{report:?}");
    assert!(report.unused.iter().any(|k| k.starts_with("classifier.0")), "{:?}", report.unused);
    let Network::Grid(net) = network.valid() else { unreachable!() };
    let features = net.trunk(input(&device));
    assert_eq!(features.dims(), [1, 32, 14, 14]);
    // torchvision's trunk is these features after the last 2x2 max pooling
    // (its 7x7 average pooling of a 7x7 map changes nothing).
    let pooled = net.trunk.pool().forward(features);
    assert_close("vgg16 conv-head trunk, pooled", &infer::host(pooled), &reference()["vgg16"]["trunk"]);
}

#[test]
fn faster_rcnn_trunk_loads_the_vgg16_convolutions() {
    let device = Device::flex();
    let config = config(Backbone::FasterRcnn);
    let mut network = Network::new(&config, &device);
    let report = load_trunk(&mut network, &config, &fixture("vgg16_w16.pth"), InputConvention::Raw, false).unwrap();
    // 13 convolutions; fc6 takes RoIs of 32 x 7 x 7 as torchvision's
    // classifier.0 takes the pooled trunk, so it loads too.
    assert_eq!(report.loaded.len(), 15, "{report:?}");
    let Network::FasterRcnn(net) = network.valid() else { unreachable!() };
    let features = net.trunk(input(&device));
    assert_eq!(features.dims(), [1, 32, 14, 14]);
}

#[test]
fn another_architecture_is_refused_with_the_missing_and_misshapen_tensors() {
    let device = Device::flex();
    let config = config(Backbone::Alexnet);
    let mut network = Network::new(&config, &device);
    let before = infer::host(network.trunk_convs()[0].weight.val());
    let err = load_trunk(&mut network, &config, &fixture("vgg16_w16.pth"), InputConvention::Raw, false).unwrap_err();
    let text = err.to_string();
    assert!(matches!(err, PretrainedError::Mismatch { .. }), "{text}");
    assert!(text.contains("vgg16_w16.pth") && text.contains("wrong shape: features.0.weight"), "{text}");
    assert!(text.contains("missing: features.8.weight"), "{text}");
    // Nothing changed.
    assert_eq!(infer::host(network.trunk_convs()[0].weight.val()), before);
}

#[test]
fn another_width_is_refused() {
    let device = Device::flex();
    let mut config = config(Backbone::Vgg16);
    config.width = 0.125;
    let mut network = Network::new(&config, &device);
    let err = load_trunk(&mut network, &config, &fixture("vgg16_w16.pth"), InputConvention::Raw, false).unwrap_err();
    assert!(err.to_string().contains("at width 0.125"), "{err}");
}

#[test]
fn a_narrower_trunk_keeps_the_strongest_filters_when_pruning() {
    let device = Device::flex();
    // Half the fixture's width: 4 of 8 filters in features.5, 16 of 32 later.
    let mut config = config(Backbone::Vgg16);
    config.width = 1.0 / 32.0;
    let mut network = Network::new(&config, &device);
    let err = load_trunk(&mut network, &config, &fixture("vgg16_w16.pth"), InputConvention::Raw, false).unwrap_err();
    assert!(err.to_string().contains("--pretrained-prune"), "{err}");
    let report = load_trunk(&mut network, &config, &fixture("vgg16_w16.pth"), InputConvention::Raw, true).unwrap();
    assert_eq!(report.loaded.len(), 13, "{report:?}");
    assert_eq!(report.skipped.len(), 2, "the hidden layers no longer fit: {report:?}");
    let file = infer::pretrained::read_tensors(&fixture("vgg16_w16.pth")).unwrap();
    // features.5 (our conv 2) takes all 4 inputs of conv 1, which was not pruned.
    let theirs = &file["features.5.weight"];
    assert_eq!(theirs.shape, [8, 4, 3, 3]);
    let ours = infer::host(network.trunk_convs()[2].weight.val());
    let rows: Vec<&[f32]> = theirs.values.chunks(36).collect();
    let l1 = |r: &[f32]| r.iter().map(|v| v.abs()).sum::<f32>();
    let kept: Vec<usize> = ours.chunks(36).map(|o| rows.iter().position(|r| *r == o).expect("a file filter")).collect();
    assert!(kept.windows(2).all(|w| w[0] < w[1]), "original order: {kept:?}");
    let weakest_kept = kept.iter().map(|&k| l1(rows[k])).fold(f32::MAX, f32::min);
    let strongest_dropped = (0..8).filter(|k| !kept.contains(k)).map(|k| l1(rows[k])).fold(0.0, f32::max);
    assert!(weakest_kept >= strongest_dropped);
}

#[test]
fn truncated_and_missing_files_name_the_file() {
    let device = Device::flex();
    let config = config(Backbone::Alexnet);
    let dir = tempfile::tempdir().unwrap();
    for (name, keep) in [("cut.safetensors", 5000), ("cut.pth", 5000), ("empty.pth", 0)] {
        let src = if name.ends_with("pth") { "vgg16_w16.pth" } else { "alexnet_w16.safetensors" };
        let bytes = std::fs::read(fixture(src)).unwrap();
        let path = dir.path().join(name);
        std::fs::write(&path, &bytes[..keep]).unwrap();
        let mut network = Network::new(&config, &device);
        let err = load_trunk(&mut network, &config, &path, InputConvention::Auto, false).unwrap_err();
        assert!(matches!(err, PretrainedError::Read { .. }), "{name}: {err}");
        assert!(err.to_string().contains(name), "{err}");
    }
    let mut network = Network::new(&config, &device);
    let err =
        load_trunk(&mut network, &config, &dir.path().join("nope.pth"), InputConvention::Auto, false).unwrap_err();
    assert!(err.to_string().contains("nope.pth: no such file"), "{err}");
}
