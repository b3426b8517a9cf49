//! COCO-style detection annotations (`images`, `annotations` with `bbox`
//! `[x, y, width, height]` in pixels, `categories`), so that labeling tools
//! and viewers read our data and we read theirs. Corner labels add two
//! optional fields to an annotation: `corner_type` and `point`, the exact
//! projected corner in image coordinates.

use std::collections::HashSet;
use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::bbox::BBox;
use crate::error::{DataError, Result};

#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct CocoDataset {
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub info: Option<serde_json::Value>,
    pub images: Vec<CocoImage>,
    pub annotations: Vec<CocoAnnotation>,
    pub categories: Vec<CocoCategory>,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CocoImage {
    pub id: u64,
    pub file_name: String,
    pub width: u32,
    pub height: u32,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CocoAnnotation {
    pub id: u64,
    pub image_id: u64,
    pub category_id: u64,
    pub bbox: [f32; 4],
    #[serde(default)]
    pub area: f32,
    #[serde(default)]
    pub iscrowd: u8,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub corner_type: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub point: Option<[f32; 2]>,
}

impl CocoAnnotation {
    /// A corner label of the project's one class: its box and its point.
    pub fn corner(id: u64, image_id: u64, bbox: &BBox, point: [f64; 2], kind: Option<&str>) -> Self {
        Self {
            id,
            image_id,
            category_id: 1,
            bbox: bbox.to_xywh(),
            area: bbox.area(),
            iscrowd: 0,
            corner_type: kind.map(str::to_string),
            point: Some([point[0] as f32, point[1] as f32]),
        }
    }
}

impl CocoAnnotation {
    /// A region that may or may not hold a corner (`iscrowd` 1): trainers
    /// leave it out of both classes and evaluation does not count detections there.
    pub fn ignore_region(id: u64, image_id: u64, bbox: &BBox) -> Self {
        Self {
            id,
            image_id,
            category_id: 1,
            bbox: bbox.to_xywh(),
            area: bbox.area(),
            iscrowd: 1,
            corner_type: None,
            point: None,
        }
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CocoCategory {
    pub id: u64,
    pub name: String,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub supercategory: Option<String>,
}

impl CocoAnnotation {
    pub fn bbox(&self) -> BBox {
        BBox::from_xywh(self.bbox)
    }
}

impl CocoDataset {
    /// The annotations of one image.
    pub fn annotations_of(&self, image_id: u64) -> impl Iterator<Item = &CocoAnnotation> {
        self.annotations.iter().filter(move |a| a.image_id == image_id)
    }

    /// Checks ids and boxes; the error names `path` and the first offending entry.
    pub fn validate(&self, path: &Path) -> Result<()> {
        let invalid = |message: String| Err(DataError::invalid(path, message));
        let mut images = HashSet::new();
        let mut sizes = std::collections::HashMap::new();
        for im in &self.images {
            if !images.insert(im.id) {
                return invalid(format!("duplicate image id {}", im.id));
            }
            if im.width == 0 || im.height == 0 {
                return invalid(format!(
                    "image {} ({}) has a zero size {}x{}",
                    im.id, im.file_name, im.width, im.height
                ));
            }
            sizes.insert(im.id, (im.width as f32, im.height as f32));
        }
        let categories: HashSet<u64> = self.categories.iter().map(|c| c.id).collect();
        let mut ids = HashSet::new();
        for a in &self.annotations {
            if !ids.insert(a.id) {
                return invalid(format!("duplicate annotation id {}", a.id));
            }
            if !images.contains(&a.image_id) {
                return invalid(format!("annotation {} refers to unknown image {}", a.id, a.image_id));
            }
            if !categories.contains(&a.category_id) {
                return invalid(format!("annotation {} refers to unknown category {}", a.id, a.category_id));
            }
            if a.iscrowd > 1 {
                return invalid(format!("annotation {} has iscrowd {} (0 or 1)", a.id, a.iscrowd));
            }
            let [x, y, w, h] = a.bbox;
            if !a.bbox().is_finite() || w < 0.0 || h < 0.0 {
                return invalid(format!("annotation {} has an invalid bbox {:?}", a.id, a.bbox));
            }
            if w == 0.0 || h == 0.0 {
                return invalid(format!("annotation {} has a zero-size bbox {:?}", a.id, a.bbox));
            }
            // A pixel of slack for tools that round outwards.
            let (width, height) = sizes[&a.image_id];
            if x < -1.0 || y < -1.0 || x + w > width + 1.0 || y + h > height + 1.0 {
                return invalid(format!(
                    "annotation {} has a bbox {:?} outside its {width}x{height} image {}",
                    a.id, a.bbox, a.image_id
                ));
            }
        }
        Ok(())
    }
}

/// The one category of corner labels (id 1, "corner").
pub fn corner_categories() -> Vec<CocoCategory> {
    vec![CocoCategory { id: 1, name: "corner".into(), supercategory: Some("corner".into()) }]
}

pub fn read_coco(path: &Path) -> Result<CocoDataset> {
    parse_coco(path, &crate::atomic::read_text(path)?)
}

/// A validated COCO set from the text of `path`.
pub fn parse_coco(path: &Path, text: &str) -> Result<CocoDataset> {
    let data: CocoDataset = serde_json::from_str(text).map_err(|e| DataError::json(path, e))?;
    data.validate(path)?;
    Ok(data)
}

pub fn write_coco(path: &Path, data: &CocoDataset) -> Result<()> {
    crate::atomic::write_json(path, data)
}
