//! The three-level indoor area: halls and corridors whose footprints are
//! axis-aligned rectangles with a flat or ramped floor. Walls are the
//! boundary of the union of the footprints; corners are where three planes
//! meet (floor or ceiling and two walls, a ramp's ends at its side walls,
//! the corners of box obstacles).
//!
//! World frame: x forward at the start of the route, y left, z up, origin on
//! the level-1 floor where the robot starts.

use serde::{Deserialize, Serialize};

use super::block::Block;
use super::people::Walker;
use super::surface::{Material, Pattern, Surface, SurfaceKind};
use crate::InvalidSetting;
use crate::math::{Point3, Vec3};
use crate::seed::mix;

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct WorldConfig {
    /// 0: the paper's building, shaped by the fields below; N >= 1: generated
    /// building N (its own levels, ramps and rooms; the fields below unused).
    pub building: u32,
    /// Floor heights of levels 1, 2 and 3 above the level-1 floor.
    pub level_heights_m: [f64; 3],
    /// Slope of the two ramps between the levels.
    pub ramp_slope_deg: f64,
    /// Height of the (single, flat) ceiling above the level-1 floor.
    pub ceiling_height_m: f64,
    /// Width of the corridors that hold the ramps (and of the long corridor).
    pub corridor_width_m: f64,
    /// Above 0: instead of a building, one straight featureless corridor
    /// this long (`corridor.rs`), level 1's floor, `corridor_width_m` wide.
    #[serde(skip_serializing_if = "is_zero")]
    pub corridor_m: f64,
}

fn is_zero(v: &f64) -> bool {
    *v == 0.0
}

impl Default for WorldConfig {
    fn default() -> Self {
        Self {
            building: 0,
            level_heights_m: [0.0, 0.5, 1.0],
            ramp_slope_deg: 10.0,
            ceiling_height_m: 3.5,
            corridor_width_m: 2.2,
            corridor_m: 0.0,
        }
    }
}

impl WorldConfig {
    pub fn validate(&self) -> Result<(), InvalidSetting> {
        if self.building > super::building::MAX_BUILDING {
            let problem = format!("{} outside 0..={}", self.building, super::building::MAX_BUILDING);
            return Err(InvalidSetting::field("building", problem));
        }
        if self.corridor_m != 0.0 {
            if !(10.0..=1000.0).contains(&self.corridor_m) {
                return Err(InvalidSetting::field("corridor_m", format!("{} m outside [10, 1000]", self.corridor_m)));
            }
            if self.building != 0 {
                let problem = format!("a corridor is a world of its own; building is {}, must be 0", self.building);
                return Err(InvalidSetting::field("building", problem));
            }
        }
        let [h0, h1, h2] = self.level_heights_m;
        if !(h0.is_finite() && h1 > h0 + 0.05 && h2 > h1 + 0.05) {
            let problem = format!("{:?} must rise by at least 5 cm each", self.level_heights_m);
            return Err(InvalidSetting::field("level_heights_m", problem));
        }
        if !(1.0..=30.0).contains(&self.ramp_slope_deg) {
            return Err(InvalidSetting::field(
                "ramp_slope_deg",
                format!("{} deg outside [1, 30]", self.ramp_slope_deg),
            ));
        }
        if !(self.ceiling_height_m > h2 + 1.5 && self.ceiling_height_m < 20.0) {
            let problem =
                format!("{} m must be below 20 m and leave 1.5 m above level 3 ({h2} m)", self.ceiling_height_m);
            return Err(InvalidSetting::field("ceiling_height_m", problem));
        }
        if !(1.2..=4.0).contains(&self.corridor_width_m) {
            return Err(InvalidSetting::field(
                "corridor_width_m",
                format!("{} m outside [1.2, 4]", self.corridor_width_m),
            ));
        }
        Ok(())
    }

    /// Horizontal length of the ramp that climbs `rise_m`.
    pub fn ramp_run(&self, rise_m: f64) -> f64 {
        rise_m / self.ramp_slope_deg.to_radians().tan()
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Axis {
    X,
    Y,
}

/// The floor of a footprint rectangle.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Floor {
    Flat {
        height_m: f64,
    },
    /// Height rises linearly from `h0` at `from` to `h1` at `to` along `axis`.
    Ramp {
        axis: Axis,
        from: f64,
        to: f64,
        h0: f64,
        h1: f64,
    },
}

/// A footprint rectangle of free space with its floor.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Region {
    pub name: String,
    pub x: [f64; 2],
    pub y: [f64; 2],
    pub floor: Floor,
    /// Level index of a flat region; `None` for a ramp.
    pub level: Option<usize>,
    /// Ceiling height above the floor under it; `None`: the layout's one
    /// flat ceiling (`WorldConfig::ceiling_height_m`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub ceiling_m: Option<f64>,
}

