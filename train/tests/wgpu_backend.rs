//! The GPU path (`--backend wgpu`), built only with the `wgpu` feature:
//! `cargo test --release -p train --features wgpu --test wgpu_backend`.
//! It needs a wgpu adapter (a GPU driver, or Mesa's lavapipe software Vulkan
//! driver) and fails, saying so, where there is none.
//!
//! The shipped detectors give the same detections on wgpu as on the CPU, and
//! training steps give the same losses on both.
#![cfg(feature = "wgpu")]

mod common;

use std::path::Path;

use common::tiny_data;
use infer::Detector;
use infer::backend::ComputeBackend;
use infer::config::Backbone;

fn wgpu() -> burn::prelude::Device {
    ComputeBackend::Wgpu.device().unwrap_or_else(|e| panic!("{e}"))
}

fn test_images() -> Vec<image::DynamicImage> {
    (4..6).map(|i| datasets::atomic::read_image(&tiny_data().join(format!("images/{i:06}.png"))).unwrap()).collect()
}

#[test]
fn shipped_detectors_find_the_same_corners_on_wgpu_as_on_the_cpu() {
    let images = test_images();
    for backbone in [Backbone::FasterRcnn, Backbone::Vgg16, Backbone::Alexnet] {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../checkpoints").join(backbone.name());
        let mut cpu = Detector::load(&dir, ComputeBackend::Flex.device().unwrap()).unwrap();
        let mut gpu = Detector::load(&dir, wgpu()).unwrap();
        // Low threshold, so that there is much to compare.
        cpu.config.detection.score_threshold = 0.05;
        gpu.config.detection.score_threshold = 0.05;
        for image in &images {
            let (a, b) = (cpu.detect(image), gpu.detect(image));
            assert!(!a.is_empty(), "{backbone}: no detections to compare");
            // Float sums run in another order on the GPU: scores near the
            // threshold or near a tie in NMS may differ; the confident ones may not.
            let confident = |d: &[infer::Detection]| d.iter().filter(|d| d.score >= 0.3).count();
            assert_eq!(confident(&a), confident(&b), "{backbone}: {a:?} vs {b:?}");
            for d in a.iter().filter(|d| d.score >= 0.3) {
                let nearest = b
                    .iter()
                    .map(|e| {
                        let corners = [
                            (d.bbox.x1 - e.bbox.x1).abs(),
                            (d.bbox.y1 - e.bbox.y1).abs(),
                            (d.bbox.x2 - e.bbox.x2).abs(),
                            (d.bbox.y2 - e.bbox.y2).abs(),
                        ];
                        (corners.into_iter().fold(0.0f32, f32::max), (d.score - e.score).abs())
                    })
                    .min_by(|x, y| x.0.total_cmp(&y.0))
                    .unwrap();
                assert!(nearest.0 < 0.05 && nearest.1 < 1e-3, "{backbone}: {d:?} has no twin on wgpu: {nearest:?}");
            }
        }
    }
}

/// Three training steps (losses, backward, AdamW) from the same shipped
/// weights on the CPU and on wgpu: the losses of every step agree, so the
/// gradients and the optimizer's update agree too.
#[test]
fn training_steps_on_wgpu_match_the_cpu() {
    for backbone in [Backbone::Alexnet, Backbone::Vgg16, Backbone::FasterRcnn] {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../checkpoints").join(backbone.name());
        let mut histories = Vec::new();
        for device in [ComputeBackend::Flex.device().unwrap(), wgpu()] {
            let device = device.autodiff();
            let (config, mut network, _) = infer::checkpoint::load(&dir, &device).unwrap();
            let data = train::step::synthetic_batch(&config, 2, &device);
            let mut optim = train::fused_adamw::FusedAdamW::new(1e-4).init(None);
            // The same seed: Faster R-CNN samples the same anchors and proposals.
            let mut rng = <rand::rngs::ChaCha8Rng as rand::SeedableRng>::seed_from_u64(3);
            let mut losses = Vec::new();
            for _ in 0..3 {
                let l = train::step::batch_losses(&network, &config, &data, &mut rng);
                losses.push(l.total.clone().into_scalar::<f32>());
                network = train::trainer::apply(network, &mut optim, 1e-3, l.total.backward());
            }
            histories.push(losses);
        }
        let (cpu, gpu) = (&histories[0], &histories[1]);
        eprintln!("{backbone}: losses {cpu:?} on the CPU, {gpu:?} on wgpu");
        let close = |a: f32, b: f32, tolerance: f32| (a - b).abs() <= tolerance * a.abs();
        // The first loss is the forward pass alone: equal up to float order.
        // Later ones follow AdamW steps, whose first moves are about lr times
        // the gradient's sign, so a gradient near zero that rounds the other
        // way moves its weight the other way: they agree more loosely.
        assert!(close(cpu[0], gpu[0], 1e-4), "{backbone}: losses {cpu:?} on the CPU, {gpu:?} on wgpu");
        for (a, b) in cpu.iter().zip(gpu).skip(1) {
            assert!(close(*a, *b, 3e-2), "{backbone}: losses {cpu:?} on the CPU, {gpu:?} on wgpu");
        }
        // The steps moved the loss by far more than that tolerance: a device
        // that skipped or botched the update would fail the comparison above.
        assert!((cpu[2] - cpu[0]).abs() > 0.1 * cpu[0].abs(), "{backbone}: {cpu:?}");
    }
}
