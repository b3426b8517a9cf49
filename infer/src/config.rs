//! The detector's configuration: which network, how wide, and the settings of
//! its heads. It is saved with every checkpoint, and inference rebuilds the
//! network from it.

use datasets::InvalidSetting;
use datasets::preprocess::PreprocessConfig;
use serde::{Deserialize, Serialize};

use crate::anchors::AnchorConfig;
use crate::faster_rcnn::FasterRcnnConfig;
use crate::grid_net::GridNetConfig;
use crate::trunk::{Architecture, TrunkConfig};

/// The three networks of the paper. Variants are data: one enum, not copies.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "kebab-case")]
pub enum Backbone {
    /// Two-stage detector on a VGG16 trunk (stride 16): RPN, RoIAlign, box head.
    FasterRcnn,
    /// VGG16 whose last classifier layer is a grid head.
    Vgg16,
    /// AlexNet whose last classifier layer is a grid head.
    Alexnet,
}

impl Backbone {
    pub fn name(self) -> &'static str {
        match self {
            Self::FasterRcnn => "faster-rcnn",
            Self::Vgg16 => "vgg16",
            Self::Alexnet => "alexnet",
        }
    }
}

impl Backbone {
    /// Convolutions in the trunk (torchvision's `features`).
    pub fn trunk_convs(self) -> usize {
        match self {
            Self::FasterRcnn | Self::Vgg16 => crate::trunk::VGG16_CHANNELS.len(),
            Self::Alexnet => crate::trunk::ALEXNET_CHANNELS.len(),
        }
    }
}

