//! Detection on decoded images with a loaded checkpoint: the library call the
//! localization crate uses. The model is loaded once and reused.

use std::path::Path;

use burn::prelude::*;
use image::{DynamicImage, GrayImage};

use crate::checkpoint::{self, CheckpointError, CheckpointMeta};
use crate::config::DetectorConfig;
use crate::network::{Detection, Network};
use datasets::preprocess::{ImageToNet, preprocess};

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
        let edges: Vec<GrayImage> = images.iter().map(|im| preprocess(im, &self.config.preprocess)).collect();
        let found = self.detect_inputs(&edges);
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
    pub fn detect_inputs(&self, edges: &[GrayImage]) -> Vec<Vec<Detection>> {
        let inputs = input_tensor(edges, &self.device);
        self.network.detect(&self.config, inputs)
    }
}

/// Stacks preprocessed edge images (0 or 255) into a `[B, 1, S, S]` tensor of 0..1.
pub fn input_tensor(edges: &[GrayImage], device: &Device) -> Tensor<4> {
    let (w, h) = edges[0].dimensions();
    let mut data = Vec::with_capacity(edges.len() * (w * h) as usize);
    for e in edges {
        data.extend(e.as_raw().iter().map(|&v| v as f32 / 255.0));
    }
    Tensor::<4>::from_data(TensorData::new(data, [edges.len(), 1, h as usize, w as usize]), device)
}
