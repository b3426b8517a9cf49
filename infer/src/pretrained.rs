//! Starting weights for a network's trunk from a file with torchvision's
//! parameter names: a PyTorch `.pth`/`.pt` state dict, a `.safetensors`
//! file (torchvision's or HED's VGG16), or a trunk written by `pretrain`.
//!
//! The convolutions must all be in the file with the right shapes. The two
//! hidden classifier layers are taken too when the file has them and their
//! shapes fit (torchvision's `fc6`/`fc7` for Faster R-CNN, `classifier.0/3`
//! for the grid networks); the last classifier layer (ImageNet's 1000
//! classes) is never used, since our heads replace it.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use burn::nn::Linear;
use burn::nn::conv::Conv2d;
use burn::prelude::*;
use burn::store::{ModuleStore, PytorchStore, SafetensorsStore};
use serde::{Deserialize, Serialize};

use crate::config::{Backbone, DetectorConfig};
use crate::network::Network;
use crate::trunk::{replace_value, widen_filters};

/// torchvision's `features.N` index of each convolution: ReLU and pooling
/// layers hold the indices in between and have no weights.
pub const VGG16_FEATURE_INDEX: [usize; 13] = [0, 2, 5, 7, 10, 12, 14, 17, 19, 21, 24, 26, 28];
pub const ALEXNET_FEATURE_INDEX: [usize; 5] = [0, 3, 6, 8, 10];
/// torchvision's `classifier.N` index of the two hidden fully connected
/// layers (dropout takes the others; VGG16's `classifier.6` and AlexNet's
/// `classifier.6` are the 1000-class layers our heads replace).
pub const VGG16_HIDDEN_INDEX: [usize; 2] = [0, 3];
pub const ALEXNET_HIDDEN_INDEX: [usize; 2] = [1, 4];

/// What the file's network expected as input, so that its first convolution
/// can be rewritten for our one-channel edge images in 0..1. A colour first
/// convolution becomes a grey one by summing over its input channels (a grey
/// image has R = G = B); the input normalisation folds into weight and bias.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "kebab-case")]
pub enum InputConvention {
    #[default]
    /// Decide from the file: HED's side outputs mean `hed`, a one-channel
    /// first convolution means `raw`, anything else `torchvision`.
    Auto,
    /// The input as it is (our own trunks; a plain channel sum for others).
    Raw,
    /// torchvision ImageNet models: RGB in 0..1, minus mean, over std.
    Torchvision,
    /// HED (Caffe VGG16): BGR in 0..255 minus the per-channel means.
    Hed,
}

const TORCHVISION_MEAN: [f32; 3] = [0.485, 0.456, 0.406];
const TORCHVISION_STD: [f32; 3] = [0.229, 0.224, 0.225];
/// HED's BGR means (its README).
const HED_MEAN_BGR: [f32; 3] = [104.006_99, 116.668_77, 122.678_92];

impl InputConvention {
    /// Per input channel: (scale, offset) with `channel = scale * x - offset`
    /// for our input x in 0..1.
    fn affine(self, channels: usize) -> Vec<(f32, f32)> {
        match self {
            Self::Torchvision if channels == 3 => {
                (0..3).map(|c| (1.0 / TORCHVISION_STD[c], TORCHVISION_MEAN[c] / TORCHVISION_STD[c])).collect()
            }
            Self::Hed if channels == 3 => (0..3).map(|c| (255.0, HED_MEAN_BGR[c])).collect(),
            _ => vec![(1.0, 0.0); channels],
        }
    }
}

#[derive(Debug, thiserror::Error)]
pub enum PretrainedError {
    #[error("{path}: {message}")]
    Read { path: PathBuf, message: String },
    #[error("{path}: these weights do not fit the {backbone} trunk at width {width}:\n{details}")]
    Mismatch { path: PathBuf, backbone: Backbone, width: f32, details: String },
}

