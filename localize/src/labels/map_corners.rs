//! Corners of the point map a run built: where two vertical surfaces (walls,
//! the sides of a box) meet along a vertical edge, and a horizontal surface
//! (the floor, a box's top) meets that edge. A single scan sees few corners
//! whole; the map, gathered from every pose along the route, holds the
//! surfaces around many more.
//!
//! Each pair of nearby vertical surfels at an angle votes for the point
//! where their planes cross (seen from above); the votes pile up on the
//! edges. Each edge then takes the heights of the horizontal surfels around
//! it that its own vertical surfels reach.

use std::collections::HashMap;

use datasets::InvalidSetting;
use datasets::math::Vec3;
use serde::{Deserialize, Serialize};

use crate::estimation::point_map::MapPoint;

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MapCornerConfig {
    /// Find corners in the map at all (besides those followed over the
    /// scans). Off by default: on the generated buildings it doubles the
    /// labels' recall but furniture (chairs, tables) costs most of their
    /// precision (docs/autolabel.md).
    pub enabled: bool,
    /// Two vertical surfels this close (horizontally), at least
    /// `min_angle_deg` apart, vote for the edge where their planes cross,
    /// when it lies within `pair_radius_m` of both.
    pub pair_radius_m: f64,
    pub min_angle_deg: f64,
    /// Votes an edge needs, in a cell of `cell_m` and its neighbours.
    pub min_votes: usize,
    pub cell_m: f64,
    /// Horizontal surfels within this distance of an edge give its corners'
    /// heights; each height needs `min_horizontal` of them.
    pub horizontal_radius_m: f64,
    pub min_horizontal: usize,
    /// A corner's height must lie within this of the height span of the
    /// edge's own vertical surfels.
    pub height_slack_m: f64,
}

impl Default for MapCornerConfig {
    fn default() -> Self {
        Self {
            enabled: false,
            pair_radius_m: 0.4,
            min_angle_deg: 45.0,
            min_votes: 12,
            cell_m: 0.05,
            horizontal_radius_m: 0.5,
            min_horizontal: 3,
            height_slack_m: 0.25,
        }
    }
}

impl MapCornerConfig {
    pub fn validate(&self) -> Result<(), InvalidSetting> {
        InvalidSetting::range("pair_radius_m", self.pair_radius_m, 0.05, 3.0, false)?;
        InvalidSetting::range("min_angle_deg", self.min_angle_deg, 10.0, 90.0, false)?;
        InvalidSetting::count("min_votes", self.min_votes, 1, 1_000_000)?;
        InvalidSetting::range("cell_m", self.cell_m, 0.005, 0.5, false)?;
        InvalidSetting::range("horizontal_radius_m", self.horizontal_radius_m, 0.05, 3.0, false)?;
        InvalidSetting::count("min_horizontal", self.min_horizontal, 1, 1_000_000)?;
        InvalidSetting::non_negative("height_slack_m", self.height_slack_m, 3.0)?;
        Ok(())
    }
}

/// A corner of the map, with how well its position is known.
#[derive(Debug, Clone, PartialEq)]
pub struct MapCorner {
    pub position: Vec3,
    /// Standard error of the edge's position (RMS spread of its votes over
    /// the square root of their number).
    pub sigma_m: f64,
    pub votes: usize,
}

/// Cell of a 2D grid of edge `size`.
fn cell2(x: f64, y: f64, size: f64) -> [i64; 2] {
    [(x / size).floor() as i64, (y / size).floor() as i64]
}

/// A vertical edge: where it is, and the heights its surfels span.
struct Edge {
    xy: [f64; 2],
    sigma_m: f64,
    votes: usize,
    z_span: [f64; 2],
}

