//! A checkpoint whose weights hold a NaN (a diverged run, a corrupt copy) is
//! refused on loading, naming the file and the layer, instead of giving NaN
//! boxes and no detections.

use burn::module::Param;
use infer::checkpoint::{CheckpointMeta, load, save};
use infer::config::{Backbone, DetectorConfig};
use infer::network::Network;

#[test]
fn nan_weights_are_refused_with_the_layer_named() {
    let device = infer::backend::ComputeBackend::default().device().unwrap();
    let mut config = DetectorConfig::new(Backbone::Alexnet, 0.125);
    config.hidden = 64;
    let meta = CheckpointMeta {
        format_version: 1,
        backbone: Backbone::Alexnet,
        width: 0.125,
        dataset: "none".into(),
        epochs: 0,
        metrics: None,
        pretrained: None,
        train_seconds: 0.0,
        parameters: 0,
    };
    let dir = tempfile::tempdir().unwrap();
    let good = dir.path().join("good");
    let mut network = Network::new(&config, &device);
    assert_eq!(network.first_non_finite(), None);
    save(&good, &config, &network, &meta).unwrap();
    assert!(load(&good, &device).is_ok());

    let (convs, _) = network.trunk_layers_mut();
    let weight = convs[1].weight.val();
    let mask = weight.clone().zeros_like().slice([0..1, 0..1, 0..1, 0..1]).add_scalar(f32::NAN);
    convs[1].weight = Param::from_tensor(weight.slice_assign([0..1, 0..1, 0..1, 0..1], mask));
    let (param, count) = network.first_non_finite().expect("the NaN is found");
    assert_eq!(count, 1);
    assert!(param.contains("features") && param.contains('1') && param.ends_with("weight"), "{param}");
    let bad = dir.path().join("bad");
    save(&bad, &config, &network, &meta).unwrap();
    let Err(error) = load(&bad, &device) else { panic!("NaN weights were loaded") };
    let message = error.to_string();
    assert!(message.contains("model.bpk") && message.contains(&param) && message.contains("NaN"), "{message}");
}