/// What was loaded, for the run's log and the checkpoint's metadata.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ImportReport {
    pub source: String,
    pub convention: InputConvention,
    /// Our parameter <- the file's tensor.
    pub loaded: Vec<(String, String)>,
    /// The file's tensors nothing used (e.g. HED's side outputs).
    pub unused: Vec<String>,
    /// Hidden classifier layers left at their initialisation, with why.
    pub skipped: Vec<String>,
}

/// One tensor read from a file, as f32 values.
#[derive(Debug, Clone)]
pub struct FileTensor {
    pub shape: Vec<usize>,
    pub values: Vec<f32>,
}

/// Reads every tensor of a `.safetensors` or PyTorch file. A prefix common to
/// all names (`state_dict.`, `model.`, `module.`) is stripped, so that a
/// training checkpoint of a torchvision model reads like its state dict.
pub fn read_tensors(path: &Path) -> Result<BTreeMap<String, FileTensor>, PretrainedError> {
    let err = |message: String| PretrainedError::Read { path: path.to_path_buf(), message };
    if !path.is_file() {
        return Err(err(datasets::atomic::why_unreadable(path)));
    }
    let raw = if is_safetensors(path).map_err(|e| err(e.to_string()))? {
        let mut store = SafetensorsStore::from_file(path);
        collect(&mut store).map_err(|e| err(format!("not a readable safetensors file ({e})")))?
    } else {
        // torchvision's names are kept as they are (`features.0, features.2, ...`).
        let mut store = PytorchStore::from_file(path).map_indices_contiguous(false);
        collect(&mut store).map_err(|e| err(format!("not a readable PyTorch file ({e})")))?
    };
    if raw.is_empty() {
        return Err(err("holds no tensors".into()));
    }
    Ok(strip_common_prefix(raw))
}

fn collect<S: ModuleStore>(store: &mut S) -> Result<BTreeMap<String, FileTensor>, String> {
    let mut out = BTreeMap::new();
    for (name, tensor) in store.get_all_tensors().map_err(|e| e.to_string())? {
        if !tensor.dtype.is_float() {
            continue; // counters such as BatchNorm's num_batches_tracked
        }
        let shape = tensor.shape.as_slice().to_vec();
        let data = burn::store::bridge::to_data(tensor).map_err(|e| format!("{name}: {e}"))?;
        let values = data.try_into_vec_as::<f32>().map_err(|e| format!("{name}: {e:?}"))?;
        out.insert(name.clone(), FileTensor { shape, values });
    }
    Ok(out)
}

/// Safetensors starts with a little-endian u64 header length and a JSON
/// object; PyTorch files are ZIP archives or pickles.
fn is_safetensors(path: &Path) -> std::io::Result<bool> {
    use std::io::Read;
    let mut head = [0u8; 9];
    let n = std::fs::File::open(path)?.read(&mut head)?;
    Ok(n == 9 && head[8] == b'{')
}

fn strip_common_prefix(tensors: BTreeMap<String, FileTensor>) -> BTreeMap<String, FileTensor> {
    for prefix in ["state_dict.", "model.", "module.", "backbone."] {
        if tensors.keys().all(|k| k.starts_with(prefix)) {
            let stripped = tensors.into_iter().map(|(k, v)| (k[prefix.len()..].to_string(), v)).collect();
            return strip_common_prefix(stripped);
        }
    }
    tensors
}

/// The file's name for each of our trunk convolutions and hidden layers.
fn names(backbone: Backbone) -> (Vec<String>, Vec<String>) {
    let (features, hidden): (&[usize], &[usize]) = match backbone {
        Backbone::FasterRcnn | Backbone::Vgg16 => (&VGG16_FEATURE_INDEX, &VGG16_HIDDEN_INDEX),
        Backbone::Alexnet => (&ALEXNET_FEATURE_INDEX, &ALEXNET_HIDDEN_INDEX),
    };
    (
        features.iter().map(|i| format!("features.{i}")).collect(),
        hidden.iter().map(|i| format!("classifier.{i}")).collect(),
    )
}