impl std::fmt::Display for Backbone {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

pub use crate::grid_net::GridHead;

/// Default channel multiplier: a quarter of torchvision's widths trains at a
/// few images per second on two CPU cores.
pub const DEFAULT_WIDTH: f32 = 0.25;

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DetectorConfig {
    pub backbone: Backbone,
    /// Channel multiplier of the convolutions; 1.0 is torchvision's network.
    pub width: f32,
    /// Width of the fully connected layers (torchvision: 4096). Defaults to
    /// 4096 * width^2, which keeps the heads' share of the compute as the
    /// convolutions shrink.
    pub hidden: usize,
    /// Channels of the network input: the preprocessing's (`preprocess.channels()`).
    pub in_channels: usize,
    /// Foreground classes (corners are one class).
    pub num_classes: usize,
    /// How images become network inputs (size, Canny thresholds).
    pub preprocess: PreprocessConfig,
    pub anchors: AnchorConfig,
    pub rpn: RpnConfig,
    pub roi: RoiConfig,
    /// Cells per side of the grid head (VGG16, AlexNet).
    pub grid_cells: usize,
    /// The grid networks' head; configs written before it existed had `fc`.
    #[serde(default = "fc_head")]
    pub grid_head: GridHead,
    pub detection: DetectionConfig,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RpnConfig {
    pub pre_nms_top_n_train: usize,
    pub post_nms_top_n_train: usize,
    pub pre_nms_top_n_test: usize,
    pub post_nms_top_n_test: usize,
    pub nms_iou: f32,
    /// Anchors with IoU >= this are positives.
    pub fg_iou: f32,
    /// Anchors with IoU < this are negatives.
    pub bg_iou: f32,
    pub batch_size_per_image: usize,
    pub positive_fraction: f32,
    pub min_size: f32,
}

impl RpnConfig {
    /// Proposal settings while training (`true`) or testing.
    pub fn proposals(&self, training: bool) -> crate::faster_rcnn::ProposalSettings {
        let (pre_nms_top_n, post_nms_top_n) = if training {
            (self.pre_nms_top_n_train, self.post_nms_top_n_train)
        } else {
            (self.pre_nms_top_n_test, self.post_nms_top_n_test)
        };
        crate::faster_rcnn::ProposalSettings {
            pre_nms_top_n,
            post_nms_top_n,
            nms_iou: self.nms_iou,
            min_size: self.min_size,
        }
    }
}

impl Default for RpnConfig {
    fn default() -> Self {
        Self {
            pre_nms_top_n_train: 1000,
            post_nms_top_n_train: 300,
            pre_nms_top_n_test: 600,
            post_nms_top_n_test: 150,
            nms_iou: 0.7,
            fg_iou: 0.7,
            bg_iou: 0.3,
            batch_size_per_image: 256,
            positive_fraction: 0.5,
            min_size: 1e-3,
        }
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RoiConfig {
    /// RoIAlign output side.
    pub pool_size: usize,
    /// Samples per bin side in RoIAlign.
    pub sampling_ratio: usize,
    pub fg_iou: f32,
    pub bg_iou: f32,
    pub batch_size_per_image: usize,
    pub positive_fraction: f32,
    /// Box coding weights of the head (torchvision: 10, 10, 5, 5).
    pub box_weights: [f32; 4],
}

impl Default for RoiConfig {
    fn default() -> Self {
        Self {
            pool_size: 7,
            sampling_ratio: 2,
            fg_iou: 0.5,
            bg_iou: 0.5,
            // An image holds about six corners: 64 RoIs (at most 16 positive)
            // cover them at half the head's cost of torchvision's 128.
            batch_size_per_image: 64,
            positive_fraction: 0.25,
            box_weights: [10.0, 10.0, 5.0, 5.0],
        }
    }
}

/// Post-processing shared by all networks.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DetectionConfig {
    pub score_threshold: f32,
    pub nms_iou: f32,
    pub max_detections: usize,
}

impl Default for DetectionConfig {
    fn default() -> Self {
        // NMS at torchvision's 0.5: a box obstacle's labelled corners lie
        // 30-60 px apart, so their 96 px boxes overlap. At 0.3, even perfect
        // detections of the default training split would keep at most 87 %
        // of its corners; at 0.5, 93 %.
        Self { score_threshold: 0.05, nms_iou: 0.5, max_detections: 100 }
    }
}

impl DetectorConfig {
    pub fn new(backbone: Backbone, width: f32) -> Self {
        Self {
            backbone,
            width,
            hidden: default_hidden(width),
            in_channels: 1,
            num_classes: 1,
            preprocess: PreprocessConfig::default(),
            anchors: AnchorConfig::default(),
            rpn: RpnConfig::default(),
            roi: RoiConfig::default(),
            grid_cells: 14,
            grid_head: GridHead::default(),
            detection: DetectionConfig::default(),
        }
    }

    /// Feeds the grayscale image beside the edges (or not), and sizes the
    /// network's input to match: the two must change together.
    pub fn set_gray_channel(&mut self, on: bool) {
        self.preprocess.gray_channel = on;
        self.in_channels = self.preprocess.channels();
    }

    /// A channel count of torchvision's network scaled by the width.
    pub fn channels(&self, torchvision: usize) -> usize {
        self.trunk().channels(torchvision)
    }

    /// The trunk's layers: VGG16 for Faster R-CNN and the vgg16 baseline.
    pub fn trunk(&self) -> TrunkConfig {
        let architecture = match self.backbone {
            Backbone::FasterRcnn | Backbone::Vgg16 => Architecture::Vgg16,
            Backbone::Alexnet => Architecture::Alexnet,
        };
        TrunkConfig::new(architecture).with_in_channels(self.in_channels).with_width(self.width)
    }

    /// The layers of the faster-rcnn backbone.
    pub fn faster_rcnn(&self) -> FasterRcnnConfig {
        FasterRcnnConfig::new(self.trunk(), self.anchors.per_location(), self.hidden, self.num_classes)
            .with_pool_size(self.roi.pool_size)
            .with_sampling_ratio(self.roi.sampling_ratio)
    }

    /// The layers of the vgg16 and alexnet baselines.
    pub fn grid_net(&self) -> GridNetConfig {
        GridNetConfig::new(self.trunk(), self.grid_head, self.grid_cells, self.hidden)
    }

    pub fn input_size(&self) -> usize {
        self.preprocess.size as usize
    }

    pub fn validate(&self) -> Result<(), InvalidSetting> {
        if !(self.width > 0.0 && self.width <= 4.0) {
            return Err(InvalidSetting::field("width", format!("{} outside (0, 4]", self.width)));
        }
        for (field, value) in
            [("in_channels", self.in_channels), ("num_classes", self.num_classes), ("hidden", self.hidden)]
        {
            if value == 0 {
                return Err(InvalidSetting::field(field, "must be at least 1"));
            }
        }
        self.preprocess.validate().map_err(|e| e.within("preprocess"))?;
        if self.in_channels != self.preprocess.channels() {
            let problem =
                format!("{} but the preprocessing gives {} channels", self.in_channels, self.preprocess.channels());
            return Err(InvalidSetting::field("in_channels", problem));
        }
        let size = self.input_size();
        if !size.is_multiple_of(32) || size < 64 {
            return Err(InvalidSetting::field(
                "preprocess.size",
                format!("{size} must be a multiple of 32 and at least 64"),
            ));
        }
        if self.grid_cells == 0 || !size.is_multiple_of(self.grid_cells) {
            let problem = format!("a grid of {} cells does not divide the input size {size}", self.grid_cells);
            return Err(InvalidSetting::field("grid_cells", problem));
        }
        if self.anchors.sizes.is_empty() {
            return Err(InvalidSetting::field("anchors.sizes", "needs at least one size"));
        }
        if self.anchors.aspect_ratios.is_empty() {
            return Err(InvalidSetting::field("anchors.aspect_ratios", "needs at least one aspect ratio"));
        }
        let d = &self.detection;
        for (field, value) in [("detection.score_threshold", d.score_threshold), ("detection.nms_iou", d.nms_iou)] {
            if !(0.0..=1.0).contains(&value) {
                return Err(InvalidSetting::field(field, format!("{value} outside [0, 1]")));
            }
        }
        // Every size a config can set is bounded: a checkpoint's config.json
        // that asks for 10^9 hidden units is an error, not an allocation abort.
        let (r, p) = (&self.rpn, &self.roi);
        let sizes = [
            ("hidden", self.hidden, 1 << 16),
            ("in_channels", self.in_channels, 16),
            ("num_classes", self.num_classes, 1024),
            ("preprocess.size", size, 2048),
            ("grid_cells", self.grid_cells, 512),
            ("anchors.sizes", self.anchors.sizes.len(), 64),
            ("anchors.aspect_ratios", self.anchors.aspect_ratios.len(), 64),
            ("rpn.pre_nms_top_n_train", r.pre_nms_top_n_train, 1 << 20),
            ("rpn.post_nms_top_n_train", r.post_nms_top_n_train, 1 << 20),
            ("rpn.pre_nms_top_n_test", r.pre_nms_top_n_test, 1 << 20),
            ("rpn.post_nms_top_n_test", r.post_nms_top_n_test, 1 << 20),
            ("rpn.batch_size_per_image", r.batch_size_per_image, 1 << 16),
            ("roi.pool_size", p.pool_size, 64),
            ("roi.sampling_ratio", p.sampling_ratio, 64),
            ("roi.batch_size_per_image", p.batch_size_per_image, 1 << 16),
            ("detection.max_detections", d.max_detections, 1 << 16),
        ];
        if let Some((field, value, max)) = sizes.iter().find(|(_, v, max)| v > max) {
            return Err(InvalidSetting::field(*field, format!("{value} is larger than {max}")));
        }
        if p.pool_size == 0 {
            return Err(InvalidSetting::field("roi.pool_size", "must be at least 1"));
        }
        Ok(())
    }
}

fn fc_head() -> GridHead {
    GridHead::Fc
}

pub fn default_hidden(width: f32) -> usize {
    ((4096.0 * width * width).round() as usize).max(64)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_size_a_config_sets_is_bounded() {
        let good = DetectorConfig::new(Backbone::FasterRcnn, 0.25);
        assert_eq!(good.validate(), Ok(()));
        let mut huge = good.clone();
        huge.hidden = 1_000_000_000;
        assert_eq!(huge.validate(), Err(InvalidSetting::field("hidden", "1000000000 is larger than 65536")));
        let mut huge = good.clone();
        huge.roi.pool_size = 1 << 20;
        assert_eq!(huge.validate().unwrap_err().field, "roi.pool_size");
        let mut bad = good.clone();
        bad.preprocess.canny_low = f32::NAN;
        assert_eq!(bad.validate().unwrap_err().field, "preprocess.canny_low");
        let mut huge = good;
        huge.detection.max_detections = usize::MAX;
        assert_eq!(huge.validate().unwrap_err().field, "detection.max_detections");
    }
}
