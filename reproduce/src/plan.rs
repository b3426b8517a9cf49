//! What the experiment runs: the data, the trunks to transfer from, the
//! three fine-tuning runs and the localization settings. `Plan::full` is
//! the paper's experiment on the default data; `Plan::quick` a smoke version
//! of every stage that takes a few minutes.

use std::path::PathBuf;

use datasets::simulator::corpus::CorpusConfig;
use datasets::simulator::generate::DatagenConfig;
use infer::backend::ComputeBackend;
use infer::config::{Backbone, DEFAULT_WIDTH};
use localize::config::LocalizeConfig;
use serde::{Deserialize, Serialize};
use train::pretrain::PretrainConfig;

/// The paper's three networks, the proposed one first (the reference of
/// the loss reductions).
pub const BACKBONES: [Backbone; 3] = [Backbone::FasterRcnn, Backbone::Vgg16, Backbone::Alexnet];

/// The pretrained networks a plan needs, each before those that start
/// from it: vgg16 and alexnet (trunks), then faster-rcnn (a whole
/// detector, whose own pretraining starts from the vgg16 trunk).
pub fn pretrained_families(runs: &[FineTune]) -> Vec<Backbone> {
    let planned = |b: Backbone| runs.iter().any(|r| r.backbone == b);
    [Backbone::Vgg16, Backbone::Alexnet, Backbone::FasterRcnn]
        .into_iter()
        .filter(|&b| planned(b) || (b == Backbone::Vgg16 && planned(Backbone::FasterRcnn)))
        .collect()
}

/// Whether a backbone's fine-tuning starts from the whole pretrained
/// network (trunk, RPN and heads) rather than from its trunk alone. The
/// box head and the RPN are most of what faster-rcnn learns; 200 images
/// are too few to learn them from scratch without overfitting.
pub fn starts_from_whole_network(backbone: Backbone) -> bool {
    backbone == Backbone::FasterRcnn
}

/// Where the trunks come from.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub enum TrunkSource {
    /// The pretrained networks shipped in `DIR/pretrained/<backbone>/`,
    /// made by `pretrain` with the default corpus (their `meta.json` says
    /// how): `trunk.safetensors`, and for faster-rcnn `detector/`.
    Shipped(PathBuf),
    /// Pretrain each network here, on a generated corpus.
    Pretrain { corpus: CorpusConfig, epochs: usize },
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FineTune {
    pub backbone: Backbone,
    pub epochs: usize,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Plan {
    pub quick: bool,
    /// How the data is generated, unless `recorded` is given.
    pub datagen: DatagenConfig,
    /// A user's own data instead of the generated: `DIR/detection` (COCO
    /// `train.json`, `test.json` and their images) and `DIR/sequence` (the
    /// recorded-sequence layout of the design).
    #[serde(default)]
    pub recorded: Option<PathBuf>,
    pub width: f32,
    pub trunks: TrunkSource,
    pub runs: Vec<FineTune>,
    pub backend: ComputeBackend,
    pub localize: LocalizeConfig,
}

impl Plan {
    /// The experiment on the default data: the shipped trunks fine-tuned on
    /// the 200 training images, epochs chosen so that the whole run fits 45
    /// minutes on two cores.
    pub fn full(checkpoints: PathBuf) -> Self {
        Self {
            quick: false,
            datagen: DatagenConfig::default(),
            recorded: None,
            width: DEFAULT_WIDTH,
            trunks: TrunkSource::Shipped(checkpoints),
            runs: vec![
                FineTune { backbone: Backbone::FasterRcnn, epochs: 16 },
                FineTune { backbone: Backbone::Vgg16, epochs: 16 },
                FineTune { backbone: Backbone::Alexnet, epochs: 40 },
            ],
            backend: ComputeBackend::default(),
            localize: LocalizeConfig::paper_estimator(),
        }
    }

    /// Every stage on little data at a small width: pretraining on a
    /// two-world corpus, two epochs of fine-tuning, a sequence at ten times
    /// the paper's speed (one pass over the route in 57 frames).
    pub fn quick() -> Self {
        let mut datagen = DatagenConfig::default();
        datagen.detection.images = 24;
        datagen.detection.train = 16;
        datagen.sequence.speed_mps = 0.5;
        Self {
            quick: true,
            datagen,
            recorded: None,
            width: 0.125,
            trunks: TrunkSource::Pretrain {
                corpus: CorpusConfig { worlds: 2, images_per_world: 8, test_every: 4, ..CorpusConfig::default() },
                epochs: 1,
            },
            runs: BACKBONES.iter().map(|&backbone| FineTune { backbone, epochs: 2 }).collect(),
            backend: ComputeBackend::default(),
            localize: LocalizeConfig::paper_estimator(),
        }
    }

    /// Settings of the pretraining of one trunk family.
    pub fn pretrain_config(&self, family: Backbone) -> Option<PretrainConfig> {
        match &self.trunks {
            TrunkSource::Shipped(_) => None,
            TrunkSource::Pretrain { corpus, epochs } => {
                let mut c = PretrainConfig::new(family, self.width);
                c.corpus = corpus.clone();
                c.epochs = *epochs;
                Some(c)
            }
        }
    }
}