/// Loads the trunk (and the hidden layers when they fit) of `network` from
/// `path`. Either every convolution loads or nothing changes. With `prune`,
/// a file with more channels than our width (HED's full-width VGG16 into a
/// width-0.25 trunk) gives each layer its strongest filters.
pub fn load_trunk(
    network: &mut Network,
    config: &DetectorConfig,
    path: &Path,
    convention: InputConvention,
    prune: bool,
) -> Result<ImportReport, PretrainedError> {
    let tensors = read_tensors(path)?;
    let (conv_names, hidden_names) = names(config.backbone);
    let convention = resolve_convention(&tensors, convention);
    // Check everything first, so that a bad file leaves the network untouched.
    let (convs, hidden) = network.trunk_layers_mut();
    let (planned, pruned) = plan_convs(&tensors, convs, &conv_names, convention, prune).map_err(|details| {
        PretrainedError::Mismatch { path: path.to_path_buf(), backbone: config.backbone, width: config.width, details }
    })?;

    let device = convs[0].weight.device();
    let mut loaded = Vec::new();
    for (i, weight, bias) in planned {
        let conv = &mut convs[i];
        let shape = conv.weight.dims();
        set_conv(conv, weight, bias, &device);
        loaded.push((format!("features.{i}"), conv_names[i].clone()));
        debug_assert_eq!(conv.weight.dims(), shape);
    }
    let mut skipped = Vec::new();
    for ((layer, name), ours) in hidden.into_iter().zip(&hidden_names).zip(["hidden.0", "hidden.1"]) {
        let (Some(w), Some(b)) = (tensors.get(&format!("{name}.weight")), tensors.get(&format!("{name}.bias"))) else {
            continue;
        };
        if pruned {
            skipped.push(format!("{name}: the trunk was pruned, so its inputs no longer match"));
            continue;
        }
        let [d_in, d_out] = layer.weight.dims();
        // PyTorch stores a linear layer's weight as [out, in]; Burn as [in, out].
        if w.shape != [d_out, d_in] || b.shape != [d_out] {
            skipped.push(format!("{name}.weight {:?} does not fit our {ours} [{d_out}, {d_in}]", w.shape));
            continue;
        }
        set_linear(layer, &w.values, &b.values, d_in, d_out, &device);
        loaded.push((ours.to_string(), name.clone()));
    }
    let used: std::collections::HashSet<&str> = loaded.iter().map(|(_, n)| n.as_str()).collect();
    let unused =
        tensors.keys().filter(|k| !used.contains(k.rsplit_once('.').map(|(l, _)| l).unwrap_or(k))).cloned().collect();
    Ok(ImportReport { source: path.display().to_string(), convention, loaded, unused, skipped })
}

/// The input convention `convention` names, or (for `Auto`) the one the
/// file's first layer says.
fn resolve_convention(tensors: &BTreeMap<String, FileTensor>, convention: InputConvention) -> InputConvention {
    match convention {
        InputConvention::Auto if tensors.contains_key("dsn1.weight") && tensors.contains_key("fuse.weight") => {
            InputConvention::Hed
        }
        InputConvention::Auto if tensors.get("features.0.weight").is_some_and(|t| t.shape.get(1) == Some(&1)) => {
            InputConvention::Raw
        }
        InputConvention::Auto => InputConvention::Torchvision,
        c => c,
    }
}

/// Per convolution to load: its index in our trunk, its weights and biases.
type ConvPlan = Vec<(usize, Vec<f32>, Vec<f32>)>;

