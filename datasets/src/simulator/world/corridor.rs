//! A long straight corridor with nothing in it: plain walls, floor and
//! ceiling, no doorway, pillar or furniture. Along its axis every plane
//! looks the same, the hard case of LIDAR odometry: scan matching and walls
//! pin the robot across the corridor, only the wheels and the IMU along it.

use super::layout::{Floor, Layout, Region, WorldConfig};

/// Room behind the start, so that the robot starts inside the corridor.
const BEHIND_START_M: f64 = 1.5;

/// The corridor of `config.corridor_m` (the robot drives from one end
/// towards the other, stopping `BEHIND_START_M` short of it).
pub fn build(config: &WorldConfig, appearance_seed: u64) -> Layout {
    let length = config.corridor_m;
    let w = config.corridor_width_m / 2.0;
    let floor = config.level_heights_m[0];
    let corridor = Region {
        name: "corridor".to_string(),
        x: [-BEHIND_START_M, length - BEHIND_START_M],
        y: [-w, w],
        floor: Floor::Flat { height_m: floor },
        level: Some(0),
        ceiling_m: None,
    };
    let route = vec![[0.0, 0.0], [length - 2.0 * BEHIND_START_M, 0.0]];
    let mut layout = Layout::unbuilt(config.clone(), vec![floor], vec![corridor], Vec::new(), route);
    layout.build_surfaces_and_corners(appearance_seed);
    layout
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::{Point3, Vec3};
    use crate::simulator::world::World;

    #[test]
    fn the_corridor_is_long_empty_and_its_only_corners_are_at_its_ends() {
        let config = WorldConfig { corridor_m: 60.0, ..WorldConfig::default() };
        let world = World::new(&config, 1);
        let layout = &world.layout;
        assert_eq!(layout.regions.len(), 1);
        assert!(layout.blocks.is_empty() && layout.obstacles.is_empty() && layout.walkers.is_empty());
        for corner in &layout.corners {
            let x = corner.position[0];
            assert!(!(-1.0..=58.0).contains(&x), "a corner inside the corridor at {x}");
        }
        // Sideways the wall is half the width away, ahead the far end.
        let origin = Point3::new(0.0, 0.0, 1.0);
        let side = world.cast(&origin, &Vec3::y(), 0.0, 100.0).unwrap();
        assert!((side.t - config.corridor_width_m / 2.0).abs() < 1e-9, "{}", side.t);
        let ahead = world.cast(&origin, &Vec3::x(), 0.0, 100.0).unwrap();
        assert!((ahead.t - 58.5).abs() < 1e-9, "{}", ahead.t);
    }
}
