//! A COCO-form labeled image set, loaded and preprocessed once: what training
//! and evaluation iterate over.

use std::path::{Path, PathBuf};

use rayon::prelude::*;

use crate::boxes::BBox;
use crate::metrics::TruthCorner;
use datasets::DataError;
use datasets::io::formats::read_coco;
use datasets::preprocess::{ImageToNet, NetInput, PreprocessConfig, network_input};

#[derive(Debug, Clone)]
pub struct LabeledImage {
    pub path: PathBuf,
    /// The network input (Canny edges, square; the grayscale image beside
    /// them where the preprocessing asks for it).
    pub input: NetInput,
    pub width: u32,
    pub height: u32,
    /// Corners in original image pixels.
    pub truth: Vec<TruthCorner>,
    /// Regions that may or may not hold a corner (COCO `iscrowd` 1, as
    /// `localize autolabel` writes where its 3D sensor cannot tell): neither
    /// taught as corner nor as background, and detections there are not
    /// counted.
    pub ignore: Vec<BBox>,
}

impl LabeledImage {
    pub fn to_net(&self, size: u32) -> ImageToNet {
        ImageToNet::new(self.width, self.height, size)
    }
    /// Ground-truth boxes in network input pixels.
    pub fn net_boxes(&self, size: u32) -> Vec<BBox> {
        let map = self.to_net(size);
        self.truth.iter().map(|t| map.to_net(&t.bbox)).collect()
    }
    /// Ignore regions in network input pixels.
    pub fn net_ignore(&self, size: u32) -> Vec<BBox> {
        let map = self.to_net(size);
        self.ignore.iter().map(|b| map.to_net(b)).collect()
    }
}

/// Loads the images of a COCO file (paths relative to the file's folder)
/// and preprocesses them. An annotation without a `point` uses its box centre;
/// `iscrowd` annotations are ignore regions.
pub fn load_coco_set(annotations: &Path, preprocess_config: &PreprocessConfig) -> Result<Vec<LabeledImage>, DataError> {
    let coco = read_coco(annotations)?;
    if coco.images.is_empty() {
        return Err(DataError::invalid(annotations, "no images: nothing to train or evaluate on"));
    }
    let root = annotations.parent().unwrap_or(Path::new("."));
    coco.images
        .par_iter()
        .map(|im| {
            let path = root.join(&im.file_name);
            let image = datasets::atomic::read_image(&path)?;
            if (image.width(), image.height()) != (im.width, im.height) {
                return Err(DataError::invalid(
                    &path,
                    format!(
                        "image is {}x{} but {} says {}x{}",
                        image.width(),
                        image.height(),
                        annotations.display(),
                        im.width,
                        im.height
                    ),
                ));
            }
            let (crowd, corners): (Vec<_>, Vec<_>) = coco.annotations_of(im.id).partition(|a| a.iscrowd != 0);
            let truth = corners
                .into_iter()
                .map(|a| TruthCorner { bbox: a.bbox(), point: a.point.unwrap_or_else(|| a.bbox().centre()) })
                .collect();
            let ignore = crowd.into_iter().map(|a| a.bbox()).collect();
            Ok(LabeledImage {
                path,
                input: network_input(&image, preprocess_config),
                width: im.width,
                height: im.height,
                truth,
                ignore,
            })
        })
        .collect()
}