pub fn map_corners(points: &[MapPoint], config: &MapCornerConfig) -> Vec<MapCorner> {
    let vertical: Vec<&MapPoint> = points.iter().filter(|p| p.normal.z.abs() < 0.2).collect();
    let horizontal: Vec<&MapPoint> = points.iter().filter(|p| p.normal.z.abs() > 0.9).collect();
    let edges = vertical_edges(&vertical, config);
    // Horizontal surfels by 2D cell, for the heights around each edge.
    let r = config.horizontal_radius_m;
    let mut grid: HashMap<[i64; 2], Vec<usize>> = HashMap::new();
    for (k, p) in horizontal.iter().enumerate() {
        grid.entry(cell2(p.position.x, p.position.y, r)).or_default().push(k);
    }
    let mut corners = Vec::new();
    for edge in edges {
        let [cx, cy] = cell2(edge.xy[0], edge.xy[1], r);
        let mut heights: Vec<f64> = Vec::new();
        for dx in -1..=1 {
            for dy in -1..=1 {
                for &k in grid.get(&[cx + dx, cy + dy]).into_iter().flatten() {
                    let p = horizontal[k].position;
                    let near = (p.x - edge.xy[0]).hypot(p.y - edge.xy[1]) <= r;
                    let reached =
                        p.z >= edge.z_span[0] - config.height_slack_m && p.z <= edge.z_span[1] + config.height_slack_m;
                    if near && reached {
                        heights.push(p.z);
                    }
                }
            }
        }
        for z in height_clusters(heights, 0.05, config.min_horizontal) {
            corners.push(MapCorner {
                position: Vec3::new(edge.xy[0], edge.xy[1], z),
                sigma_m: edge.sigma_m,
                votes: edge.votes,
            });
        }
    }
    corners
}

/// Heights that at least `min` values share within `gap` of each other: the
/// mean of each such run of sorted values.
fn height_clusters(mut values: Vec<f64>, gap: f64, min: usize) -> Vec<f64> {
    values.sort_by(f64::total_cmp);
    let mut out = Vec::new();
    let mut start = 0;
    for k in 1..=values.len() {
        if k == values.len() || values[k] - values[k - 1] > gap {
            let run = &values[start..k];
            if run.len() >= min {
                out.push(run.iter().sum::<f64>() / run.len() as f64);
            }
            start = k;
        }
    }
    out
}

/// A pair's vote: where its planes cross, seen from above, and the
/// directions (azimuths) of its two normals.
#[derive(Clone, Copy)]
struct Vote {
    xy: [f64; 2],
    normals: [f64; 2],
}

/// The angle between two directions, ignoring their sign (0..pi/2).
fn axis_gap(a: f64, b: f64) -> f64 {
    let d = (a - b).rem_euclid(std::f64::consts::PI);
    d.min(std::f64::consts::PI - d)
}

/// The mean direction of azimuths that agree up to their sign.
fn circular_mean(angles: &[f64]) -> f64 {
    // Doubled angles make a direction and its opposite one.
    let (s, c) = angles.iter().fold((0.0, 0.0), |(s, c), a| (s + (2.0 * a).sin(), c + (2.0 * a).cos()));
    s.atan2(c) / 2.0
}

/// The height span of the face through `xy` whose normal has azimuth
/// `normal`, from the vertical surfels on it within 1.5 m of the edge;
/// `None` unless it runs at least 0.5 m along the wall and 0.4 m up.
fn face_extent(vertical: &[&MapPoint], xy: [f64; 2], normal: f64, config: &MapCornerConfig) -> Option<[f64; 2]> {
    let (n, t) = ([normal.cos(), normal.sin()], [-normal.sin(), normal.cos()]);
    let (mut along, mut z) = ([f64::INFINITY, f64::NEG_INFINITY], [f64::INFINITY, f64::NEG_INFINITY]);
    for p in vertical {
        let d = [p.position.x - xy[0], p.position.y - xy[1]];
        let off = d[0] * n[0] + d[1] * n[1];
        let s = d[0] * t[0] + d[1] * t[1];
        if off.abs() > 0.04 || s.abs() > 1.5 || axis_gap(p.normal.y.atan2(p.normal.x), normal) > 0.35 {
            continue;
        }
        along = [along[0].min(s), along[1].max(s)];
        z = [z[0].min(p.position.z), z[1].max(p.position.z)];
    }
    let reaches_edge = along[0] <= config.pair_radius_m && along[1] >= -config.pair_radius_m;
    (along[1] - along[0] >= 0.5 && z[1] - z[0] >= 0.4 && reaches_edge).then_some(z)
}

