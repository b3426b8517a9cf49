//! `bench conv`: GFLOP/s of the three convolution kernels (forward, input
//! gradient, weight gradient), the project's GEMM kernels next to Burn's own
//! flex kernels, for the reference layer (64->64 3x3 on 8x64x112x112, the
//! layer the PyTorch comparison measures) and for every convolution of the
//! default networks.

use std::time::Instant;

use anyhow::Result;
use burn::backend::ops::{ConvOptions, FloatTensorOps, ModuleOps};
use burn::backend::tensor::FloatTensor;
use burn::backend::{Flex, TensorMetadata};
use burn::prelude::*;
use infer::config::{Backbone, DEFAULT_WIDTH, DetectorConfig};
use infer::kernels::conv_kernels::ConvGeometry;
use infer::kernels::conv_op::{conv_options, flex_forward, flex_input_grad, flex_weight_grad};
use infer::network::Network;
use rand::rngs::ChaCha8Rng;
use rand::{RngExt, SeedableRng};

/// One convolution to time.
struct Layer {
    name: String,
    x: [usize; 4],
    weight: [usize; 4],
    options: ConvOptions<2>,
}

#[derive(serde::Serialize)]
pub struct KernelFigures {
    layer: String,
    gflop: f64,
    /// The kernels the project trains with.
    forward_gflops: f64,
    input_grad_gflops: f64,
    weight_grad_gflops: f64,
    /// Burn 0.22.1's own flex kernels on the same tensors.
    burn_forward_gflops: f64,
    burn_input_grad_gflops: f64,
    burn_weight_grad_gflops: f64,
}

fn reference_layer() -> Layer {
    Layer {
        name: "64->64 3x3 p1 on 8x64x112x112".into(),
        x: [8, 64, 112, 112],
        weight: [64, 64, 3, 3],
        options: ConvOptions::new([1, 1], [1, 1], [1, 1], 1),
    }
}

/// Every trunk convolution of `backbone` at the default width, batch 8,
/// with the input size each one sees.
fn network_layers(backbone: Backbone, batch: usize) -> Vec<Layer> {
    let config = DetectorConfig::new(backbone, DEFAULT_WIDTH);
    let device = Device::flex();
    let network = Network::new(&config, &device);
    let size = config.preprocess.size as usize;
    let image = Tensor::<4>::zeros([1, config.in_channels, size, size], &device);
    network
        .trunk_convs()
        .iter()
        .enumerate()
        .map(|(i, conv)| {
            let [_, c, h, w] = network.trunk_until(image.clone(), i).dims();
            Layer {
                name: format!("{} conv{}", backbone.name(), i + 1),
                x: [batch, c, h, w],
                weight: conv.weight.val().dims(),
                options: conv_options(conv).expect("the networks pad explicitly"),
            }
        })
        .collect()
}

fn random_flex(shape: [usize; 4], rng: &mut ChaCha8Rng) -> FloatTensor<Flex> {
    let values: Vec<f32> = (0..shape.iter().product()).map(|_| rng.random_range(-1.0..1.0)).collect();
    Flex::float_from_data(TensorData::new(values, shape), &Default::default())
}

/// Median seconds of `reps` runs of `f`, after one warm-up run.
fn median_secs(reps: usize, mut f: impl FnMut()) -> f64 {
    f();
    let mut times: Vec<f64> = (0..reps)
        .map(|_| {
            let started = Instant::now();
            f();
            started.elapsed().as_secs_f64()
        })
        .collect();
    times.sort_by(f64::total_cmp);
    times[times.len() / 2]
}

fn measure(layer: &Layer, reps: usize) -> KernelFigures {
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let o = &layer.options;
    let geo = ConvGeometry::new(layer.x, layer.weight, o.stride, o.padding, o.dilation, o.groups)
        .expect("a layer of a working network");
    let x = random_flex(layer.x, &mut rng);
    let w = random_flex(layer.weight, &mut rng);
    let b =
        Flex::float_from_data(TensorData::new(vec![0.1f32; layer.weight[0]], [layer.weight[0]]), &Default::default());
    let y = Flex::conv2d(x.clone(), w.clone(), Some(b.clone()), o.clone());
    let g = random_flex(y.shape().dims(), &mut rng);
    let gflops = |secs: f64| geo.flops() / secs / 1e9;
    KernelFigures {
        layer: layer.name.clone(),
        gflop: geo.flops() / 1e9,
        forward_gflops: gflops(median_secs(reps, || drop(flex_forward(x.clone(), w.clone(), b.clone(), o.clone())))),
        input_grad_gflops: gflops(median_secs(reps, || drop(flex_input_grad(&x, &w, &g, o.clone())))),
        weight_grad_gflops: gflops(median_secs(reps, || drop(flex_weight_grad(&x, &w, &g, o.clone())))),
        burn_forward_gflops: gflops(median_secs(reps, || {
            drop(Flex::conv2d(x.clone(), w.clone(), Some(b.clone()), o.clone()))
        })),
        burn_input_grad_gflops: gflops(median_secs(reps, || {
            drop(Flex::conv2d_x_backward(x.clone(), w.clone(), g.clone(), o.clone()))
        })),
        burn_weight_grad_gflops: gflops(median_secs(reps, || {
            drop(Flex::conv2d_weight_backward(x.clone(), w.clone(), g.clone(), o.clone()))
        })),
    }
}

pub fn run(reps: usize, json: bool) -> Result<()> {
    if json {
        println!("{}", serde_json::to_string(&measure(&reference_layer(), reps))?);
        return Ok(());
    }
    println!("GFLOP/s, project GEMM kernels / Burn flex kernels (median of {reps} runs)\n");
    println!("| layer | input | GFLOP | forward | input grad | weight grad |");
    println!("|---|---|---|---|---|---|");
    let mut layers = vec![reference_layer()];
    layers.extend(network_layers(Backbone::Vgg16, 8));
    layers.extend(network_layers(Backbone::Alexnet, 8));
    for layer in &layers {
        let f = measure(layer, reps);
        println!(
            "| {} | {:?} | {:.2} | {:.1} / {:.1} | {:.1} / {:.1} | {:.1} / {:.1} |",
            f.layer,
            layer.x,
            f.gflop,
            f.forward_gflops,
            f.burn_forward_gflops,
            f.input_grad_gflops,
            f.burn_input_grad_gflops,
            f.weight_grad_gflops,
            f.burn_weight_grad_gflops
        );
    }
    Ok(())
}
