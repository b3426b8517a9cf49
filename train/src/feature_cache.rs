//! Outputs of the frozen trunk layers, computed once. Frozen layers never
//! change and the only augmentation is a left-right flip, so each image has
//! at most two possible outputs there: computing them before the first epoch
//! takes the frozen layers' forward pass (and any backward) out of every
//! training step.

use std::collections::HashMap;

use burn::prelude::*;
use indicatif::{ProgressBar, ProgressStyle};

use crate::step::{Batch, batch_boxes, batch_ignore, batch_inputs, make_batch};
use infer::labeled::LabeledImage;
use infer::network::Network;

/// Above this, the cache would crowd the machine's memory; training then
/// runs the frozen layers on every step (still without their backward).
pub const MAX_CACHE_BYTES: usize = 6 << 30;

pub struct FeatureCache {
    /// The trunk convolution the cached features enter.
    pub start: usize,
    /// `[C, H, W]` of one entry.
    shape: [usize; 3],
    /// (image index, flipped) -> features.
    entries: HashMap<(usize, bool), Vec<f32>>,
}

impl FeatureCache {
    /// Bytes a cache of `entries` entries would take, from one probe image.
    pub fn estimate_bytes(
        network: &Network,
        start: usize,
        input: [usize; 3],
        entries: usize,
        device: &Device,
    ) -> usize {
        let [c, h, w] = input;
        let probe = Tensor::<4>::zeros([1, c, h, w], device);
        network.valid().trunk_until(probe, start).dims().iter().product::<usize>() * 4 * entries
    }

    /// Runs the first `start` convolutions of `network` on every image (and
    /// on its mirror image when `flips`), on the non-autodiff `device`.
    pub fn build(
        network: &Network,
        images: &[&LabeledImage],
        flips: bool,
        start: usize,
        batch_size: usize,
        device: &Device,
        show_progress: bool,
    ) -> Self {
        let model = network.valid();
        let keys: Vec<(usize, bool)> =
            (0..images.len()).flat_map(|i| [(i, false), (i, true)]).filter(|&(_, f)| flips || !f).collect();
        let bar = if show_progress { ProgressBar::new(keys.len() as u64) } else { ProgressBar::hidden() };
        bar.set_style(
            ProgressStyle::with_template("caching frozen features [{bar:30}] {pos}/{len} ({eta})")
                .expect("template")
                .progress_chars("=> "),
        );
        let mut entries = HashMap::with_capacity(keys.len());
        let mut shape = [0; 3];
        for chunk in keys.chunks(batch_size) {
            let ims: Vec<&LabeledImage> = chunk.iter().map(|&(i, _)| images[i]).collect();
            let flipped: Vec<bool> = chunk.iter().map(|&(_, f)| f).collect();
            let out = model.trunk_until(batch_inputs(&ims, &flipped, device), start);
            let [b, c, h, w] = out.dims();
            shape = [c, h, w];
            let values = infer::host(out);
            let n = c * h * w;
            for (k, key) in chunk.iter().enumerate().take(b) {
                entries.insert(*key, values[k * n..(k + 1) * n].to_vec());
            }
            bar.inc(chunk.len() as u64);
        }
        bar.finish_and_clear();
        Self { start, shape, entries }
    }

    /// The training batch of images `ids` of the set the cache was built
    /// from: their cached features when there is a cache, else the images.
    pub fn batch_of(
        cache: Option<&Self>,
        images: &[&LabeledImage],
        ids: &[usize],
        flips: &[bool],
        size: u32,
        device: &Device,
    ) -> Batch {
        let chosen: Vec<&LabeledImage> = ids.iter().map(|&i| images[i]).collect();
        match cache {
            Some(cache) => Batch {
                inputs: cache.features(ids, flips, device),
                start: cache.start,
                boxes: batch_boxes(&chosen, flips, size),
                ignore: batch_ignore(&chosen, flips, size),
            },
            None => make_batch(&chosen, flips, size, device),
        }
    }

    /// The cached features of images `ids` (flipped where `flips` says) as
    /// one batch on `device`.
    pub fn features(&self, ids: &[usize], flips: &[bool], device: &Device) -> Tensor<4> {
        let [c, h, w] = self.shape;
        let mut data = Vec::with_capacity(ids.len() * c * h * w);
        for (&i, &f) in ids.iter().zip(flips) {
            data.extend_from_slice(&self.entries[&(i, f)]);
        }
        Tensor::from_data(TensorData::new(data, [ids.len(), c, h, w]), device)
    }
}
