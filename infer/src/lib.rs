//! The detector networks and everything that runs after training: box
//! operations, anchors, RoIAlign, the three networks, checkpoints, detection
//! on an image and evaluation.

pub mod anchors;
pub mod backend;
pub mod boxes;
pub mod checkpoint;
pub mod config;
pub mod corner_response;
pub mod detector;
pub mod detector_args;
pub mod eval;
pub mod faster_rcnn;
pub mod grid_net;
pub mod kernels;
pub mod labeled;
pub mod metrics;
pub mod network;
pub mod point_eval;
pub mod pretrained;
pub mod roi_align;
pub mod trunk;

pub use config::{Backbone, DetectorConfig};
pub use detector::Detector;
pub use network::{Detection, Network};

use burn::prelude::*;

/// A tensor's values on the host, as `f32`.
pub fn host<const D: usize>(t: Tensor<D>) -> Vec<f32> {
    t.into_data().try_into_vec_as::<f32>().expect("float tensors convert to f32")
}