/// The weights and biases each of our convolutions takes from `tensors`
/// (their filters chosen when `prune`), and whether any was pruned; or every
/// problem found, with what the file holds.
fn plan_convs(
    tensors: &BTreeMap<String, FileTensor>,
    convs: &[Conv2d],
    conv_names: &[String],
    convention: InputConvention,
    prune: bool,
) -> Result<(ConvPlan, bool), String> {
    let mut problems = String::new();
    let mut planned: Vec<(usize, Vec<f32>, Vec<f32>)> = Vec::new();
    // The previous layer's output channels that were kept, when pruned.
    let mut kept: Option<Vec<usize>> = None;
    let mut pruned = false;
    for (i, (conv, name)) in convs.iter().zip(conv_names).enumerate() {
        let ours = conv.weight.dims();
        let (w, b) = (tensors.get(&format!("{name}.weight")), tensors.get(&format!("{name}.bias")));
        let (Some(w), Some(b)) = (w, b) else {
            let _ = writeln!(problems, "  missing: {name}.weight / {name}.bias (our features.{i})");
            continue;
        };
        let first = i == 0;
        let inputs =
            if first { w.shape.get(1).copied() } else { kept.as_ref().map(Vec::len).or(w.shape.get(1).copied()) };
        // Any first layer folds to the edge channel (see `to_one_channel`).
        let in_ok = inputs == Some(ours[1]) || first;
        let out_ok = w.shape.first() == Some(&ours[0]) || (prune && w.shape.first() > Some(&ours[0]));
        if w.shape.len() != 4 || !out_ok || !in_ok || w.shape[2..] != ours[2..] || b.shape != w.shape[..1] {
            let _ = writeln!(
                problems,
                "  wrong shape: {name}.weight {:?} (ours {:?}), {name}.bias {:?}{}",
                w.shape,
                ours,
                b.shape,
                if w.shape.first() > Some(&ours[0]) && !prune {
                    "; --pretrained-prune keeps a subset of the channels"
                } else {
                    ""
                }
            );
            kept = None;
            continue;
        }
        let w = match (&kept, first) {
            (Some(k), false) => select_inputs(w, k),
            _ => w.clone(),
        };
        let (weight, bias) = if first && w.shape[1] != ours[1] {
            let (weight, bias) = to_one_channel(&w, &b.values, convention);
            // The edge channel; a grayscale channel beside it starts at zero weight.
            (widen_filters(&weight, w.shape[0], w.shape[2] * w.shape[3], ours[1]), bias)
        } else {
            (w.values, b.values.clone())
        };
        if w.shape[0] > ours[0] {
            let keep = strongest_filters(&weight, w.shape[0], ours[0]);
            let per = weight.len() / w.shape[0];
            let weight = keep.iter().flat_map(|&o| weight[o * per..(o + 1) * per].iter().copied()).collect();
            let bias = keep.iter().map(|&o| bias[o]).collect();
            planned.push((i, weight, bias));
            kept = Some(keep);
            pruned = true;
        } else {
            planned.push((i, weight, bias));
            kept = None;
        }
    }
    for extra in convs.len()..conv_names.len() {
        let _ = writeln!(problems, "  our trunk lacks features.{extra}");
    }
    if !problems.is_empty() {
        let keys: Vec<String> = tensors.iter().map(|(k, t)| format!("{k} {:?}", t.shape)).collect();
        let _ = write!(problems, "  the file holds: {}", keys.join(", "));
        return Err(problems);
    }
    Ok((planned, pruned))
}

