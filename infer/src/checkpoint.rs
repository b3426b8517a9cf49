//! A checkpoint is a folder: `config.json` (the resolved detector config),
//! `model.bpk` (burnpack weights) and `meta.json` (data set, epochs, metrics).
//! Inference rebuilds the network from the config and loads the weights,
//! with no training code involved. The names are defined here once.

use std::path::{Path, PathBuf};

use burn::prelude::*;
use burn::store::ModuleRecord;
use burn::store::burn_pack::{Reader, Writer};
use datasets::InvalidSetting;
use serde::{Deserialize, Serialize};

use crate::config::{Backbone, DetectorConfig};
use crate::metrics::EvalMetrics;
use crate::network::Network;

pub const CONFIG_FILE: &str = "config.json";
/// Burnpack appends `.bpk` to this stem.
pub const WEIGHTS_STEM: &str = "model";
pub const WEIGHTS_FILE: &str = "model.bpk";
pub const META_FILE: &str = "meta.json";
pub const FORMAT_VERSION: u32 = 1;

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CheckpointMeta {
    pub format_version: u32,
    pub backbone: Backbone,
    pub width: f32,
    /// The training data, as given to `train --data`.
    pub dataset: String,
    pub epochs: usize,
    pub metrics: Option<EvalMetrics>,
    /// Where the trunk's starting weights came from, if not from scratch.
    pub pretrained: Option<String>,
    pub train_seconds: f64,
    pub parameters: usize,
}

