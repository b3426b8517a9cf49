//! Planes by Hough voting on normals: each point's normal and offset become
//! (theta, phi, rho) and vote into an accumulator; the strongest cell seeds a
//! plane whose inliers are refit by least squares and leave the vote; near
//! duplicates are merged at the end.
//!
//! The accumulator is a "ball": rings of equal polar angle phi hold a number
//! of theta cells proportional to sin(phi), so that every cell covers about
//! the same solid angle. A plain theta x phi grid would spread the floor's
//! votes (phi near 0, theta undefined) over a whole row of cells.

use datasets::InvalidSetting;
use datasets::math::{Mat3, Vec3};
use nalgebra::Point3;
use rayon::prelude::*;
use rustc_hash::FxHashMap;
use serde::{Deserialize, Serialize};

use crate::error::Result;
use crate::scan::normals::{PointNormal, smallest_eigenvector};

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PlaneConfig {
    /// Angular size of an accumulator cell (theta and phi).
    pub angle_bin_deg: f64,
    /// Offset size of an accumulator cell.
    pub distance_bin_m: f64,
    /// Points whose neighbourhood is less planar than this do not vote.
    pub max_curvature: f64,
    /// A cell must hold this many votes to seed a plane.
    pub min_votes: usize,
    /// A plane must gather this many inliers to be kept.
    pub min_inliers: usize,
    /// Inlier: point-to-plane distance below this...
    pub inlier_distance_m: f64,
    /// ...and normal within this angle of the plane's.
    pub inlier_angle_deg: f64,
    /// Planes closer than this in angle and offset are merged.
    pub merge_angle_deg: f64,
    pub merge_distance_m: f64,
    pub max_planes: usize,
}

impl Default for PlaneConfig {
    fn default() -> Self {
        Self {
            angle_bin_deg: 2.0,
            distance_bin_m: 0.05,
            max_curvature: 0.1,
            min_votes: 60,
            min_inliers: 80,
            inlier_distance_m: 0.08,
            inlier_angle_deg: 15.0,
            merge_angle_deg: 3.0,
            merge_distance_m: 0.06,
            max_planes: 60,
        }
    }
}

impl PlaneConfig {
    /// The extractor's own limits (stricter than `LocalizeConfig::validate`'s
    /// ranges for the histogram bin).
    pub fn validate(&self) -> std::result::Result<(), InvalidSetting> {
        let field = |name: &str, problem: String| Err(InvalidSetting::field(format!("planes.{name}"), problem));
        if !(self.angle_bin_deg > 0.05 && self.angle_bin_deg <= 30.0) {
            return field("angle_bin_deg", format!("{} deg outside (0.05, 30]", self.angle_bin_deg));
        }
        if !(self.distance_bin_m > 0.0) {
            return field("distance_bin_m", format!("{} m must be > 0", self.distance_bin_m));
        }
        if !(self.inlier_distance_m > 0.0) {
            return field("inlier_distance_m", format!("{} m must be > 0", self.inlier_distance_m));
        }
        if !(self.inlier_angle_deg > 0.0 && self.inlier_angle_deg < 90.0) {
            return field("inlier_angle_deg", format!("{} deg outside (0, 90)", self.inlier_angle_deg));
        }
        if self.min_votes == 0 {
            return field("min_votes", "must be at least 1".into());
        }
        if self.min_inliers < 3 {
            return field("min_inliers", format!("{} is fewer than the 3 a plane needs", self.min_inliers));
        }
        Ok(())
    }
}

/// The points p with normal . p = distance (unit normal, distance >= 0).
#[derive(Debug, Clone, PartialEq)]
pub struct Plane {
    pub normal: Vec3,
    pub distance: f64,
    pub centroid: Vec3,
    /// Indices of the points of the plane.
    pub inliers: Vec<u32>,
    /// RMS point-to-plane distance of the inliers.
    pub rms_m: f64,
}

impl Plane {
    pub fn signed_distance(&self, p: &Vec3) -> f64 {
        self.normal.dot(p) - self.distance
    }
    /// Angle between two planes' normals, ignoring their sign (0..90 deg).
    pub fn angle_deg(&self, other: &Plane) -> f64 {
        self.normal.dot(&other.normal).abs().min(1.0).acos().to_degrees()
    }
}

/// The planes of a cloud and, per point, the plane it belongs to.
#[derive(Debug, Clone, Default)]
pub struct PlaneSet {
    pub planes: Vec<Plane>,
    pub labels: Vec<Option<u16>>,
}

