//! The GEMM convolution agrees with Burn's own convolution: forward output
//! and the input, weight and bias gradients, on many seeded random shapes
//! (stride, padding per side, dilation, groups, batch 1 and 8, odd sizes).

use burn::module::Param;
use burn::nn::PaddingConfig2d;
use burn::nn::conv::{Conv2d, Conv2dConfig};
use burn::prelude::*;
use infer::kernels::conv_op::{gemm_conv2d, gemm_conv2d_relu};
use rand::rngs::ChaCha8Rng;
use rand::{RngExt, SeedableRng};

/// Relative tolerance: differences come only from the summation order.
const TOLERANCE: f32 = 1e-4;

#[derive(Debug, Clone)]
struct Case {
    batch: usize,
    channels: [usize; 2],
    groups: usize,
    kernel: [usize; 2],
    stride: [usize; 2],
    /// top, left, bottom, right
    padding: [usize; 4],
    dilation: [usize; 2],
    size: [usize; 2],
}

impl Case {
    fn random(rng: &mut ChaCha8Rng) -> Self {
        loop {
            let groups = [1, 1, 2, 3][rng.random_range(0..4)];
            let case = Case {
                batch: if rng.random_bool(0.5) { 1 } else { 8 },
                channels: [groups * rng.random_range(1..4), groups * rng.random_range(1..4)],
                groups,
                kernel: [[1, 2, 3, 5][rng.random_range(0..4)], [1, 3, 4][rng.random_range(0..3)]],
                stride: [rng.random_range(1..4), rng.random_range(1..3)],
                padding: [0; 4].map(|_| rng.random_range(0..3)),
                dilation: [rng.random_range(1..3), rng.random_range(1..3)],
                size: [rng.random_range(5..18), rng.random_range(5..18)],
            };
            // Keep cases with at least one output position per axis.
            let fits = (0..2).all(|i| {
                let padded = case.size[i] + case.padding[i] + case.padding[i + 2];
                padded > case.dilation[i] * (case.kernel[i] - 1)
            });
            if fits {
                return case;
            }
        }
    }

    fn conv(&self, device: &Device) -> Conv2d {
        let [t, l, b, r] = self.padding;
        Conv2dConfig::new(self.channels, self.kernel)
            .with_stride(self.stride)
            .with_padding(PaddingConfig2d::Explicit(t, l, b, r))
            .with_dilation(self.dilation)
            .with_groups(self.groups)
            .init(device)
    }
}

fn values<const D: usize>(t: Tensor<D>) -> Vec<f32> {
    t.into_data().try_into_vec_as::<f32>().unwrap()
}

fn assert_close(what: &str, case: &Case, ours: Vec<f32>, burn: Vec<f32>) {
    assert_eq!(ours.len(), burn.len(), "{what} length, {case:?}");
    let scale = burn.iter().fold(1.0f32, |m, v| m.max(v.abs()));
    let worst = ours.iter().zip(&burn).map(|(a, b)| (a - b).abs()).fold(0.0f32, f32::max);
    assert!(worst <= TOLERANCE * scale, "{what}: largest difference {worst} (scale {scale}), {case:?}");
}

/// A tensor of uniform values in [-1, 1) from `rng` (the device's own
/// generator is shared by tests running in parallel, so it is not used).
fn uniform<const D: usize>(shape: [usize; D], rng: &mut ChaCha8Rng, device: &Device) -> Tensor<D> {
    let data: Vec<f32> = (0..shape.iter().product()).map(|_| rng.random_range(-1.0..1.0)).collect();
    Tensor::from_data(TensorData::new(data, shape), device)
}

/// Output, input gradient, weight gradient, bias gradient of
/// `sum(conv(x) * r)`, or of `sum(relu(conv(x)) * r)`.
fn run(case: &Case, gemm: bool, seed: u64) -> [Vec<f32>; 4] {
    run_with(case, gemm, false, seed)
}

fn run_with(case: &Case, gemm: bool, relu: bool, seed: u64) -> [Vec<f32>; 4] {
    let device = Device::flex().autodiff();
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut conv = case.conv(&device);
    conv.weight = Param::from_tensor(uniform(conv.weight.val().dims(), &mut rng, &device));
    conv.bias = Some(Param::from_tensor(uniform([case.channels[1]], &mut rng, &device)));
    let x = uniform([case.batch, case.channels[0], case.size[0], case.size[1]], &mut rng, &device).require_grad();
    let y = match (gemm, relu) {
        (true, false) => gemm_conv2d(&conv, x.clone()),
        (true, true) => gemm_conv2d_relu(&conv, x.clone()),
        (false, false) => conv.forward(x.clone()),
        (false, true) => burn::tensor::activation::relu(conv.forward(x.clone())),
    };
    let r = uniform(y.dims(), &mut rng, &device);
    let grads = (y.clone() * r).sum().backward();
    [
        values(y),
        values(x.grad(&grads).expect("input gradient")),
        values(conv.weight.grad(&grads).expect("weight gradient")),
        values(conv.bias.as_ref().unwrap().grad(&grads).expect("bias gradient")),
    ]
}