#[derive(Debug, thiserror::Error)]
pub enum CheckpointError {
    #[error(transparent)]
    Data(#[from] datasets::DataError),
    #[error("{path}: {message}")]
    Invalid { path: PathBuf, message: String },
    #[error("{path}: {source}")]
    Setting {
        path: PathBuf,
        #[source]
        source: InvalidSetting,
    },
    #[error("{path}: the weights do not fit the network of {config}")]
    Weights {
        path: PathBuf,
        config: PathBuf,
        #[source]
        source: burn::store::RecordError,
    },
    #[error("{path}: cannot write the weights")]
    Save {
        path: PathBuf,
        #[source]
        source: burn::store::RecordError,
    },
}

/// Writes a checkpoint folder atomically: into a temporary sibling folder,
/// then renamed over `dir`.
pub fn save(
    dir: &Path,
    config: &DetectorConfig,
    network: &Network,
    meta: &CheckpointMeta,
) -> Result<(), CheckpointError> {
    datasets::atomic::write_dir(dir, |tmp| {
        datasets::atomic::write_json(&tmp.join(CONFIG_FILE), config)?;
        datasets::atomic::write_json(&tmp.join(META_FILE), meta)?;
        save_weights(network, &tmp.join(WEIGHTS_STEM))
    })
}

/// Writes `stem.bpk`.
pub fn save_weights(network: &Network, stem: &Path) -> Result<(), CheckpointError> {
    let result = match network {
        Network::FasterRcnn(m) => m.clone().save_file(stem),
        Network::Grid(m) => m.clone().save_file(stem),
    };
    result.map_err(|source| CheckpointError::Save { path: stem.with_extension("bpk"), source })
}

pub fn read_config(dir: &Path) -> Result<DetectorConfig, CheckpointError> {
    let path = dir.join(CONFIG_FILE);
    parse_config(&path, &datasets::atomic::read_text(&path)?)
}

/// A validated detector configuration from the text of `path`.
pub fn parse_config(path: &Path, text: &str) -> Result<DetectorConfig, CheckpointError> {
    let config: DetectorConfig = serde_json::from_str(text).map_err(|e| datasets::DataError::json(path, e))?;
    config.validate().map_err(|source| CheckpointError::Setting { path: path.to_path_buf(), source })?;
    Ok(config)
}

pub fn read_meta(dir: &Path) -> Result<CheckpointMeta, CheckpointError> {
    let path = dir.join(META_FILE);
    let text = datasets::atomic::read_text(&path)?;
    Ok(serde_json::from_str(&text).map_err(|e| datasets::DataError::json(&path, e))?)
}

/// Loads a checkpoint folder onto `device`.
pub fn load(dir: &Path, device: &Device) -> Result<(DetectorConfig, Network, CheckpointMeta), CheckpointError> {
    if !dir.is_dir() {
        return Err(CheckpointError::Invalid { path: dir.to_path_buf(), message: "no such checkpoint folder".into() });
    }
    let config = read_config(dir)?;
    let meta = read_meta(dir)?;
    let network = load_weights(dir, &config, device)?;
    Ok((config, network, meta))
}

/// How weights files written before the networks had sub-modules name their
/// tensors, and where those tensors live now: old prefix, new prefix. A key
/// takes the first rule whose prefix it starts with; today's keys match none.
const LEGACY_KEYS: [(&str, &str); 11] = [
    // Faster R-CNN: the trunk, the RPN head and the box head were flat fields.
    ("features.", "trunk.features."),
    ("rpn_conv.", "rpn.conv."),
    ("rpn_cls.", "rpn.cls."),
    ("rpn_bbox.", "rpn.bbox."),
    ("fc6.", "box_head.fc6."),
    ("fc7.", "box_head.fc7."),
    ("cls_score.", "box_head.cls_score."),
    ("bbox_pred.", "box_head.bbox_pred."),
    // The grid networks held both heads' layers, one list always empty.
    ("classifier.", "head.Fc.classifier."),
    ("head_convs.0.", "head.Conv.hidden."),
    ("head_convs.1.", "head.Conv.cells."),
];

/// A tensor name of today's networks for a name of any version's file.
fn current_key(name: &str) -> String {
    LEGACY_KEYS
        .iter()
        .find_map(|(old, new)| name.strip_prefix(old).map(|rest| format!("{new}{rest}")))
        .unwrap_or_else(|| name.to_string())
}

/// The weights record of `path`, with legacy tensor names renamed (the
/// parameter ids and data are kept as they are), from one read of the file.
fn read_record(path: &Path) -> Result<ModuleRecord, burn::store::RecordError> {
    let mut tensors = Reader::from_file(path)?.into_tensors()?;
    for tensor in &mut tensors {
        tensor.name = current_key(&tensor.name);
    }
    ModuleRecord::from_bytes(Writer::new(tensors).into_bytes()?)
}

/// Builds the network of `config` and loads `dir/model.bpk` into it.
pub fn load_weights(dir: &Path, config: &DetectorConfig, device: &Device) -> Result<Network, CheckpointError> {
    let path = dir.join(WEIGHTS_FILE);
    if !path.is_file() {
        return Err(CheckpointError::Invalid { path, message: "weights file is missing".into() });
    }
    let weights_error = |source: burn::store::RecordError| CheckpointError::Weights {
        path: path.clone(),
        config: dir.join(CONFIG_FILE),
        source,
    };
    let record = || read_record(&path).map_err(weights_error);
    let network = match Network::new(config, device) {
        Network::FasterRcnn(m) => Network::FasterRcnn(m.try_load_record(record()?).map_err(weights_error)?),
        Network::Grid(m) => Network::Grid(m.try_load_record(record()?).map_err(weights_error)?),
    };
    // NaN weights would give NaN boxes and no detections without a word.
    if let Some((param, count)) = network.first_non_finite() {
        return Err(CheckpointError::Invalid {
            path,
            message: format!("{count} weights of `{param}` are NaN or infinite (a diverged or corrupt training run)"),
        });
    }
    Ok(network)
}

/// Loads the whole network of the checkpoint in `dir` (trunk, RPN and
/// heads) as the starting point of a new run with `config`: fine-tuning a
/// detector trained elsewhere. The two must describe the same layers; the
/// post-processing and sampling settings may differ, and a detector of the
/// edges alone may start one that also sees the grayscale image (the new
/// input channel's weights start at zero).
pub fn load_for_fine_tuning(dir: &Path, config: &DetectorConfig, device: &Device) -> Result<Network, CheckpointError> {
    let theirs = read_config(dir)?;
    let same_layers = |c: &DetectorConfig| {
        (
            c.backbone,
            c.width.to_bits(),
            c.hidden,
            c.num_classes,
            c.anchors.per_location(),
            c.roi.pool_size,
            c.grid_cells,
            c.grid_head,
        )
    };
    if same_layers(&theirs) != same_layers(config) {
        return Err(CheckpointError::Invalid {
            path: dir.join(CONFIG_FILE),
            message: format!(
                "a {} of width {} (hidden {}) cannot start a {} of width {} (hidden {}): the layers differ",
                theirs.backbone, theirs.width, theirs.hidden, config.backbone, config.width, config.hidden
            ),
        });
    }
    if theirs.in_channels > config.in_channels {
        return Err(CheckpointError::Invalid {
            path: dir.join(CONFIG_FILE),
            message: format!(
                "a detector of {} input channels cannot start one of {}: it would lose inputs it was trained on",
                theirs.in_channels, config.in_channels
            ),
        });
    }
    let mut as_saved = config.clone();
    as_saved.in_channels = theirs.in_channels;
    as_saved.preprocess.gray_channel = theirs.preprocess.gray_channel;
    let mut network = load_weights(dir, &as_saved, device)?;
    network.widen_input(config.in_channels);
    Ok(network)
}

#[cfg(test)]
mod tests {
    use std::collections::BTreeMap;

