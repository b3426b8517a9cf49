//! Upright prisms on a rotated rectangular footprint: the pillars, angled
//! partitions, furniture, crates and glass panes of a generated building.
//! Each kind says which of its corners are landmarks (where three planes
//! meet: floor or ceiling and two faces, or three faces of a crate or a
//! closed shelf) and which are clutter a detector must ignore (tables and
//! chairs, whose thin tops and legs meet no third plane, and glass).

use serde::Serialize;

use super::layout::{Corner, CornerKind};
use super::surface::{Material, Pattern, Surface, SurfaceKind};
use crate::math::{Point3, Vec3};

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum BlockKind {
    /// Floor to ceiling; its vertical edges make floor and ceiling corners.
    Pillar,
    /// A thin wall floor to ceiling at any angle.
    Partition,
    /// A glass pane floor to ceiling: the LIDAR partly passes, the camera sees through.
    Glass,
    /// A box on the floor, labelled like the paper building's obstacles.
    Crate,
    /// A table top on four legs.
    Table,
    /// A seat on four legs with a back rest.
    Chair,
    /// A tall closed shelf: a box like a crate, so its corners are box corners
    /// (a corner the detector sees but is told is background teaches it to
    /// miss crates).
    Shelf,
}

/// A block: footprint centre, half extents along its own axes, yaw of its
/// first axis from world x, and the height range it spans.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Block {
    pub kind: BlockKind,
    pub centre: [f64; 2],
    pub half: [f64; 2],
    pub yaw: f64,
    pub z: [f64; 2],
}

impl Block {
    /// A point of the footprint frame (along, across) in world x, y.
    fn point_at(&self, a: f64, b: f64) -> [f64; 2] {
        let (s, c) = self.yaw.sin_cos();
        [self.centre[0] + c * a - s * b, self.centre[1] + s * a + c * b]
    }

    /// The footprint's corners, counter-clockwise seen from above.
    pub fn footprint(&self) -> [[f64; 2]; 4] {
        let [a, b] = self.half;
        [self.point_at(-a, -b), self.point_at(a, -b), self.point_at(a, b), self.point_at(-a, b)]
    }

    /// Horizontal distance from `p` to the footprint (0 inside).
    pub fn distance(&self, p: [f64; 2]) -> f64 {
        let (s, c) = self.yaw.sin_cos();
        let (dx, dy) = (p[0] - self.centre[0], p[1] - self.centre[1]);
        let (a, b) = (c * dx + s * dy, -s * dx + c * dy);
        let ea = (a.abs() - self.half[0]).max(0.0);
        let eb = (b.abs() - self.half[1]).max(0.0);
        ea.hypot(eb)
    }

    /// Radius of the circle around the centre that holds the footprint.
    pub fn radius(&self) -> f64 {
        self.half[0].hypot(self.half[1])
    }

    /// The block's faces.
    pub fn surfaces(&self, seed: u64) -> Vec<Surface> {
        match self.kind {
            BlockKind::Glass => {
                let [p, q] = [self.point_at(-self.half[0], 0.0), self.point_at(self.half[0], 0.0)];
                let [z0, z1] = self.z;
                let verts = vec![
                    Point3::new(p[0], p[1], z0),
                    Point3::new(q[0], q[1], z0),
                    Point3::new(q[0], q[1], z1),
                    Point3::new(p[0], p[1], z1),
                ];
                let (s, c) = self.yaw.sin_cos();
                let material = Material { base: [0.75, 0.85, 0.85], pattern: Pattern::Glass, seed };
                vec![Surface::new(SurfaceKind::Glass, verts, Vec3::new(-s, c, 0.0), Vec3::new(c, s, 0.0), material)]
            }
            BlockKind::Pillar | BlockKind::Partition => {
                let material =
                    Material { base: [0.86, 0.84, 0.80], pattern: Pattern::Plaster { posters: false }, seed };
                prism(&self.footprint(), self.z, SurfaceKind::Wall, material, false)
            }
            BlockKind::Crate => {
                let material = Material { base: [0.62, 0.45, 0.28], pattern: Pattern::Cardboard, seed };
                let mut faces = prism(&self.footprint(), self.z, SurfaceKind::BoxSide, material, false);
                if let Some(top) = faces.last_mut() {
                    top.kind = SurfaceKind::BoxTop;
                }
                faces
            }
            BlockKind::Shelf => {
                let material = Material { base: [0.55, 0.38, 0.22], pattern: Pattern::Wood, seed };
                prism(&self.footprint(), self.z, SurfaceKind::Furniture, material, false)
            }
            BlockKind::Table | BlockKind::Chair => self.furniture_surfaces(seed),
        }
    }

