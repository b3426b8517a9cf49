//! The synthetic multilevel world and its sensors: the layout (the paper's
//! three levels with two 10 degree ramps, or a generated building), a
//! ray-cast camera, an M8-like LIDAR, wheel odometry and an IMU, and the
//! corner labels.

pub mod block;
pub mod building;
pub mod bvh;
pub mod corridor;
pub mod labels;
pub mod layout;
pub mod lidar;
pub mod motion;
pub mod people;
pub mod render;
pub mod rig;
pub mod route;
pub mod surface;

use bvh::{Bvh, Hit};
pub use layout::{Corner, CornerKind, Layout, WorldConfig};

use crate::math::{Point3, Vec3};
use surface::SurfaceKind;

/// The layout with its ray-casting acceleration structure.
#[derive(Debug, Clone)]
pub struct World {
    pub layout: Layout,
    bvh: Bvh,
}

/// What a ray met.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Seen {
    /// An index into the layout's surfaces.
    Surface(usize),
    /// An index into the layout's walkers.
    Person(usize),
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sensed {
    pub t: f64,
    pub seen: Seen,
    /// The normal of the face met (either orientation).
    pub normal: Vec3,
}

impl World {
    /// The paper building (`config.building == 0`), generated building N or
    /// the long corridor (`config.corridor_m > 0`);
    /// `appearance_seed` varies colours and posters, never the geometry.
    pub fn new(config: &WorldConfig, appearance_seed: u64) -> Self {
        let layout = match config.building {
            _ if config.corridor_m > 0.0 => corridor::build(config, appearance_seed),
            0 => Layout::build(config, appearance_seed),
            n => building::generate(n, appearance_seed),
        };
        let bvh = Bvh::build(&layout.surfaces);
        Self { layout, bvh }
    }

    /// The nearest surface along a ray (`dir` need not be unit; `t` is in
    /// units of `dir`).
    pub fn cast(&self, origin: &Point3, dir: &Vec3, t_min: f64, t_max: f64) -> Option<Hit> {
        self.bvh.nearest(&self.layout.surfaces, origin, dir, t_min, t_max)
    }

    /// The nearest surface (glass included) or person along a ray at world
    /// time `time`.
    pub fn sense(&self, origin: &Point3, dir: &Vec3, t_min: f64, t_max: f64, time: f64) -> Option<Sensed> {
        let surfaces = &self.layout.surfaces;
        let mut best = self.cast(origin, dir, t_min, t_max).map(|hit| Sensed {
            t: hit.t,
            seen: Seen::Surface(hit.surface),
            normal: surfaces[hit.surface].normal,
        });
        let mut limit = best.map_or(t_max, |b| b.t);
        for (index, walker) in self.layout.walkers.iter().enumerate() {
            if let Some((t, normal)) = walker.intersect(time, origin, dir, t_min, limit) {
                limit = t;
                best = Some(Sensed { t, seen: Seen::Person(index), normal });
            }
        }
        best
    }

    /// Whether something opaque (a surface other than glass, or a person at
    /// `time`) lies along the ray within `(t_min, t_max)`.
    pub fn blocked(&self, origin: &Point3, dir: &Vec3, t_min: f64, t_max: f64, time: f64) -> bool {
        let mut from = t_min;
        while let Some(hit) = self.sense(origin, dir, from, t_max, time) {
            match hit.seen {
                Seen::Surface(i) if self.layout.surfaces[i].kind == SurfaceKind::Glass => from = hit.t + 1e-6,
                _ => return true,
            }
        }
        false
    }
}