#[test]
fn forward_and_all_gradients_match_burns_on_random_shapes() {
    let mut rng = ChaCha8Rng::seed_from_u64(2026);
    let cases: Vec<Case> = (0..40).map(|_| Case::random(&mut rng)).collect();
    // The generator covers what it should, so the test cannot pass by
    // drawing only easy cases.
    assert!(cases.iter().any(|c| c.groups > 1));
    assert!(cases.iter().any(|c| c.stride != [1, 1]) && cases.iter().any(|c| c.stride == [1, 1] && c.groups == 1));
    assert!(cases.iter().any(|c| c.dilation != [1, 1]));
    assert!(cases.iter().any(|c| c.batch == 1) && cases.iter().any(|c| c.batch == 8));
    for (i, case) in cases.iter().enumerate() {
        let seed = 100 + i as u64;
        let [y, dx, dw, db] = run(case, true, seed);
        let [y_ref, dx_ref, dw_ref, db_ref] = run(case, false, seed);
        assert_close("output", case, y, y_ref);
        assert_close("input gradient", case, dx, dx_ref);
        assert_close("weight gradient", case, dw, dw_ref);
        assert_close("bias gradient", case, db, db_ref);
    }
}

#[test]
fn the_fused_relu_convolution_matches_burns_conv_then_relu() {
    let mut rng = ChaCha8Rng::seed_from_u64(2027);
    let mut cut = 0;
    for i in 0..16 {
        let case = Case::random(&mut rng);
        let seed = 300 + i as u64;
        let [y, dx, dw, db] = run_with(&case, true, true, seed);
        let [y_ref, dx_ref, dw_ref, db_ref] = run_with(&case, false, true, seed);
        // Inputs and weights in [-1, 1): about half the outputs are cut.
        let zeros = y_ref.iter().filter(|&&v| v == 0.0).count();
        cut += usize::from(zeros > 0 && zeros < y_ref.len());
        assert_close("output", &case, y, y_ref);
        assert_close("input gradient", &case, dx, dx_ref);
        assert_close("weight gradient", &case, dw, dw_ref);
        assert_close("bias gradient", &case, db, db_ref);
    }
    // The ReLU both passes and cuts in most cases, so its mask is tested.
    assert!(cut >= 12, "only {cut} of 16 cases had outputs on both sides of zero");
}

#[test]
fn the_reference_layer_matches_at_full_size() {
    // The benchmark's layer (64->64 3x3, padding 1), batch 2 to stay quick.
    let case = Case {
        batch: 2,
        channels: [64, 64],
        groups: 1,
        kernel: [3, 3],
        stride: [1, 1],
        padding: [1; 4],
        dilation: [1, 1],
        size: [56, 56],
    };
    let [y, dx, dw, db] = run(&case, true, 9);
    let [y_ref, dx_ref, dw_ref, db_ref] = run(&case, false, 9);
    assert_close("output", &case, y, y_ref);
    assert_close("input gradient", &case, dx, dx_ref);
    assert_close("weight gradient", &case, dw, dw_ref);
    assert_close("bias gradient", &case, db, db_ref);
}

/// A direct convolution (stride 1, no padding, one group), written out as
/// the definition: the reference for the paths that do not use our kernel.
fn direct_conv(x: &[f32], [n, c, h, w]: [usize; 4], weight: &[f32], [o, kh, kw]: [usize; 3], bias: &[f32]) -> Vec<f32> {
    let (oh, ow) = (h - kh + 1, w - kw + 1);
    let mut out = vec![0.0; n * o * oh * ow];
    for b in 0..n {
        for k in 0..o {
            for i in 0..oh {
                for j in 0..ow {
                    let mut sum = bias.get(k).copied().unwrap_or(0.0);
                    for ch in 0..c {
                        for u in 0..kh {
                            for v in 0..kw {
                                sum += weight[((k * c + ch) * kh + u) * kw + v]
                                    * x[((b * c + ch) * h + i + u) * w + j + v];
                            }
                        }
                    }
                    out[((b * o + k) * oh + i) * ow + j] = sum;
                }
            }
        }
    }
    out
}

#[test]
fn other_devices_and_bias_free_convolutions_are_right_too() {
    // The kernel serves the flex device with a bias; the rest goes through
    // Burn's convolution, which must still compute the convolution.
    #[allow(deprecated)]
    let ndarray = Device::ndarray();
    let mut rng = ChaCha8Rng::seed_from_u64(21);
    for (device, with_bias) in [(ndarray, true), (Device::flex(), false)] {
        let conv = Conv2dConfig::new([2, 3], [3, 3]).with_bias(with_bias).init(&device);
        let shape = [2, 2, 6, 7];
        let data: Vec<f32> = (0..shape.iter().product()).map(|_| rng.random_range(-1.0..1.0)).collect();
        let x = Tensor::<4>::from_data(TensorData::new(data.clone(), shape), &device);
        let weight = values(conv.weight.val());
        let bias = conv.bias.as_ref().map(|b| values(b.val())).unwrap_or_default();
        assert_eq!(bias.len(), if with_bias { 3 } else { 0 });
        let expected = direct_conv(&data, shape, &weight, [3, 3, 3], &bias);
        let ours = values(gemm_conv2d(&conv, x));
        assert_eq!(ours.len(), expected.len());
        for (k, (a, b)) in ours.iter().zip(&expected).enumerate() {
            assert!((a - b).abs() <= 1e-5 * (1.0 + b.abs()), "bias {with_bias}: output {k} is {a}, expected {b}");
        }
    }
}