/// The accumulator's live vote counts: each cell's own (points not yet
/// taken by a plane) and the sum over its neighbourhood, kept up to date as
/// planes take points instead of recounted for every plane.
struct VoteCounts {
    /// Each cell's neighbourhood (sorted keys, the cell included), only cells that hold votes.
    neighbours: FxHashMap<u64, Vec<u64>>,
    /// The cells whose neighbourhood holds a given cell.
    neighbour_of: FxHashMap<u64, Vec<u64>>,
    own: FxHashMap<u64, usize>,
    smoothed: FxHashMap<u64, usize>,
}

impl VoteCounts {
    fn new(ball: &Ball, cells: &FxHashMap<u64, Vec<u32>>) -> Self {
        let mut neighbours = FxHashMap::default();
        let mut neighbour_of: FxHashMap<u64, Vec<u64>> = FxHashMap::default();
        let mut smoothed = FxHashMap::default();
        for &key in cells.keys() {
            let near: Vec<u64> = ball.neighbourhood(key).into_iter().filter(|k| cells.contains_key(k)).collect();
            for &k in &near {
                neighbour_of.entry(k).or_default().push(key);
            }
            smoothed.insert(key, near.iter().map(|k| cells[k].len()).sum());
            neighbours.insert(key, near);
        }
        let own = cells.iter().map(|(&k, v)| (k, v.len())).collect();
        Self { neighbours, neighbour_of, own, smoothed }
    }

    /// The cell with the most smoothed votes among those that still hold
    /// votes of their own and are not `exhausted`; ties go to the smaller key.
    fn strongest(&self, exhausted: &std::collections::HashSet<u64>) -> Option<(usize, u64)> {
        self.own
            .iter()
            .filter(|&(k, &n)| n > 0 && !exhausted.contains(k))
            .map(|(&k, _)| (self.smoothed[&k], std::cmp::Reverse(k)))
            .max()
            .map(|(votes, std::cmp::Reverse(k))| (votes, k))
    }

    /// Removes the votes of points now taken (one cell key per point).
    fn withdraw(&mut self, taken: impl Iterator<Item = u64>) {
        for key in taken {
            *self.own.get_mut(&key).expect("a voting cell") -= 1;
            for holder in &self.neighbour_of[&key] {
                *self.smoothed.get_mut(holder).expect("a voting cell") -= 1;
            }
        }
    }
}

pub struct PlaneExtractor {
    config: PlaneConfig,
}

/// Cell of the ball accumulator: (ring of phi, theta cell in the ring, rho cell).
struct Ball {
    bin: f64,
    rings: usize,
    thetas: Vec<u32>,
}

impl Ball {
    fn new(bin_deg: f64) -> Self {
        let bin = bin_deg.to_radians();
        let rings = (std::f64::consts::PI / bin).ceil() as usize;
        let thetas = (0..rings)
            .map(|r| {
                let phi = (r as f64 + 0.5) * bin;
                ((std::f64::consts::TAU * phi.sin() / bin).round() as u32).max(1)
            })
            .collect();
        Self { bin, rings, thetas }
    }

    fn key(&self, normal: &Vec3, rho: f64, rho_bin: f64) -> u64 {
        let phi = normal.z.clamp(-1.0, 1.0).acos();
        let ring = ((phi / self.bin) as usize).min(self.rings - 1);
        let theta = normal.y.atan2(normal.x) + std::f64::consts::PI;
        let cell = self.theta_cell(ring, theta);
        let rho_cell = ((rho / rho_bin) as u64).min(u32::MAX as u64 - 1);
        Self::pack(ring, cell, rho_cell)
    }

    fn theta_cell(&self, ring: usize, theta: f64) -> u32 {
        let cells = self.thetas[ring];
        ((theta / std::f64::consts::TAU * cells as f64) as u32).min(cells - 1)
    }

    fn pack(ring: usize, cell: u32, rho_cell: u64) -> u64 {
        (ring as u64) << 48 | (cell as u64) << 32 | rho_cell
    }

