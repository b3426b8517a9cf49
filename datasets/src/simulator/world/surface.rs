//! A planar convex polygon of the world (a floor, a wall, a box face...) and
//! its ray intersection.

use serde::Serialize;

use crate::math::{Point3, Vec3};

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum SurfaceKind {
    Floor,
    Ramp,
    Wall,
    Ceiling,
    BoxSide,
    BoxTop,
    /// Tables, chairs, shelves: clutter, never landmarks.
    Furniture,
    /// Seen through by the camera, partly passed by the LIDAR.
    Glass,
}

/// How a surface looks: a base colour (linear RGB, 0..1) and a pattern.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Material {
    pub base: [f32; 3],
    pub pattern: Pattern,
    /// Varies the pattern (poster places, tile shades) between surfaces.
    pub seed: u64,
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Pattern {
    /// Square tiles with dark grout lines.
    Tiles { size_m: f64 },
    /// Painted plaster with faint mottling and a few posters.
    Plaster { posters: bool },
    /// Ceiling panels.
    Panels { size_m: f64 },
    /// Anti-slip stripes across a ramp.
    Stripes { period_m: f64 },
    /// Cardboard with a band of tape.
    Cardboard,
    /// Wood grain along u.
    Wood,
    /// Clear glass: a faint tint over what lies behind.
    Glass,
}

#[derive(Debug, Clone)]
pub struct Surface {
    pub kind: SurfaceKind,
    /// Unit normal, pointing to the side the surface is seen from.
    pub normal: Vec3,
    /// The plane is `normal . p = offset`.
    pub offset: f64,
    /// Convex, counter-clockwise seen from the normal's side.
    pub vertices: Vec<Point3>,
    /// In-plane texture axes (metres): `u` horizontal where possible.
    pub u_axis: Vec3,
    pub v_axis: Vec3,
    pub material: Material,
    /// Inward edge half-spaces `m . p >= c`, one per edge.
    edges: Vec<(Vec3, f64)>,
}

impl Surface {
    /// Builds a surface from convex vertices in either winding; `facing` says
    /// which side it is seen from, `u_hint` the preferred texture u axis.
    pub fn new(kind: SurfaceKind, mut vertices: Vec<Point3>, facing: Vec3, u_hint: Vec3, material: Material) -> Self {
        // Newell's normal of the polygon.
        let mut n = Vec3::zeros();
        for i in 0..vertices.len() {
            let (a, b) = (vertices[i], vertices[(i + 1) % vertices.len()]);
            n += Vec3::new((a.y - b.y) * (a.z + b.z), (a.z - b.z) * (a.x + b.x), (a.x - b.x) * (a.y + b.y));
        }
        let mut normal = n.normalize();
        if normal.dot(&facing) < 0.0 {
            vertices.reverse();
            normal = -normal;
        }
        let offset = normal.dot(&vertices[0].coords);
        let edges = (0..vertices.len())
            .map(|i| {
                let (a, b) = (vertices[i], vertices[(i + 1) % vertices.len()]);
                let m = normal.cross(&(b - a));
                // A hair of tolerance so that rays through shared edges hit.
                (m, m.dot(&a.coords) - 1e-9 * m.norm())
            })
            .collect();
        let u = (u_hint - normal * normal.dot(&u_hint)).normalize();
        let v = normal.cross(&u);
        Self { kind, normal, offset, vertices, u_axis: u, v_axis: v, material, edges }
    }

    /// Distance `t` along `dir` from `origin` to this surface, if the ray
    /// meets the polygon within `(t_min, t_max)`. Both sides count.
    pub fn intersect(&self, origin: &Point3, dir: &Vec3, t_min: f64, t_max: f64) -> Option<f64> {
        let denom = self.normal.dot(dir);
        if denom.abs() < 1e-12 {
            return None;
        }
        let t = (self.offset - self.normal.dot(&origin.coords)) / denom;
        if !(t > t_min && t < t_max) {
            return None;
        }
        let p = origin.coords + dir * t;
        let inside = self.edges.iter().all(|(m, c)| m.dot(&p) >= *c);
        inside.then_some(t)
    }

    /// Signed distance of a point to the plane.
    pub fn plane_distance(&self, p: &Point3) -> f64 {
        self.normal.dot(&p.coords) - self.offset
    }

    /// Whether a point on (or near) the plane lies within the polygon,
    /// allowing `margin_m` outside its edges.
    pub fn contains_projection(&self, p: &Point3, margin_m: f64) -> bool {
        self.edges.iter().all(|(m, c)| m.dot(&p.coords) >= c - margin_m * m.norm())
    }

    pub fn bounds(&self) -> (Point3, Point3) {
        let mut lo = self.vertices[0];
        let mut hi = self.vertices[0];
        for v in &self.vertices {
            lo = lo.inf(v);
            hi = hi.sup(v);
        }
        (lo, hi)
    }
}
