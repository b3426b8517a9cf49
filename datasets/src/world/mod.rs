//! The synthetic multilevel world and its sensors: the layout (three levels,
//! two 10 degree ramps, walls, boxes), a ray-cast camera, an M8-like LIDAR,
//! wheel odometry and an IMU, and the corner labels.

pub mod bvh;
pub mod labels;
pub mod layout;
pub mod lidar;
pub mod motion;
pub mod render;
pub mod rig;
pub mod route;
pub mod surface;

use bvh::{Bvh, Hit};
pub use layout::{Corner, CornerKind, Layout, WorldConfig};

use crate::math::{Point3, Vec3};

/// The layout with its ray-casting acceleration structure.
#[derive(Debug, Clone)]
pub struct World {
    pub layout: Layout,
    bvh: Bvh,
}

impl World {
    pub fn new(config: &WorldConfig, appearance_seed: u64) -> Self {
        let layout = Layout::build(config, appearance_seed);
        let bvh = Bvh::build(&layout.surfaces);
        Self { layout, bvh }
    }

    /// The nearest surface along a ray (`dir` need not be unit; `t` is in
    /// units of `dir`).
    pub fn cast(&self, origin: &Point3, dir: &Vec3, t_min: f64, t_max: f64) -> Option<Hit> {
        self.bvh.nearest(&self.layout.surfaces, origin, dir, t_min, t_max)
    }
}