    /// The cell and its neighbours: rho +-1, theta +-1 (wrapping) in the same
    /// ring and the rings above and below (at the same theta).
    fn neighbourhood(&self, key: u64) -> Vec<u64> {
        let ring = (key >> 48) as usize;
        let cell = ((key >> 32) & 0xffff) as u32;
        let rho_cell = key & 0xffff_ffff;
        let theta = (cell as f64 + 0.5) / self.thetas[ring] as f64 * std::f64::consts::TAU;
        let mut keys = Vec::with_capacity(27);
        for r in ring.saturating_sub(1)..=(ring + 1).min(self.rings - 1) {
            let cells = self.thetas[r];
            let centre = self.theta_cell(r, theta);
            let mut thetas = vec![centre, (centre + 1) % cells, (centre + cells - 1) % cells];
            thetas.sort_unstable();
            thetas.dedup();
            for c in thetas {
                for rho in rho_cell.saturating_sub(1)..=rho_cell + 1 {
                    keys.push(Self::pack(r, c, rho));
                }
            }
        }
        keys.sort_unstable();
        keys.dedup();
        keys
    }
}

impl PlaneExtractor {
    pub fn new(config: PlaneConfig) -> Result<Self> {
        config.validate()?;
        Ok(Self { config })
    }

    pub fn extract(&self, points: &[Point3<f32>], normals: &[PointNormal]) -> PlaneSet {
        let c = &self.config;
        let at = |i: usize| points[i].cast::<f64>().coords;
        // Every normal flipped so that its plane offset is >= 0 (pointing away
        // from the origin), as the polar form needs.
        let voting: Vec<(Vec3, f64)> = normals
            .iter()
            .enumerate()
            .map(|(i, n)| {
                let rho = n.normal.dot(&at(i));
                if rho < 0.0 { (-n.normal, -rho) } else { (n.normal, rho) }
            })
            .collect();
        let ball = Ball::new(c.angle_bin_deg);
        // Each point's accumulator cell; only planar neighbourhoods vote.
        let cell_of: Vec<Option<u64>> = voting
            .iter()
            .zip(normals)
            .map(|((normal, rho), n)| {
                (n.curvature <= c.max_curvature).then(|| ball.key(normal, *rho, c.distance_bin_m))
            })
            .collect();
        let mut cells: FxHashMap<u64, Vec<u32>> = FxHashMap::default();
        for (i, key) in cell_of.iter().enumerate() {
            if let Some(key) = key {
                cells.entry(*key).or_default().push(i as u32);
            }
        }
        let mut votes = VoteCounts::new(&ball, &cells);
        let mut labels: Vec<Option<u16>> = vec![None; points.len()];
        // The points no plane has taken yet, in index order: what each
        // gathering scans (fewer and fewer as planes take them).
        let mut untaken: Vec<u32> = (0..points.len() as u32).collect();
        let mut planes: Vec<Plane> = Vec::new();
        let cos_inlier = c.inlier_angle_deg.to_radians().cos();
        let mut exhausted: std::collections::HashSet<u64> = std::collections::HashSet::new();
        while planes.len() < c.max_planes {
            // The strongest cell, counting only votes of points not yet
            // taken, smoothed over each cell's neighbourhood: a normal error
            // of a degree moves rho by several centimetres at a few metres,
            // so a plane's votes straddle cell borders.
            let Some((smoothed, key)) = votes.strongest(&exhausted) else { break };
            if smoothed < c.min_votes {
                break;
            }
            let seed: Vec<u32> = votes.neighbours[&key]
                .iter()
                .filter_map(|k| cells.get(k))
                .flatten()
                .copied()
                .filter(|&i| labels[i as usize].is_none())
                .collect();
            let inliers = gather_inliers(&seed, points, &untaken, &voting, c);
            if inliers.len() < c.min_inliers {
                exhausted.insert(key);
                continue;
            }
            let plane = make_plane(inliers, &at);
            for &i in &plane.inliers {
                labels[i as usize] = Some(planes.len() as u16);
            }
            untaken.retain(|&i| labels[i as usize].is_none());
            votes.withdraw(plane.inliers.iter().filter_map(|&i| cell_of[i as usize]));
            planes.push(plane);
        }
        merge_duplicates(&mut planes, &mut labels, c, &at);
        reassign_to_nearest(&mut planes, &mut labels, &voting, cos_inlier, &at);
        PlaneSet { planes, labels }
    }
}