/// Writes the trunk convolutions and the two hidden layers of `network` as
/// a `.safetensors` file in torchvision's naming and layouts, which
/// `train --pretrained` (ours or any other tool's loader) reads back.
/// `metadata` goes into the file's header.
pub fn save_trunk(
    network: &Network,
    backbone: Backbone,
    path: &Path,
    metadata: std::collections::HashMap<String, String>,
) -> Result<(), datasets::DataError> {
    let (conv_names, hidden_names) = names(backbone);
    let mut tensors: Vec<(String, Vec<usize>, Vec<f32>)> = Vec::new();
    for (conv, name) in network.trunk_convs().iter().zip(&conv_names) {
        tensors.push((format!("{name}.weight"), conv.weight.dims().to_vec(), crate::host(conv.weight.val())));
        if let Some(b) = &conv.bias {
            tensors.push((format!("{name}.bias"), b.dims().to_vec(), crate::host(b.val())));
        }
    }
    for (layer, name) in network.hidden_layers().into_iter().zip(&hidden_names) {
        let [d_in, d_out] = layer.weight.dims();
        tensors.push((format!("{name}.weight"), vec![d_out, d_in], crate::host(layer.weight.val().transpose())));
        if let Some(b) = &layer.bias {
            tensors.push((format!("{name}.bias"), vec![d_out], crate::host(b.val())));
        }
    }
    let bytes: Vec<(String, Vec<usize>, Vec<u8>)> =
        tensors.into_iter().map(|(n, s, v)| (n, s, v.iter().flat_map(|x| x.to_le_bytes()).collect())).collect();
    let views = bytes
        .iter()
        .map(|(n, s, b)| {
            safetensors::tensor::TensorView::new(safetensors::Dtype::F32, s.clone(), b).map(|v| (n.clone(), v))
        })
        .collect::<Result<Vec<_>, _>>()
        .map_err(|e| datasets::DataError::invalid(path, e.to_string()))?;
    let out =
        safetensors::serialize(views, Some(metadata)).map_err(|e| datasets::DataError::invalid(path, e.to_string()))?;
    datasets::atomic::write_bytes(path, &out)
}

/// The convolution's weights restricted to input channels `keep`.
fn select_inputs(w: &FileTensor, keep: &[usize]) -> FileTensor {
    let [out, cin, kh, kw] = [w.shape[0], w.shape[1], w.shape[2], w.shape[3]];
    let k = kh * kw;
    let mut values = Vec::with_capacity(out * keep.len() * k);
    for o in 0..out {
        for &c in keep {
            values.extend_from_slice(&w.values[(o * cin + c) * k..(o * cin + c + 1) * k]);
        }
    }
    FileTensor { shape: vec![out, keep.len(), kh, kw], values }
}

/// The `n` of `out` filters with the largest L1 norms, in their original
/// order (magnitude pruning, Li et al. 2017, "Pruning Filters for Efficient
/// ConvNets"): how a narrower trunk starts from a wider one's weights.
fn strongest_filters(weight: &[f32], out: usize, n: usize) -> Vec<usize> {
    let per = weight.len() / out;
    let norms: Vec<f32> = (0..out).map(|o| weight[o * per..(o + 1) * per].iter().map(|v| v.abs()).sum()).collect();
    let mut order: Vec<usize> = (0..out).collect();
    order.sort_by(|&a, &b| norms[b].total_cmp(&norms[a]).then(a.cmp(&b)));
    order.truncate(n);
    order.sort_unstable();
    order
}

/// The first convolution rewritten for a one-channel input in 0..1: with
/// input channel c = s_c * x - o_c, the response is
/// sum_c W_c * (s_c x - o_c) + b = (sum_c s_c W_c) * x + (b - sum_c o_c sum(W_c)).
/// (Exact except on the one-pixel border, where the zero padding differs.)
fn to_one_channel(w: &FileTensor, bias: &[f32], convention: InputConvention) -> (Vec<f32>, Vec<f32>) {
    let [out, cin, kh, kw] = [w.shape[0], w.shape[1], w.shape[2], w.shape[3]];
    let affine = convention.affine(cin);
    let k = kh * kw;
    let mut weight = vec![0.0f32; out * k];
    let mut new_bias = bias.to_vec();
    for o in 0..out {
        for (c, &(scale, offset)) in affine.iter().enumerate() {
            let src = &w.values[(o * cin + c) * k..(o * cin + c + 1) * k];
            for (dst, &v) in weight[o * k..(o + 1) * k].iter_mut().zip(src) {
                *dst += scale * v;
            }
            new_bias[o] -= offset * src.iter().sum::<f32>();
        }
    }
    (weight, new_bias)
}