    use super::*;
    use crate::config::GridHead;

    /// Tensor name to (shape, bytes) of a weights file.
    fn tensors(path: &Path) -> BTreeMap<String, (Vec<usize>, Vec<u8>)> {
        Reader::from_file(path)
            .unwrap()
            .into_tensors()
            .unwrap()
            .into_iter()
            .map(|t| (t.name.clone(), (t.shape.to_vec(), t.to_bytes().unwrap().to_vec())))
            .collect()
    }

    /// The name a file of before the sub-modules gave `name`.
    fn legacy_key(name: &str) -> String {
        LEGACY_KEYS
            .iter()
            .find_map(|(old, new)| name.strip_prefix(new).map(|rest| format!("{old}{rest}")))
            .expect("every tensor had a legacy name")
    }

    #[test]
    fn files_use_todays_names_and_legacy_files_load_the_same_weights() {
        let device = Device::flex();
        let mut fc = DetectorConfig::new(Backbone::Alexnet, 0.0625);
        fc.grid_head = GridHead::Fc;
        let cases = [
            (
                DetectorConfig::new(Backbone::FasterRcnn, 0.0625),
                ["trunk.features.12.bias", "rpn.cls.weight", "box_head.bbox_pred.bias"],
            ),
            (
                DetectorConfig::new(Backbone::Vgg16, 0.0625),
                ["trunk.features.0.weight", "head.Conv.hidden.weight", "head.Conv.cells.bias"],
            ),
            (fc, ["trunk.features.4.weight", "head.Fc.classifier.0.weight", "head.Fc.classifier.2.bias"]),
        ];
        for (config, expected) in cases {
            let dir = tempfile::tempdir().unwrap();
            let network = Network::new(&config, &device);
            save_weights(&network, &dir.path().join(WEIGHTS_STEM)).unwrap();
            let today = tensors(&dir.path().join(WEIGHTS_FILE));
            for name in expected {
                assert!(today.contains_key(name), "{}: no {name} in {:?}", config.backbone, today.keys());
            }
            assert!(today.keys().all(|k| current_key(k) == *k), "{:?}", today.keys());

            // The same weights under the old names load into the same network.
            let old = dir.path().join("old");
            std::fs::create_dir(&old).unwrap();
            let mut renamed = Reader::from_file(dir.path().join(WEIGHTS_FILE)).unwrap().into_tensors().unwrap();
            for tensor in &mut renamed {
                tensor.name = legacy_key(&tensor.name);
            }
            Writer::new(renamed).write_to_file(old.join(WEIGHTS_FILE)).unwrap();
            let loaded = load_weights(&old, &config, &device).unwrap();
            save_weights(&loaded, &old.join("again")).unwrap();
            assert_eq!(tensors(&old.join("again.bpk")), today, "{}", config.backbone);
        }
    }
}
