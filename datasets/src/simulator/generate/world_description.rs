//! `world.json`: the part of the world a sequence's evaluation needs.

use serde::Serialize;

use crate::simulator::world::{World, WorldConfig};

/// `world.json`: what the ground truth knows about the area, for per-level
/// evaluation and for checking corners.
#[derive(Debug, Clone, Serialize)]
pub struct WorldDescription<'a> {
    pub config: &'a WorldConfig,
    pub levels: Vec<LevelDescription>,
    pub regions: &'a [crate::simulator::world::layout::Region],
    pub corners: &'a [crate::simulator::world::Corner],
}

#[derive(Debug, Clone, Serialize)]
pub struct LevelDescription {
    pub name: String,
    pub floor_height_m: f64,
}

impl<'a> WorldDescription<'a> {
    pub fn of(world: &'a World) -> Self {
        let layout = &world.layout;
        let levels = layout
            .levels
            .iter()
            .enumerate()
            .map(|(i, &h)| LevelDescription { name: format!("level {}", i + 1), floor_height_m: h })
            .collect();
        Self { config: &layout.config, levels, regions: &layout.regions, corners: &layout.corners }
    }
}
