//! Detection on decoded images with a loaded checkpoint: the library call the
//! localization crate uses. The model is loaded once and reused.

use std::path::Path;

use burn::prelude::*;
use image::DynamicImage;

use crate::checkpoint::{self, CheckpointError, CheckpointMeta};
use crate::config::DetectorConfig;
use crate::network::{Detection, Network};
use datasets::preprocess::{ImageToNet, NetInput, network_input};

pub struct Detector {
    pub config: DetectorConfig,
    pub meta: CheckpointMeta,
    network: Network,
    device: Device,
}

impl Detector {
    /// Loads a checkpoint folder for inference on `device` (no autodiff).
    pub fn load(dir: &Path, device: Device) -> Result<Self, CheckpointError> {
        let device = device.without_autodiff();
        let (config, network, meta) = checkpoint::load(dir, &device)?;
        Ok(Self { config, meta, network: network.valid(), device })
    }

    pub fn from_network(config: DetectorConfig, meta: CheckpointMeta, network: &Network, device: Device) -> Self {
        Self { config, meta, network: network.valid(), device }
    }

    /// Detections on one image, in its own pixel coordinates.
    pub fn detect(&self, image: &DynamicImage) -> Vec<Detection> {
        self.detect_many(std::slice::from_ref(image)).pop().unwrap_or_default()
    }

    /// Detections on several images at once (one batch).
    pub fn detect_many(&self, images: &[DynamicImage]) -> Vec<Vec<Detection>> {
        if images.is_empty() {
            return Vec::new();
        }
        let inputs: Vec<NetInput> = images.iter().map(|im| network_input(im, &self.config.preprocess)).collect();
        let found = self.detect_inputs(&inputs);
        found
            .into_iter()
            .zip(images)
            .map(|(dets, im)| {
                let map = ImageToNet::new(im.width(), im.height(), self.config.preprocess.size);
                dets.into_iter().map(|d| Detection { bbox: map.to_image(&d.bbox), ..d }).collect()
            })
            .collect()
    }

    /// Detections on already preprocessed network inputs, in input pixels.
    pub fn detect_inputs(&self, inputs: &[NetInput]) -> Vec<Vec<Detection>> {
        let inputs = input_tensor(inputs, &self.device);
        self.network.detect(&self.config, inputs)
    }
}

/// Stacks preprocessed inputs (all of one size and channel count) into a
/// `[B, C, S, S]` tensor of their network values ([`NetInput::values`]).
pub fn input_tensor(inputs: &[NetInput], device: &Device) -> Tensor<4> {
    let (w, h) = inputs[0].edges().dimensions();
    let channels = inputs[0].planes.len();
    let mut data = Vec::with_capacity(inputs.len() * channels * (w * h) as usize);
    for input in inputs {
        for c in 0..channels {
            data.extend(input.values(c));
        }
    }
    Tensor::<4>::from_data(TensorData::new(data, [inputs.len(), channels, h as usize, w as usize]), device)
}
