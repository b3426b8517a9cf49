//! The native max pooling agrees with Burn's: output and input gradient on
//! seeded random shapes (VGG's 2x2/2 and AlexNet's 3x3/2, odd sizes, batch
//! 1 and 8), on ReLU outputs full of tied zeros, and with NaN in a window.

use burn::nn::pool::{MaxPool2d, MaxPool2dConfig};
use burn::prelude::*;
use burn::tensor::activation::relu;
use infer::kernels::max_pool_native::max_pool2d;
use rand::rngs::ChaCha8Rng;
use rand::{RngExt, SeedableRng};

fn values<const D: usize>(t: Tensor<D>) -> Vec<f32> {
    t.into_data().try_into_vec_as::<f32>().unwrap()
}

fn uniform(shape: [usize; 4], rng: &mut ChaCha8Rng, device: &Device) -> Tensor<4> {
    let data: Vec<f32> = (0..shape.iter().product()).map(|_| rng.random_range(-1.0..1.0)).collect();
    Tensor::from_data(TensorData::new(data, shape), device)
}

/// Output and input gradient of `sum(pool(relu(x)) * r)`, natively or by Burn.
fn run(pool: &MaxPool2d, shape: [usize; 4], native: bool, seed: u64) -> [Vec<f32>; 2] {
    let device = Device::flex().autodiff();
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let x = uniform(shape, &mut rng, &device).require_grad();
    // ReLU first: half the inputs become tied zeros, as in a real trunk.
    let h = relu(x.clone());
    let y = if native { max_pool2d(pool, h) } else { pool.forward(h) };
    let r = uniform(y.dims(), &mut rng, &device);
    let grads = (y.clone() * r).sum().backward();
    [values(y), values(x.grad(&grads).expect("input gradient"))]
}

#[test]
fn output_and_gradient_equal_burns_on_random_shapes() {
    let mut rng = ChaCha8Rng::seed_from_u64(77);
    for case in 0..30 {
        let (kernel, stride) = [(2, 2), (3, 2), (3, 3), (2, 1)][case % 4];
        let pool = MaxPool2dConfig::new([kernel, kernel]).with_strides([stride, stride]).init();
        let batch = if rng.random_bool(0.5) { 1 } else { 8 };
        let shape = [batch, rng.random_range(1..5), rng.random_range(kernel..20), rng.random_range(kernel..20)];
        let [y, dx] = run(&pool, shape, true, case as u64);
        let [y_ref, dx_ref] = run(&pool, shape, false, case as u64);
        // Same maxima, same routing: exactly equal, not merely close.
        assert_eq!(y, y_ref, "output, kernel {kernel} stride {stride}, shape {shape:?}");
        assert_eq!(dx, dx_ref, "input gradient, kernel {kernel} stride {stride}, shape {shape:?}");
    }
}

#[test]
fn a_nan_in_a_window_propagates_as_in_burn() {
    let device = Device::flex();
    let pool = MaxPool2dConfig::new([2, 2]).with_strides([2, 2]).init();
    let data = vec![1.0, f32::NAN, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0];
    let x = Tensor::<4>::from_data(TensorData::new(data, [1, 1, 2, 4]), &device);
    let ours = values(max_pool2d(&pool, x.clone()));
    let burn = values(pool.forward(x));
    assert!(ours[0].is_nan() && burn[0].is_nan());
    assert_eq!(ours[1], burn[1]);
}

#[test]
fn padded_pools_and_other_devices_are_right_too() {
    // The native pool serves unpadded pools on the flex device; the rest goes
    // through Burn's, which must still pool. Inputs whose maxima are known.
    #[allow(deprecated)]
    let device = Device::ndarray();
    let pool = MaxPool2dConfig::new([2, 2]).with_strides([2, 2]).init();
    // x[r][c] = 10 r + c on a 4 x 6 map: a 2 x 2 window's maximum is its
    // bottom-right value.
    let x = Tensor::<4>::from_data(
        TensorData::new((0..4).flat_map(|r| (0..6).map(move |c| (10 * r + c) as f32)).collect(), [1, 1, 4, 6]),
        &device,
    );
    assert_eq!(values(max_pool2d(&pool, x)), [11.0, 13.0, 15.0, 31.0, 33.0, 35.0]);

    let device = Device::flex();
    let pool = MaxPool2dConfig::new([3, 3])
        .with_strides([2, 2])
        .with_padding(burn::nn::PaddingConfig2d::Explicit(1, 1, 1, 1))
        .init();
    // x[r][c] = 6 r + c; the window of output (i, j) covers rows 2i-1..=2i+1
    // and columns 2j-1..=2j+1, so its maximum is x[2i+1][2j+1].
    let x = Tensor::<4>::from_data(TensorData::new((0..36).map(|v| v as f32).collect(), [1, 1, 6, 6]), &device);
    assert_eq!(values(max_pool2d(&pool, x)), [7.0, 9.0, 11.0, 19.0, 21.0, 23.0, 31.0, 33.0, 35.0]);
}