/// The vertical edges the pairs of vertical surfels vote for.
/// Every pair of vertical surfels within the pair radius whose planes cross
/// at an angle votes, in the cell of the crossing point (seen from above),
/// for an edge there: the crossing and the two planes' directions.
fn edge_votes(vertical: &[&MapPoint], config: &MapCornerConfig) -> HashMap<[i64; 2], Vec<Vote>> {
    let r = config.pair_radius_m;
    let mut grid: HashMap<[i64; 2], Vec<usize>> = HashMap::new();
    for (k, p) in vertical.iter().enumerate() {
        grid.entry(cell2(p.position.x, p.position.y, r)).or_default().push(k);
    }
    let min_sin = config.min_angle_deg.to_radians().sin();
    let mut votes: HashMap<[i64; 2], Vec<Vote>> = HashMap::new();
    for (i, a) in vertical.iter().enumerate() {
        let [cx, cy] = cell2(a.position.x, a.position.y, r);
        let na = [a.normal.x, a.normal.y];
        let la = na[0].hypot(na[1]);
        for dx in -1..=1 {
            for dy in -1..=1 {
                for &j in grid.get(&[cx + dx, cy + dy]).into_iter().flatten() {
                    if j <= i {
                        continue;
                    }
                    let b = vertical[j];
                    let nb = [b.normal.x, b.normal.y];
                    let lb = nb[0].hypot(nb[1]);
                    // The sine of the angle between the two planes (seen from above).
                    let det = na[0] * nb[1] - na[1] * nb[0];
                    if det.abs() < min_sin * la * lb {
                        continue;
                    }
                    let da = na[0] * a.position.x + na[1] * a.position.y;
                    let db = nb[0] * b.position.x + nb[1] * b.position.y;
                    let x = (da * nb[1] - db * na[1]) / det;
                    let y = (na[0] * db - nb[0] * da) / det;
                    let from = |p: &MapPoint| (p.position.x - x).hypot(p.position.y - y);
                    if from(a) > r || from(b) > r {
                        continue;
                    }
                    votes
                        .entry(cell2(x, y, config.cell_m))
                        .or_default()
                        .push(Vote { xy: [x, y], normals: [na[1].atan2(na[0]), nb[1].atan2(nb[0])] });
                }
            }
        }
    }
    votes
}

