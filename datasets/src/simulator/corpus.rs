//! The pretraining corpus: detection images from many worlds that differ
//! from the evaluation data in geometry (level heights, ramp slope, ceiling
//! height, corridor width), appearance (colours, posters) and views, so that
//! a trunk pretrained on it has never seen the images it is evaluated on.
//! Besides variants of the paper's area it can hold generated buildings
//! (numbered from [`CorpusConfig::first_building`], far from the benchmark's
//! buildings 1-5), so that the detector learns rooms it is not tested on.

use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::InvalidSetting;
use crate::atomic;
use crate::cli::progress;
use crate::error::{DataError, Result};
use crate::seed::{mix, unit};
use crate::simulator::generate::{DatagenConfig, key, render_views, stream, write_coco_splits};
use crate::simulator::world::rig::Rig;
use crate::simulator::world::{World, WorldConfig};

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CorpusConfig {
    /// Seed of the worlds' geometry and appearance and of the views.
    pub seed: u64,
    /// Variants of the paper's three-level area.
    pub worlds: usize,
    /// Generated buildings (`--building N`), after the variants.
    pub buildings: usize,
    /// The number of the first generated building.
    pub first_building: u32,
    pub images_per_world: usize,
    /// Every this-many-th image goes to the corpus's own test split.
    pub test_every: usize,
}

impl Default for CorpusConfig {
    fn default() -> Self {
        Self { seed: 1001, worlds: 16, buildings: 0, first_building: 1001, images_per_world: 250, test_every: 20 }
    }
}

/// Written beside the images; a corpus whose file matches is reused.
pub const CORPUS_FILE: &str = "corpus.json";

impl CorpusConfig {
    pub fn images(&self) -> usize {
        (self.worlds + self.buildings) * self.images_per_world
    }

    pub fn validate(&self) -> std::result::Result<(), InvalidSetting> {
        if self.worlds + self.buildings == 0 {
            return Err(InvalidSetting::between("the corpus needs at least one world or building"));
        }
        if self.images_per_world == 0 {
            return Err(InvalidSetting::field("images_per_world", "must be at least 1"));
        }
        if self.images() > 1_000_000 {
            let problem = format!("{} images in all is more than a corpus needs (at most 1000000)", self.images());
            return Err(InvalidSetting::field("images_per_world", problem));
        }
        if self.buildings > 0 && self.first_building < 6 {
            let problem =
                format!("{} would train on the benchmark's buildings 1-5 (use 6 or more)", self.first_building);
            return Err(InvalidSetting::field("first_building", problem));
        }
        if self.test_every < 2 {
            return Err(InvalidSetting::field("test_every", format!("{} must be at least 2", self.test_every)));
        }
        Ok(())
    }

    /// World `k`'s geometry: every setting drawn within the ranges that keep
    /// the three-level area valid.
    pub fn world(&self, k: usize) -> WorldConfig {
        let u = |field: u64| unit(mix(self.seed ^ mix(k as u64 * 16 + field)));
        let lerp = |field: u64, lo: f64, hi: f64| lo + (hi - lo) * u(field);
        let rise1 = lerp(1, 0.3, 0.8);
        let rise2 = lerp(2, 0.3, 0.8);
        let top = rise1 + rise2;
        WorldConfig {
            building: 0,
            level_heights_m: [0.0, rise1, top],
            ramp_slope_deg: lerp(3, 6.0, 14.0),
            ceiling_height_m: top + lerp(4, 2.2, 3.2),
            corridor_width_m: lerp(5, 1.8, 3.0),
            corridor_m: 0.0,
        }
    }
}

impl CorpusConfig {
    /// The corpus's world `k`: a variant of the paper's area for the first
    /// `worlds`, then the generated buildings.
    pub fn world_or_building(&self, k: usize) -> WorldConfig {
        if k < self.worlds {
            self.world(k)
        } else {
            WorldConfig { building: self.first_building + (k - self.worlds) as u32, ..WorldConfig::default() }
        }
    }
}

#[derive(Debug, Clone, PartialEq)]
pub struct CorpusSummary {
    pub images: usize,
    pub labels: usize,
    /// The corpus was already there, with the same settings.
    pub reused: bool,
}

/// Writes the corpus into `out` (`images/`, `canny/`, `train.json`,
/// `test.json`, `corpus.json`) unless it is already there with the same
/// settings. `base` gives the camera labels and preprocessing.
pub fn generate_corpus(out: &Path, config: &CorpusConfig, base: &DatagenConfig) -> Result<CorpusSummary> {
    config.validate().map_err(|e| DataError::setting(out, e.within("corpus")))?;
    let marker = out.join(CORPUS_FILE);
    let stamp = serde_json::json!({ "corpus": config, "labels": base.labels, "preprocess": base.preprocess });
    if let Ok(text) = std::fs::read_to_string(&marker)
        && serde_json::from_str::<serde_json::Value>(&text).ok().as_ref() == Some(&stamp)
    {
        let labels = crate::io::formats::read_coco(&out.join("train.json"))?.annotations.len()
            + crate::io::formats::read_coco(&out.join("test.json"))?.annotations.len();
        return Ok(CorpusSummary { images: config.images(), labels, reused: true });
    }
    let rig = Rig::default();
    let bar = progress(config.images(), "corpus");
    // The views' seed is salted so that no corpus view repeats a datagen view.
    let views_seed = mix(config.seed ^ 0xc0_4905);
    let mut views = Vec::with_capacity(config.images());
    for k in 0..config.worlds + config.buildings {
        let world = World::new(&config.world_or_building(k), key(config.seed, stream::APPEARANCE, k as u64 + 1));
        let first = k * config.images_per_world;
        views.extend(render_views(out, &world, &rig, base, views_seed, first..first + config.images_per_world, &bar)?);
    }
    bar.finish_and_clear();
    let train: Vec<bool> = (0..views.len()).map(|i| i % config.test_every != 0).collect();
    let labels = write_coco_splits(out, views, &train)?;
    atomic::write_json(&marker, &stamp)?;
    Ok(CorpusSummary { images: config.images(), labels, reused: false })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn generated_buildings_follow_the_variants_and_never_the_benchmarks() {
        let config =
            CorpusConfig { worlds: 2, buildings: 3, first_building: 40, images_per_world: 5, ..Default::default() };
        assert_eq!(config.images(), 25);
        assert_eq!(config.world_or_building(1).building, 0);
        assert_eq!(config.world_or_building(1), config.world(1));
        assert_eq!(config.world_or_building(2).building, 40);
        assert_eq!(config.world_or_building(4).building, 42);
        let benchmark = CorpusConfig { buildings: 1, first_building: 5, ..config.clone() };
        assert_eq!(benchmark.validate().unwrap_err().field, "first_building");
        assert!(CorpusConfig { worlds: 0, buildings: 0, ..config.clone() }.validate().is_err());
        assert_eq!(
            CorpusConfig { images_per_world: 1 << 20, ..config }.validate().unwrap_err().field,
            "images_per_world"
        );
    }
}