fn set_conv(conv: &mut Conv2d, weight: Vec<f32>, bias: Vec<f32>, device: &Device) {
    let shape = conv.weight.dims();
    let w = Tensor::<4>::from_data(TensorData::new(weight, shape), device);
    conv.weight = conv.weight.clone().map(|old| replace_value(&old, w));
    if let Some(b) = conv.bias.take() {
        let n = bias.len();
        let t = Tensor::<1>::from_data(TensorData::new(bias, [n]), device);
        conv.bias = Some(b.map(|old| replace_value(&old, t)));
    }
}

fn set_linear(layer: &mut Linear, torch_weight: &[f32], bias: &[f32], d_in: usize, d_out: usize, device: &Device) {
    let w = Tensor::<2>::from_data(TensorData::new(torch_weight.to_vec(), [d_out, d_in]), device).transpose();
    layer.weight = layer.weight.clone().map(|old| replace_value(&old, w));
    if let Some(b) = layer.bias.take() {
        let t = Tensor::<1>::from_data(TensorData::new(bias.to_vec(), [d_out]), device);
        layer.bias = Some(b.map(|old| replace_value(&old, t)));
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::tensor::module::conv2d;
    use burn::tensor::ops::ConvOptions;

    /// A three-channel convolution on the normalised grey image equals the
    /// folded one-channel convolution on the image itself (away from the
    /// border, where the zero padding differs by design).
    fn folding_matches(convention: InputConvention) {
        let device = Device::flex();
        let (out, k, size) = (5, 3, 12);
        let w: Vec<f32> = (0..out * 3 * k * k).map(|i| ((i * 37 % 23) as f32 - 11.0) / 17.0).collect();
        let b: Vec<f32> = (0..out).map(|i| i as f32 * 0.1 - 0.2).collect();
        let x: Vec<f32> = (0..size * size).map(|i| (i * 5 % 11) as f32 / 10.0).collect();
        let affine = convention.affine(3);
        let mut rgb = Vec::with_capacity(3 * size * size);
        for &(scale, offset) in &affine {
            rgb.extend(x.iter().map(|v| scale * v - offset));
        }
        let options = ConvOptions::new([1, 1], [1, 1], [1, 1], 1);
        let full = conv2d(
            Tensor::<4>::from_data(TensorData::new(rgb, [1, 3, size, size]), &device),
            Tensor::from_data(TensorData::new(w.clone(), [out, 3, k, k]), &device),
            Some(Tensor::from_data(TensorData::new(b.clone(), [out]), &device)),
            options.clone(),
        );
        let file = FileTensor { shape: vec![out, 3, k, k], values: w };
        let (w1, b1) = to_one_channel(&file, &b, convention);
        let folded = conv2d(
            Tensor::<4>::from_data(TensorData::new(x, [1, 1, size, size]), &device),
            Tensor::from_data(TensorData::new(w1, [out, 1, k, k]), &device),
            Some(Tensor::from_data(TensorData::new(b1, [out]), &device)),
            options,
        );
        let inner = |t: Tensor<4>| crate::host(t.slice([0..1, 0..out, 1..size - 1, 1..size - 1]));
        let (a, f) = (inner(full), inner(folded));
        let scale = a.iter().fold(0.0f32, |m, v| m.max(v.abs()));
        for (p, q) in a.iter().zip(&f) {
            assert!((p - q).abs() <= 1e-5 * scale, "{convention:?}: {p} vs {q}");
        }
    }

    #[test]
    fn hed_means_fold_into_the_first_convolution() {
        folding_matches(InputConvention::Hed);
    }

    #[test]
    fn torchvision_normalisation_folds_into_the_first_convolution() {
        folding_matches(InputConvention::Torchvision);
    }

    #[test]
    fn a_plain_channel_sum_answers_a_grey_image_alike() {
        folding_matches(InputConvention::Raw);
    }
}