/// The points of `untaken` on the plane a seed cell's points vote for. Gather,
/// refit, gather again: the seed cell's plane is only as good as one cell;
/// the refit uses every inlier.
fn gather_inliers(
    seed: &[u32],
    points: &[Point3<f32>],
    untaken: &[u32],
    voting: &[(Vec3, f64)],
    c: &PlaneConfig,
) -> Vec<u32> {
    let at = |i: usize| points[i].cast::<f64>().coords;
    let cos_inlier = c.inlier_angle_deg.to_radians().cos();
    let mut normal = seed.iter().fold(Vec3::zeros(), |a, &i| a + voting[i as usize].0).normalize();
    let mut distance = seed.iter().map(|&i| normal.dot(&at(i as usize))).sum::<f64>() / seed.len() as f64;
    let mut inliers = Vec::new();
    for _ in 0..3 {
        inliers = untaken
            .par_iter()
            .copied()
            .filter(|&i| {
                let i = i as usize;
                (normal.dot(&at(i)) - distance).abs() < c.inlier_distance_m
                    && voting[i].0.dot(&normal).abs() > cos_inlier
            })
            .collect();
        if inliers.len() < c.min_inliers {
            break;
        }
        (normal, distance) = fit_plane(&inliers, &at).0;
    }
    inliers
}

/// Least-squares plane (PCA) of some points: (unit normal, offset >= 0) and centroid.
fn fit_plane(indices: &[u32], at: &dyn Fn(usize) -> Vec3) -> ((Vec3, f64), Vec3) {
    let n = indices.len() as f64;
    let centroid = indices.iter().fold(Vec3::zeros(), |a, &i| a + at(i as usize)) / n;
    let mut covariance = Mat3::zeros();
    for &i in indices {
        let d = at(i as usize) - centroid;
        covariance += d * d.transpose();
    }
    let (mut normal, _) = smallest_eigenvector(&covariance);
    let mut distance = normal.dot(&centroid);
    if distance < 0.0 {
        normal = -normal;
        distance = -distance;
    }
    ((normal, distance), centroid)
}

fn make_plane(inliers: Vec<u32>, at: &dyn Fn(usize) -> Vec3) -> Plane {
    let ((normal, distance), centroid) = fit_plane(&inliers, at);
    let sum_sq: f64 = inliers.iter().map(|&i| (normal.dot(&at(i as usize)) - distance).powi(2)).sum();
    let rms_m = (sum_sq / inliers.len() as f64).sqrt();
    Plane { normal, distance, centroid, inliers, rms_m }
}

/// Merges planes that are the same surface split over two peaks.
fn merge_duplicates(planes: &mut Vec<Plane>, labels: &mut [Option<u16>], c: &PlaneConfig, at: &dyn Fn(usize) -> Vec3) {
    let mut i = 0;
    while i < planes.len() {
        let mut j = i + 1;
        while j < planes.len() {
            let same_side = planes[i].normal.dot(&planes[j].normal) > 0.0;
            if same_side
                && planes[i].angle_deg(&planes[j]) < c.merge_angle_deg
                && (planes[i].distance - planes[j].distance).abs() < c.merge_distance_m
            {
                let absorbed = planes.remove(j);
                let mut inliers = std::mem::take(&mut planes[i].inliers);
                inliers.extend(absorbed.inliers);
                planes[i] = make_plane(inliers, at);
            } else {
                j += 1;
            }
        }
        i += 1;
    }
    planes.sort_by_key(|p| std::cmp::Reverse(p.inliers.len()));
    labels.iter_mut().for_each(|l| *l = None);
    for (k, plane) in planes.iter().enumerate() {
        for &p in &plane.inliers {
            labels[p as usize] = Some(k as u16);
        }
    }
}

/// Gives each plane point to the plane nearest it and refits: points taken
/// greedily by an earlier plane (a floor reaching into the first half metre
/// of a 10 degree ramp) would otherwise tilt it.
fn reassign_to_nearest(
    planes: &mut [Plane],
    labels: &mut [Option<u16>],
    voting: &[(Vec3, f64)],
    cos_inlier: f64,
    at: &dyn Fn(usize) -> Vec3,
) {
    if planes.len() < 2 {
        return;
    }
    let mut members: Vec<Vec<u32>> = vec![Vec::new(); planes.len()];
    for (i, label) in labels.iter_mut().enumerate() {
        let Some(current) = *label else { continue };
        let p = at(i);
        let best = planes
            .iter()
            .enumerate()
            .filter(|(_, q)| voting[i].0.dot(&q.normal).abs() > cos_inlier)
            .min_by(|a, b| a.1.signed_distance(&p).abs().total_cmp(&b.1.signed_distance(&p).abs()))
            .map_or(current as usize, |(k, _)| k);
        *label = Some(best as u16);
        members[best].push(i as u32);
    }
    for (plane, inliers) in planes.iter_mut().zip(members) {
        if inliers.len() >= 3 {
            *plane = make_plane(inliers, at);
        }
    }
}