    /// A top (a seat) on four legs, and a chair's back rest.
    fn furniture_surfaces(&self, seed: u64) -> Vec<Surface> {
        let material = Material { base: [0.60, 0.42, 0.25], pattern: Pattern::Wood, seed };
        let [z0, z1] = self.z;
        let [a, b] = self.half;
        let seat = if self.kind == BlockKind::Chair { z0 + 0.45 } else { z1 };
        let thickness = 0.04;
        let part = |ca: f64, cb: f64, ha: f64, hb: f64, z: [f64; 2]| -> Vec<Surface> {
            let sub = Block { centre: self.point_at(ca, cb), half: [ha, hb], z, ..*self };
            prism(&sub.footprint(), z, SurfaceKind::Furniture, material, true)
        };
        let mut faces = part(0.0, 0.0, a, b, [seat - thickness, seat]);
        let leg = 0.025;
        for (sa, sb) in [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)] {
            faces.extend(part(sa * (a - leg), sb * (b - leg), leg, leg, [z0, seat - thickness]));
        }
        if self.kind == BlockKind::Chair {
            faces.extend(part(-a + 0.02, 0.0, 0.02, b, [seat, z1]));
        }
        faces
    }

    /// The block's landmark corners.
    pub fn corners(&self) -> Vec<Corner> {
        let kinds = match self.kind {
            BlockKind::Pillar | BlockKind::Partition => [CornerKind::Floor, CornerKind::Ceiling],
            BlockKind::Crate | BlockKind::Shelf => [CornerKind::BoxBottom, CornerKind::BoxTop],
            _ => return Vec::new(),
        };
        let mut corners = Vec::new();
        for [x, y] in self.footprint() {
            corners.push(Corner { position: [x, y, self.z[0]], kind: kinds[0] });
            corners.push(Corner { position: [x, y, self.z[1]], kind: kinds[1] });
        }
        corners
    }
}

/// The four sides and the top of an upright prism over `footprint`
/// (counter-clockwise), and its bottom when it floats (`bottom`).
fn prism(footprint: &[[f64; 2]; 4], z: [f64; 2], kind: SurfaceKind, material: Material, bottom: bool) -> Vec<Surface> {
    let [z0, z1] = z;
    let centre = footprint.iter().fold([0.0, 0.0], |acc, p| [acc[0] + p[0] / 4.0, acc[1] + p[1] / 4.0]);
    let mut faces = Vec::with_capacity(6);
    for i in 0..4 {
        let (p, q) = (footprint[i], footprint[(i + 1) % 4]);
        let verts = vec![
            Point3::new(p[0], p[1], z0),
            Point3::new(q[0], q[1], z0),
            Point3::new(q[0], q[1], z1),
            Point3::new(p[0], p[1], z1),
        ];
        let mid = [(p[0] + q[0]) / 2.0, (p[1] + q[1]) / 2.0];
        let outward = Vec3::new(mid[0] - centre[0], mid[1] - centre[1], 0.0);
        let along = Vec3::new(q[0] - p[0], q[1] - p[1], 0.0);
        faces.push(Surface::new(kind, verts, outward, along, material));
    }
    let at = |h: f64| footprint.iter().map(|p| Point3::new(p[0], p[1], h)).collect::<Vec<_>>();
    let along = Vec3::new(footprint[1][0] - footprint[0][0], footprint[1][1] - footprint[0][1], 0.0);
    if bottom {
        faces.insert(0, Surface::new(kind, at(z0), -Vec3::z(), along, material));
    }
    faces.push(Surface::new(kind, at(z1), Vec3::z(), along, material));
    faces
}
