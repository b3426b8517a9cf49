//! Where the levels of a route are: the footprint regions of a generated
//! world (`world.json` beside the ground truth), so that errors can be split
//! per level and for the ramps, as the paper's Table 2.

use std::path::Path;

use datasets::io::formats::Trajectory;
use datasets::math::Vec3;
use datasets::{DataError, Result};

use crate::evaluation::eval::{Comparison, ErrorSummary};
use serde::{Deserialize, Serialize};

#[derive(Debug, Clone, Deserialize)]
struct RegionEntry {
    name: String,
    x: [f64; 2],
    y: [f64; 2],
    /// Level index of a flat region; absent or null for a ramp.
    #[serde(default)]
    level: Option<usize>,
}

#[derive(Debug, Clone, Deserialize)]
struct WorldFile {
    regions: Vec<RegionEntry>,
}

/// The errors on one level (or the ramps) of the route.
#[derive(Debug, Clone, Serialize)]
pub struct SegmentMetrics {
    pub name: String,
    #[serde(flatten)]
    pub errors: ErrorSummary,
}

/// Named footprint rectangles; a position belongs to the first that holds it.
#[derive(Debug, Clone)]
pub struct LevelMap {
    regions: Vec<RegionEntry>,
}

impl LevelMap {
    pub fn read(path: &Path) -> Result<Self> {
        let text = datasets::atomic::read_text(path)?;
        let file: WorldFile = serde_json::from_str(&text).map_err(|e| DataError::json(path, e))?;
        if file.regions.is_empty() {
            return Err(DataError::invalid(path, "no regions: cannot tell where the levels are"));
        }
        Ok(Self { regions: file.regions })
    }

    /// The segment of the route at (x, y): `level N` (1-based) on a flat
    /// level, `ramps` on a ramp, `None` outside every region.
    pub fn segment_at(&self, x: f64, y: f64) -> Option<String> {
        let region = self.regions.iter().find(|r| x >= r.x[0] && x <= r.x[1] && y >= r.y[0] && y <= r.y[1])?;
        Some(match region.level {
            Some(k) => format!("level {}", k + 1),
            None if region.name.contains("ramp") => "ramps".to_string(),
            None => region.name.clone(),
        })
    }

    /// Error summaries per segment (levels, then ramps) of a comparison,
    /// by where the reference pose of each matched pair lies.
    pub fn per_segment(&self, comparison: &Comparison, reference: &Trajectory) -> Vec<SegmentMetrics> {
        let mut groups: Vec<(String, Vec<Vec3>)> = Vec::new();
        for (&(r, _), error) in comparison.association.pairs.iter().zip(&comparison.errors) {
            let p = reference.poses[r].translation.vector;
            let Some(name) = self.segment_at(p.x, p.y) else { continue };
            match groups.iter_mut().find(|(n, _)| *n == name) {
                Some((_, g)) => g.push(*error),
                None => groups.push((name, vec![*error])),
            }
        }
        groups.sort_by(|a, b| a.0.cmp(&b.0));
        groups
            .into_iter()
            .filter_map(|(name, g)| ErrorSummary::of(&g).map(|errors| SegmentMetrics { name, errors }))
            .collect()
    }
}