impl Region {
    pub fn contains(&self, x: f64, y: f64) -> bool {
        x >= self.x[0] && x <= self.x[1] && y >= self.y[0] && y <= self.y[1]
    }
    fn strictly_contains(&self, x: f64, y: f64) -> bool {
        x > self.x[0] && x < self.x[1] && y > self.y[0] && y < self.y[1]
    }
    pub fn floor_height(&self, x: f64, y: f64) -> f64 {
        match self.floor {
            Floor::Flat { height_m } => height_m,
            Floor::Ramp { axis, from, to, h0, h1 } => {
                let c = if axis == Axis::X { x } else { y };
                h0 + (h1 - h0) * ((c - from) / (to - from)).clamp(0.0, 1.0)
            }
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum CornerKind {
    /// Floor and two walls.
    Floor,
    /// Ceiling and two walls.
    Ceiling,
    /// End of a ramp-floor edge, at a side wall.
    Ramp,
    /// Top corner of a box obstacle (three box faces).
    BoxTop,
    /// Bottom corner of a box obstacle (floor and two box faces).
    BoxBottom,
}

impl CornerKind {
    pub fn name(self) -> &'static str {
        match self {
            Self::Floor => "floor",
            Self::Ceiling => "ceiling",
            Self::Ramp => "ramp",
            Self::BoxTop => "box_top",
            Self::BoxBottom => "box_bottom",
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Corner {
    pub position: [f64; 3],
    pub kind: CornerKind,
}

/// A box obstacle standing on a flat floor.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Obstacle {
    pub x: [f64; 2],
    pub y: [f64; 2],
    pub z: [f64; 2],
}

/// A point light under the ceiling.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Light {
    pub position: [f64; 3],
}

/// The built geometry: what the sensors see and what the labels come from.
#[derive(Debug, Clone)]
pub struct Layout {
    pub config: WorldConfig,
    /// Floor height of each level, lowest first.
    pub levels: Vec<f64>,
    pub regions: Vec<Region>,
    pub obstacles: Vec<Obstacle>,
    /// Pillars, partitions, glass, crates and furniture.
    pub blocks: Vec<Block>,
    /// People walking through.
    pub walkers: Vec<Walker>,
    pub surfaces: Vec<Surface>,
    pub corners: Vec<Corner>,
    pub lights: Vec<Light>,
    /// Waypoints of the robot's route (x, y on the floor); the route rounds
    /// the inner ones.
    pub route: Vec<[f64; 2]>,
}

const EPS: f64 = 1e-6;

impl Layout {
    /// Builds the area from its config. `appearance_seed` varies colours and
    /// poster placement, never the geometry.
    pub fn build(config: &WorldConfig, appearance_seed: u64) -> Self {
        let [h0, h1, h2] = config.level_heights_m;
        let w = config.corridor_width_m / 2.0;
        let l1 = config.ramp_run(h1 - h0);
        let l2 = config.ramp_run(h2 - h1);
        let turn_x = 13.0 + l1;
        let flat = |height_m| Floor::Flat { height_m };
        let region = |name: &str, x: [f64; 2], y: [f64; 2], floor: Floor, level: Option<usize>| Region {
            name: name.to_string(),
            x,
            y,
            floor,
            level,
            ceiling_m: None,
        };
        let regions = vec![
            region("level 1 hall", [-1.5, 6.0], [-2.5, 2.5], flat(h0), Some(0)),
            region("level 1 corridor", [6.0, 7.5], [-w, w], flat(h0), Some(0)),
            region(
                "ramp 1",
                [7.5, 7.5 + l1],
                [-w, w],
                Floor::Ramp { axis: Axis::X, from: 7.5, to: 7.5 + l1, h0, h1 },
                None,
            ),
            region("level 2 corridor", [7.5 + l1, 9.5 + l1], [-w, w], flat(h1), Some(1)),
            region("level 2 hall", [9.5 + l1, 16.5 + l1], [-2.5, 3.5], flat(h1), Some(1)),
            region("level 2 corridor north", [turn_x - w, turn_x + w], [3.5, 5.0], flat(h1), Some(1)),
            region(
                "ramp 2",
                [turn_x - w, turn_x + w],
                [5.0, 5.0 + l2],
                Floor::Ramp { axis: Axis::Y, from: 5.0, to: 5.0 + l2, h0: h1, h1: h2 },
                None,
            ),
            region("level 3 corridor", [turn_x - w, turn_x + w], [5.0 + l2, 6.5 + l2], flat(h2), Some(2)),
            region("level 3 hall", [9.5 + l1, 16.5 + l1], [6.5 + l2, 12.5 + l2], flat(h2), Some(2)),
        ];
        let obstacle =
            |x: [f64; 2], y: [f64; 2], floor: f64, height: f64| Obstacle { x, y, z: [floor, floor + height] };
        let obstacles = vec![
            obstacle([2.5, 3.1], [1.3, 1.9], h0, 0.7),
            obstacle([4.2, 4.8], [-1.9, -1.3], h0, 0.5),
            obstacle([15.2 + l1, 15.9 + l1], [-1.8, -1.1], h1, 0.9),
            obstacle([10.3 + l1, 10.9 + l1], [2.2, 2.8], h1, 0.6),
            obstacle([10.5 + l1, 11.3 + l1], [9.0 + l2, 9.8 + l2], h2, 1.0),
            obstacle([15.0 + l1, 15.6 + l1], [10.8 + l2, 11.4 + l2], h2, 0.5),
        ];
        let route = vec![[0.0, 0.0], [turn_x, 0.0], [turn_x, 10.0 + l2]];
        let mut layout = Self::unbuilt(config.clone(), config.level_heights_m.to_vec(), regions, obstacles, route);
        layout.build_surfaces_and_corners(appearance_seed);
        layout
    }

    /// A layout of free space, obstacles and route with nothing else yet:
    /// blocks and walkers are added, then `build_surfaces_and_corners`.
    pub(super) fn unbuilt(
        config: WorldConfig,
        levels: Vec<f64>,
        regions: Vec<Region>,
        obstacles: Vec<Obstacle>,
        route: Vec<[f64; 2]>,
    ) -> Self {
        Self {
            config,
            levels,
            regions,
            obstacles,
            blocks: Vec::new(),
            walkers: Vec::new(),
            surfaces: Vec::new(),
            corners: Vec::new(),
            lights: Vec::new(),
            route,
        }
    }

    /// The floor height under `(x, y)`, or `None` outside the free space.
    pub fn floor_height(&self, x: f64, y: f64) -> Option<f64> {
        self.regions.iter().find(|r| r.contains(x, y)).map(|r| r.floor_height(x, y))
    }

    /// The region under `(x, y)`.
    pub fn region_at(&self, x: f64, y: f64) -> Option<&Region> {
        self.regions.iter().find(|r| r.contains(x, y))
    }

    /// The ceiling height over `(x, y)` in region `r`.
    pub fn ceiling_of(&self, r: &Region, x: f64, y: f64) -> f64 {
        match r.ceiling_m {
            None => self.config.ceiling_height_m,
            Some(h) => r.floor_height(x, y) + h,
        }
    }

    /// The ceiling height over `(x, y)`, or `None` outside the free space.
    pub fn ceiling_height(&self, x: f64, y: f64) -> Option<f64> {
        self.region_at(x, y).map(|r| self.ceiling_of(r, x, y))
    }

    fn inside_any(&self, x: f64, y: f64) -> bool {
        self.regions.iter().any(|r| r.strictly_contains(x, y))
    }

    /// Derives the surfaces, corners and lights from the regions,
    /// obstacles and blocks.
    pub(super) fn build_surfaces_and_corners(&mut self, seed: u64) {
        let mut surfaces = self.floor_and_ceiling_surfaces(seed);
        let (walls, x_wall_ends, y_wall_ends) = self.wall_surfaces(seed);
        surfaces.extend(walls);
        let mut corners = self.wall_and_ramp_corners(&x_wall_ends, &y_wall_ends);
        self.box_surfaces_and_corners(seed, &mut surfaces, &mut corners);
        for (bi, b) in self.blocks.iter().enumerate() {
            surfaces.extend(b.surfaces(mix(seed ^ (7000 + bi as u64))));
            for c in b.corners() {
                push_corner(&mut corners, c.position, c.kind);
            }
        }

        // A light under the ceiling over the middle of each region.
        self.lights = self
            .regions
            .iter()
            .map(|r| {
                let (x, y) = ((r.x[0] + r.x[1]) / 2.0, (r.y[0] + r.y[1]) / 2.0);
                Light { position: [x, y, self.ceiling_of(r, x, y) - 0.1] }
            })
            .collect();
        self.surfaces = surfaces;
        self.corners = corners;
    }

    /// A floor (or ramp) and a ceiling for each region.
    fn floor_and_ceiling_surfaces(&self, seed: u64) -> Vec<Surface> {
        let mut surfaces = Vec::new();
        // Floors and ceilings, one per region.
        for (ri, r) in self.regions.iter().enumerate() {
            let corners = [[r.x[0], r.y[0]], [r.x[1], r.y[0]], [r.x[1], r.y[1]], [r.x[0], r.y[1]]];
            let floor: Vec<Point3> = corners.iter().map(|&[x, y]| Point3::new(x, y, r.floor_height(x, y))).collect();
            let (kind, pattern, base, u_hint) = match r.floor {
                Floor::Flat { .. } => {
                    (SurfaceKind::Floor, Pattern::Tiles { size_m: 0.6 }, [0.55, 0.52, 0.48], Vec3::x())
                }
                Floor::Ramp { axis, .. } => {
                    let u = if axis == Axis::X { Vec3::x() } else { Vec3::y() };
                    (SurfaceKind::Ramp, Pattern::Stripes { period_m: 0.3 }, [0.45, 0.47, 0.50], u)
                }
            };
            let material = Material { base, pattern, seed: mix(seed ^ (100 + ri as u64)) };
            surfaces.push(Surface::new(kind, floor, Vec3::z(), u_hint, material));
            let ceil: Vec<Point3> = corners.iter().map(|&[x, y]| Point3::new(x, y, self.ceiling_of(r, x, y))).collect();
            let material = Material { base: [0.92, 0.92, 0.90], pattern: Pattern::Panels { size_m: 1.2 }, seed: 0 };
            surfaces.push(Surface::new(SurfaceKind::Ceiling, ceil, -Vec3::z(), Vec3::x(), material));
        }
        surfaces
    }

    /// The walls (the parts of each rectangle edge with no free space
    /// outside), and the ends of those running along x and along y.
    fn wall_surfaces(&self, seed: u64) -> (Vec<Surface>, Vec<[f64; 2]>, Vec<[f64; 2]>) {
        let mut surfaces = Vec::new();
        let palette =
            [[0.85, 0.82, 0.74], [0.72, 0.80, 0.86], [0.88, 0.78, 0.70], [0.78, 0.85, 0.75], [0.90, 0.88, 0.84]];
        let pick = |k: u64| palette[(mix(seed ^ k) % palette.len() as u64) as usize];
        let mut breaks_x: Vec<f64> = self.regions.iter().flat_map(|r| r.x).collect();
        let mut breaks_y: Vec<f64> = self.regions.iter().flat_map(|r| r.y).collect();
        breaks_x.sort_by(f64::total_cmp);
        breaks_y.sort_by(f64::total_cmp);
        let mut x_wall_ends: Vec<[f64; 2]> = Vec::new();
        let mut y_wall_ends: Vec<[f64; 2]> = Vec::new();
        let mut wall_index = 0u64;
        for r in &self.regions {
            // (fixed coordinate, along-axis range, outward sign, wall runs along x?)
            let edges = [
                (r.y[0], r.x, -1.0, true),
                (r.y[1], r.x, 1.0, true),
                (r.x[0], r.y, -1.0, false),
                (r.x[1], r.y, 1.0, false),
            ];
            for (fixed, range, out, along_x) in edges {
                let breaks = if along_x { &breaks_x } else { &breaks_y };
                let mut cuts: Vec<f64> = vec![range[0]];
                cuts.extend(breaks.iter().copied().filter(|&b| b > range[0] + EPS && b < range[1] - EPS));
                cuts.push(range[1]);
                // Contiguous runs of sub-intervals with nothing outside.
                let mut runs: Vec<[f64; 2]> = Vec::new();
                for pair in cuts.windows(2) {
                    let mid = (pair[0] + pair[1]) / 2.0;
                    let probe = fixed + out * 1e-3;
                    let (px, py) = if along_x { (mid, probe) } else { (probe, mid) };
                    if self.inside_any(px, py) {
                        continue;
                    }
                    match runs.last_mut() {
                        Some(run) if (run[1] - pair[0]).abs() < EPS => run[1] = pair[1],
                        _ => runs.push([pair[0], pair[1]]),
                    }
                }
                for [a, b] in runs {
                    let at = |s: f64| if along_x { (s, fixed) } else { (fixed, s) };
                    let ((xa, ya), (xb, yb)) = (at(a), at(b));
                    let verts = vec![
                        Point3::new(xa, ya, r.floor_height(xa, ya)),
                        Point3::new(xb, yb, r.floor_height(xb, yb)),
                        Point3::new(xb, yb, self.ceiling_of(r, xb, yb)),
                        Point3::new(xa, ya, self.ceiling_of(r, xa, ya)),
                    ];
                    let inward = if along_x { Vec3::new(0.0, -out, 0.0) } else { Vec3::new(-out, 0.0, 0.0) };
                    let u_hint = if along_x { Vec3::x() } else { Vec3::y() };
                    let material = Material {
                        base: pick(wall_index),
                        pattern: Pattern::Plaster { posters: true },
                        seed: mix(seed ^ (1000 + wall_index)),
                    };
                    wall_index += 1;
                    surfaces.push(Surface::new(SurfaceKind::Wall, verts, inward, u_hint, material));
                    let ends = if along_x { &mut x_wall_ends } else { &mut y_wall_ends };
                    ends.push([xa, ya]);
                    ends.push([xb, yb]);
                }
            }
        }
        (surfaces, x_wall_ends, y_wall_ends)
    }

    /// Wall corners (where a wall along x ends on a wall along y, at floor
    /// and ceiling) and ramp ends.
    fn wall_and_ramp_corners(&self, x_wall_ends: &[[f64; 2]], y_wall_ends: &[[f64; 2]]) -> Vec<Corner> {
        let mut corners: Vec<Corner> = Vec::new();
        for p in x_wall_ends {
            if y_wall_ends.iter().any(|q| (p[0] - q[0]).abs() < EPS && (p[1] - q[1]).abs() < EPS) {
                let floor = self.floor_height(p[0], p[1]).unwrap_or(0.0);
                let ceiling = self.ceiling_height(p[0], p[1]).unwrap_or(self.config.ceiling_height_m);
                push_corner(&mut corners, [p[0], p[1], floor], CornerKind::Floor);
                push_corner(&mut corners, [p[0], p[1], ceiling], CornerKind::Ceiling);
            }
        }
        // Ramp ends: both ends of the two ramp-floor edges.
        for r in &self.regions {
            if let Floor::Ramp { axis, from, to, h0, h1 } = r.floor {
                for (c, h) in [(from, h0), (to, h1)] {
                    let across = if axis == Axis::X { r.y } else { r.x };
                    for s in across {
                        let (x, y) = if axis == Axis::X { (c, s) } else { (s, c) };
                        push_corner(&mut corners, [x, y, h], CornerKind::Ramp);
                    }
                }
            }
        }
        corners
    }

    /// Each box obstacle's four side faces and top, and its eight corners.
    fn box_surfaces_and_corners(&self, seed: u64, surfaces: &mut Vec<Surface>, corners: &mut Vec<Corner>) {
        for (bi, b) in self.obstacles.iter().enumerate() {
            let material = Material {
                base: [0.62, 0.45, 0.28],
                pattern: Pattern::Cardboard,
                seed: mix(seed ^ (5000 + bi as u64)),
            };
            let [x0, x1] = b.x;
            let [y0, y1] = b.y;
            let [z0, z1] = b.z;
            let quad = |a: [f64; 2], c: [f64; 2]| {
                vec![
                    Point3::new(a[0], a[1], z0),
                    Point3::new(c[0], c[1], z0),
                    Point3::new(c[0], c[1], z1),
                    Point3::new(a[0], a[1], z1),
                ]
            };
            surfaces.push(Surface::new(
                SurfaceKind::BoxSide,
                quad([x0, y0], [x1, y0]),
                -Vec3::y(),
                Vec3::x(),
                material,
            ));
            surfaces.push(Surface::new(SurfaceKind::BoxSide, quad([x1, y0], [x1, y1]), Vec3::x(), Vec3::y(), material));
            surfaces.push(Surface::new(SurfaceKind::BoxSide, quad([x1, y1], [x0, y1]), Vec3::y(), Vec3::x(), material));
            surfaces.push(Surface::new(
                SurfaceKind::BoxSide,
                quad([x0, y1], [x0, y0]),
                -Vec3::x(),
                Vec3::y(),
                material,
            ));
            let top = vec![
                Point3::new(x0, y0, z1),
                Point3::new(x1, y0, z1),
                Point3::new(x1, y1, z1),
                Point3::new(x0, y1, z1),
            ];
            surfaces.push(Surface::new(SurfaceKind::BoxTop, top, Vec3::z(), Vec3::x(), material));
            for x in b.x {
                for y in b.y {
                    push_corner(corners, [x, y, z1], CornerKind::BoxTop);
                    push_corner(corners, [x, y, z0], CornerKind::BoxBottom);
                }
            }
        }
    }
}

/// Adds a corner unless one is already there.
fn push_corner(corners: &mut Vec<Corner>, p: [f64; 3], kind: CornerKind) {
    let dup = corners.iter().any(|c| (0..3).all(|k| (c.position[k] - p[k]).abs() < 1e-6));
    if !dup {
        corners.push(Corner { position: p, kind });
    }
}