fn vertical_edges(vertical: &[&MapPoint], config: &MapCornerConfig) -> Vec<Edge> {
    let r = config.pair_radius_m;
    let votes = edge_votes(vertical, config);
    // Peaks: a cell whose 3 x 3 neighbourhood holds the most votes around it
    // (within the pair radius) and at least `min_votes`.
    let around = |c: [i64; 2]| -> Vec<Vote> {
        let mut all = Vec::new();
        for dx in -1..=1 {
            for dy in -1..=1 {
                all.extend(votes.get(&[c[0] + dx, c[1] + dy]).into_iter().flatten().copied());
            }
        }
        all
    };
    let mut peaks: Vec<(usize, [i64; 2])> =
        votes.keys().map(|&c| (around(c).len(), c)).filter(|&(n, _)| n >= config.min_votes).collect();
    peaks.sort_by(|a, b| b.0.cmp(&a.0).then(a.1.cmp(&b.1)));
    let mut edges: Vec<Edge> = Vec::new();
    for (n, c) in peaks {
        let near = around(c);
        let mean = near.iter().fold([0.0, 0.0], |s, v| [s[0] + v.xy[0], s[1] + v.xy[1]]);
        let xy = [mean[0] / n as f64, mean[1] / n as f64];
        if edges.iter().any(|e| (e.xy[0] - xy[0]).hypot(e.xy[1] - xy[1]) < r) {
            continue;
        }
        // Both faces must be surfaces, not a chair's back or a table's leg.
        // The votes' normals fall in two groups, one per face (in either order within a vote).
        let all: Vec<f64> = near.iter().flat_map(|v| v.normals).collect();
        let (a, rest): (Vec<f64>, Vec<f64>) = all.iter().partition(|x| axis_gap(**x, all[0]) < 0.35);
        let b: Vec<f64> =
            rest.iter().copied().filter(|x| axis_gap(*x, rest.first().copied().unwrap_or(0.0)) < 0.35).collect();
        if b.is_empty() {
            continue;
        }
        let faces = [a, b].map(|group| face_extent(vertical, xy, circular_mean(&group), config));
        let Some(z_span) = faces[0].zip(faces[1]).map(|(a, b)| [a[0].min(b[0]), a[1].max(b[1])]) else { continue };
        let spread =
            (near.iter().map(|v| (v.xy[0] - xy[0]).powi(2) + (v.xy[1] - xy[1]).powi(2)).sum::<f64>() / n as f64).sqrt();
        edges.push(Edge { xy, sigma_m: spread / (n as f64).sqrt(), votes: n, z_span });
    }
    edges
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Surfels every 10 cm on the plane x = `x` (y in `ys`, z in `zs`), normal -x.
    fn wall_x(x: f64, ys: (f64, f64), zs: (f64, f64)) -> Vec<MapPoint> {
        grid(ys, zs).into_iter().map(|(y, z)| MapPoint { position: Vec3::new(x, y, z), normal: -Vec3::x() }).collect()
    }

    fn wall_y(y: f64, xs: (f64, f64), zs: (f64, f64)) -> Vec<MapPoint> {
        grid(xs, zs).into_iter().map(|(x, z)| MapPoint { position: Vec3::new(x, y, z), normal: -Vec3::y() }).collect()
    }

    fn floor(z: f64, xs: (f64, f64), ys: (f64, f64)) -> Vec<MapPoint> {
        grid(xs, ys).into_iter().map(|(x, y)| MapPoint { position: Vec3::new(x, y, z), normal: Vec3::z() }).collect()
    }

    fn grid(a: (f64, f64), b: (f64, f64)) -> Vec<(f64, f64)> {
        let steps = |(lo, hi): (f64, f64)| ((hi - lo) / 0.1).round() as i32;
        (0..=steps(a)).flat_map(|i| (0..=steps(b)).map(move |j| (a.0 + 0.1 * i as f64, b.0 + 0.1 * j as f64))).collect()
    }

    #[test]
    fn two_walls_and_a_floor_give_the_corner_where_they_meet_and_a_lone_wall_none() {
        // A room's corner at (4, 3, 0): walls x = 4 and y = 3 seen up to 2 m,
        // the floor in front of them; a lone wall elsewhere.
        let mut points = wall_x(4.0, (1.0, 3.0), (0.0, 2.0));
        points.extend(wall_y(3.0, (2.0, 4.0), (0.0, 2.0)));
        points.extend(floor(0.0, (2.0, 3.9), (1.0, 2.9)));
        points.extend(wall_x(-5.0, (-2.0, 2.0), (0.0, 2.0)));
        points.extend(floor(0.0, (-4.9, -3.0), (-2.0, 2.0)));
        let corners = map_corners(&points, &MapCornerConfig::default());
        assert_eq!(corners.len(), 1, "{corners:?}");
        let c = &corners[0];
        assert!((c.position - Vec3::new(4.0, 3.0, 0.0)).norm() < 0.02, "{c:?}");
        assert!(c.votes >= 12 && c.sigma_m < 0.01, "{c:?}");
    }

    #[test]
    fn a_box_gives_its_bottom_and_top_corners_but_not_the_ceiling_its_sides_never_reach() {
        // A box 1 m on a side at x, y in [2, 3], 0.6 m high: two of its sides
        // seen, the floor around it, its top; a ceiling at 3 m far above.
        let mut points = wall_x(2.0, (2.0, 3.0), (0.0, 0.6));
        points.extend(wall_y(2.0, (2.0, 3.0), (0.0, 0.6)));
        points.extend(floor(0.0, (1.0, 1.9), (1.0, 3.0)));
        points.extend(floor(0.0, (2.0, 3.0), (1.0, 1.9)));
        points.extend(floor(0.6, (2.0, 3.0), (2.0, 3.0)));
        points.extend(floor(3.0, (1.0, 3.0), (1.0, 3.0)));
        let mut corners = map_corners(&points, &MapCornerConfig::default());
        corners.sort_by(|a, b| a.position.z.total_cmp(&b.position.z));
        assert_eq!(corners.len(), 2, "{corners:?}");
        assert!((corners[0].position - Vec3::new(2.0, 2.0, 0.0)).norm() < 0.02, "{corners:?}");
        assert!((corners[1].position - Vec3::new(2.0, 2.0, 0.6)).norm() < 0.02, "{corners:?}");
    }

    #[test]
    fn heights_cluster_by_gaps() {
        assert_eq!(height_clusters(vec![0.0, 0.01, 0.02, 1.0, 1.01, 2.0], 0.05, 2), vec![0.01, 1.005]);
        assert!(height_clusters(vec![0.0, 0.5], 0.05, 2).is_empty());
    }
}
