//! Scan-to-map registration: the frame's planar points aligned
//! point-to-plane with the point map (Gauss-Newton from the predicted pose,
//! Huber-weighted, re-associating each step), as KISS-ICP and GenZ-ICP
//! register. The result is a pose measurement with its information matrix,
//! which the pose solver weighs beside the corners and walls: a corridor
//! that pins only two directions gives no information along the third. Edge
//! points (`image_edges`), where a frame has them, register point-to-line
//! against the edge map beside the planes.

use datasets::InvalidSetting;
use datasets::math::{Pose3, Vec3};
use nalgebra::{Matrix3, Matrix6, Point3, SMatrix, Vector6};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::estimation::edge_map::EdgeMap;
use crate::estimation::ekf::{pose_entries, pose_from_entries};
use crate::estimation::euler::{rotation, wrap};
use crate::estimation::point_map::PointMap;
use crate::scan::normals::PointNormal;

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ScanMatchConfig {
    /// Off: the pose comes from corners, walls and odometry/IMU alone (the
    /// paper's estimator).
    pub enabled: bool,
    /// Edge of the point map's voxels; also the farthest a correspondence
    /// may be searched.
    pub map_voxel_m: f64,
    pub points_per_voxel: usize,
    /// A new map point closer than this to one in its voxel is skipped.
    pub map_spacing_m: f64,
    /// The frame's points are thinned to one per cube of this edge.
    pub source_voxel_m: f64,
    /// Only points this planar (surface variation) register or join the map.
    pub max_curvature: f64,
    /// Farthest a scan point may be from its map point.
    pub max_distance_m: f64,
    /// Where given, a wide baseline (the predicted motion moves the scan's
    /// points farther than `max_distance_m`: keyframes, a quick hand)
    /// registers with this gate at the first iteration, narrowed to
    /// `max_distance_m` over the first half of the iterations, from the
    /// prediction and from the last frame's pose, keeping the result with
    /// more inliers. A start farther off than the final gate still finds its
    /// correspondences; where nothing measures the motion, a wrong
    /// registration's jump carried on would send the next start farther off.
    pub wide_baseline_distance_m: Option<f64>,
    /// Largest angle between a scan point's normal and its map point's.
    pub max_normal_angle_deg: f64,
    pub iterations: usize,
    /// Standard deviation of a point-to-plane residual; also the Huber
    /// threshold's unit.
    pub point_sigma_m: f64,
    pub huber: f64,
    /// Least standard deviations of a registered position and attitude,
    /// added to what the points alone would give: the map was placed by
    /// earlier estimates, so however many points agree, the registration is
    /// no better than the map.
    pub floor_m: f64,
    pub floor_rad: f64,
    /// The registration measures x, y and yaw only: height, roll and pitch
    /// stay with gravity and the corners (a height registered against a map
    /// the estimates placed drifts over ramps as odometry does).
    pub horizontal_only: bool,
    /// Fewer correspondences than this: no measurement.
    pub min_correspondences: usize,
    /// The edge map (`image_edges`: RGB-D frames whose colour is registered
    /// to their depth): its most points per voxel, and the least spacing
    /// between them.
    pub edges_per_voxel: usize,
    pub edge_spacing_m: f64,
}

impl Default for ScanMatchConfig {
    fn default() -> Self {
        Self {
            enabled: true,
            map_voxel_m: 0.5,
            points_per_voxel: 20,
            map_spacing_m: 0.05,
            source_voxel_m: 0.2,
            max_curvature: 0.05,
            max_distance_m: 0.3,
            wide_baseline_distance_m: None,
            max_normal_angle_deg: 30.0,
            iterations: 10,
            point_sigma_m: 0.05,
            huber: 2.0,
            floor_m: 0.01,
            floor_rad: 0.002,
            horizontal_only: true,
            min_correspondences: 50,
            edges_per_voxel: 40,
            edge_spacing_m: 0.01,
        }
    }
}

impl ScanMatchConfig {
    pub fn validate(&self) -> Result<(), InvalidSetting> {
        let positive = InvalidSetting::positive;
        positive("map_voxel_m", self.map_voxel_m, 10.0)?;
        positive("source_voxel_m", self.source_voxel_m, 10.0)?;
        positive("max_curvature", self.max_curvature, 1.0)?;
        positive("max_normal_angle_deg", self.max_normal_angle_deg, 180.0)?;
        positive("point_sigma_m", self.point_sigma_m, 10.0)?;
        positive("huber", self.huber, 1000.0)?;
        positive("floor_m", self.floor_m, 10.0)?;
        positive("floor_rad", self.floor_rad, 1.0)?;
        if !(self.map_spacing_m.is_finite() && (0.0..=self.map_voxel_m).contains(&self.map_spacing_m)) {
            return Err(InvalidSetting::field(
                "map_spacing_m",
                format!("{} outside [0, map_voxel_m]", self.map_spacing_m),
            ));
        }
        // The map searches the 27 voxels around a point: no farther than one edge.
        if !(self.max_distance_m > 0.0 && self.max_distance_m <= self.map_voxel_m) {
            return Err(InvalidSetting::field(
                "max_distance_m",
                format!("{} outside (0, map_voxel_m = {}]", self.max_distance_m, self.map_voxel_m),
            ));
        }
        if let Some(start) = self.wide_baseline_distance_m
            && !(start >= self.max_distance_m && start <= self.map_voxel_m)
        {
            return Err(InvalidSetting::field(
                "wide_baseline_distance_m",
                format!(
                    "{start} outside [max_distance_m = {}, map_voxel_m = {}]",
                    self.max_distance_m, self.map_voxel_m
                ),
            ));
        }
        let count = InvalidSetting::count;
        count("points_per_voxel", self.points_per_voxel, 1, 10_000)?;
        count("iterations", self.iterations, 1, 1000)?;
        count("edges_per_voxel", self.edges_per_voxel, 1, 10_000)?;
        if !(self.edge_spacing_m.is_finite() && (0.0..=self.map_voxel_m).contains(&self.edge_spacing_m)) {
            return Err(InvalidSetting::field(
                "edge_spacing_m",
                format!("{} outside [0, map_voxel_m]", self.edge_spacing_m),
            ));
        }
        count("min_correspondences", self.min_correspondences, 6, 10_000_000)
    }
}

/// A frame's surface points in the robot frame, thinned, with their
/// normals, and its edge points (none but from a registered RGB-D frame).
#[derive(Default)]
pub struct ScanPoints {
    pub points: Vec<Vec3>,
    pub normals: Vec<Vec3>,
    pub edges: Vec<Vec3>,
}

impl ScanPoints {
    /// The planar points of a cloud (sensor frame, with its normals), one
    /// per `source_voxel_m` cube (the first seen), in the robot frame.
    pub fn select(
        config: &ScanMatchConfig,
        points: &[Point3<f32>],
        normals: &[PointNormal],
        robot_from_lidar: &Pose3,
    ) -> Self {
        // Per cube, the point nearest its centre, both by where the point's
        // surface is (`PointNormal::offset`). Keyed on the noisy position, a
        // cube the surface barely enters would keep only points the noise
        // pushed into it; the first point seen in sweep order would sit on
        // the cube's edge where the sweep enters it, the same side in every
        // cube and every scan. Either biased the registration's heading
        // (results log, 2026-12-03, the scan's thinning).
        let mut best: rustc_hash::FxHashMap<[i64; 3], (f64, usize)> = rustc_hash::FxHashMap::default();
        for (k, (p, n)) in points.iter().zip(normals).enumerate() {
            if n.curvature > config.max_curvature || !n.normal.iter().all(|v| v.is_finite()) {
                continue;
            }
            let p = p.cast::<f64>();
            let on_surface = p.coords - n.offset * n.normal;
            let scaled = on_surface / config.source_voxel_m;
            let cube = scaled.map(|v| v.floor());
            // Distance from the centre along the surface only: across it,
            // nearer the centre would mean pushed there by the noise.
            let to_centre = cube + Vec3::repeat(0.5) - scaled;
            let d = (to_centre - to_centre.dot(&n.normal) * n.normal).norm_squared();
            let key = [cube.x as i64, cube.y as i64, cube.z as i64];
            match best.get_mut(&key) {
                Some(b) if b.0 <= d => {}
                Some(b) => *b = (d, k),
                None => {
                    best.insert(key, (d, k));
                }
            }
        }
        let mut chosen: Vec<usize> = best.values().map(|b| b.1).collect();
        chosen.sort_unstable();
        let (mut out_points, mut out_normals) = (Vec::new(), Vec::new());
        for k in chosen {
            out_points.push((robot_from_lidar * points[k].cast::<f64>()).coords);
            out_normals.push(robot_from_lidar.rotation * normals[k].normal);
        }
        Self { points: out_points, normals: out_normals, edges: Vec::new() }
    }
}

/// A registration: the pose (x, y, z, roll, pitch, yaw; world from robot)
/// and its information matrix in those coordinates.
#[derive(Debug, Clone, Copy)]
pub struct ScanFix {
    pub pose: Vector6<f64>,
    pub information: Matrix6<f64>,
    pub correspondences: usize,
    /// Root mean square of the inliers' residuals (point-to-plane, and
    /// point-to-line for edge points).
    pub rms_m: f64,
    /// Residuals within the Huber threshold: what tells two starts' results apart.
    pub inliers: usize,
}

impl ScanFix {
    /// The residual rows whose squares sum to the Mahalanobis distance:
    /// sqrt(information) (pose - x).
    pub fn whitening(&self) -> Matrix6<f64> {
        let eigen = self.information.symmetric_eigen();
        let root = Matrix6::from_diagonal(&eigen.eigenvalues.map(|v| v.max(0.0).sqrt()));
        root * eigen.eigenvectors.transpose()
    }

    /// The pose difference `self.pose - x` with angles wrapped.
    pub fn difference(&self, x: &Vector6<f64>) -> Vector6<f64> {
        let mut d = self.pose - x;
        for k in 3..6 {
            d[k] = wrap(d[k]);
        }
        d
    }
}

pub struct ScanMatcher {
    config: ScanMatchConfig,
}

/// One correspondence: its point-to-plane residual and Jacobian row.
type Term = (f64, SMatrix<f64, 1, 6>);

impl ScanMatcher {
    pub fn new(config: ScanMatchConfig) -> Result<Self, InvalidSetting> {
        config.validate().map_err(|e| e.within("scan_match"))?;
        Ok(Self { config })
    }

    pub fn config(&self) -> &ScanMatchConfig {
        &self.config
    }

    pub fn new_map(&self) -> PointMap {
        let c = &self.config;
        PointMap::new(c.map_voxel_m, c.points_per_voxel, c.map_spacing_m)
    }

    pub fn new_edge_map(&self) -> EdgeMap {
        let c = &self.config;
        EdgeMap::new(c.map_voxel_m, c.edges_per_voxel, c.edge_spacing_m)
    }

    /// Registers `scan` against `map` (and its edge points against `edges`,
    /// where given) from `initial` (x, y, z, roll, pitch, yaw); `None` with
    /// too few correspondences or a singular system.
    pub fn register(
        &self,
        map: &PointMap,
        edges: Option<&EdgeMap>,
        scan: &ScanPoints,
        initial: &Vector6<f64>,
    ) -> Option<ScanFix> {
        self.register_within(map, edges, scan, initial, self.config.max_distance_m)
    }

    /// `register` with the correspondence gate narrowed from `start_gate_m`.
    fn register_within(
        &self,
        map: &PointMap,
        edges: Option<&EdgeMap>,
        scan: &ScanPoints,
        initial: &Vector6<f64>,
        start_gate_m: f64,
    ) -> Option<ScanFix> {
        let c = &self.config;
        if map.is_empty() {
            return None;
        }
        let cos_gate = c.max_normal_angle_deg.to_radians().cos();
        let mut x = *initial;
        let narrowing = (c.iterations / 2).max(1) as f64;
        let widening = (start_gate_m - c.max_distance_m).max(0.0);
        for k in 0..c.iterations {
            let gate = c.max_distance_m + widening * (1.0 - k as f64 / narrowing).max(0.0);
            let terms = self.terms(map, edges, scan, &x, cos_gate, gate);
            if terms.len() < c.min_correspondences {
                return None;
            }
            let (h, g) = self.normal_equations(&terms);
            let step = solve_observable(&h, &g)?;
            x += step;
            for k in 3..6 {
                x[k] = wrap(x[k]);
            }
            let small = step.fixed_rows::<3>(0).norm() < 1e-4 && step.fixed_rows::<3>(3).norm() < 1e-5;
            if small && gate == c.max_distance_m {
                break;
            }
        }
        let terms = self.terms(map, edges, scan, &x, cos_gate, c.max_distance_m);
        if terms.len() < c.min_correspondences {
            return None;
        }
        let (h, _) = self.normal_equations(&terms);
        let mut information = h / (c.point_sigma_m * c.point_sigma_m);
        if c.horizontal_only {
            information = horizontal_marginal(&information);
        }
        let information = self.with_floor(&information);
        let inlier_gate = c.huber * c.point_sigma_m;
        let inliers: Vec<f64> = terms.iter().map(|t| t.0).filter(|r| r.abs() <= inlier_gate).collect();
        let rms_m = (inliers.iter().map(|r| r * r).sum::<f64>() / inliers.len().max(1) as f64).sqrt();
        Some(ScanFix { pose: x, information, correspondences: terms.len(), rms_m, inliers: inliers.len() })
    }

    /// `register` from the `predicted` pose (x, y, z, roll, pitch, yaw),
    /// after a frame at `previous`:
    /// across a wide baseline (`wide_baseline_distance_m`) from both, with
    /// the wide gate, keeping the result with the most inliers (the
    /// prediction's of equals).
    pub fn register_after(
        &self,
        map: &PointMap,
        edges: Option<&EdgeMap>,
        scan: &ScanPoints,
        predicted: &Vector6<f64>,
        previous: Option<&Pose3>,
    ) -> Option<ScanFix> {
        let c = &self.config;
        let start = *predicted;
        let shift = |previous: &Pose3| largest_shift(&scan.points, &pose_from_entries(predicted), previous);
        let wide = match (c.wide_baseline_distance_m, previous) {
            (Some(gate), Some(previous)) if shift(previous) > c.max_distance_m => Some((gate, pose_entries(previous))),
            _ => None,
        };
        let Some((gate, still)) = wide else {
            return self.register(map, edges, scan, &start);
        };
        let mut best: Option<ScanFix> = None;
        for start in [start, still] {
            if let Some(fix) = self.register_within(map, edges, scan, &start, gate)
                && best.as_ref().is_none_or(|b| fix.inliers > b.inliers)
            {
                best = Some(fix);
            }
        }
        best
    }

    /// Each scan point's residual and Jacobian at `x` against the plane of
    /// its nearest map point, when one is close enough and the plane faces
    /// the way the point's own surface does (within the angle gate; the two
    /// sides of a thin wall face apart); each edge point's two residuals
    /// across the line of its nearest map edge points.
    fn terms(
        &self,
        map: &PointMap,
        edges: Option<&EdgeMap>,
        scan: &ScanPoints,
        x: &Vector6<f64>,
        cos_gate: f64,
        gate: f64,
    ) -> Vec<Term> {
        let t = Vec3::new(x[0], x[1], x[2]);
        let r = rotation(x[3], x[4], x[5]).to_rotation_matrix().into_inner();
        // d R / d angle, by central differences (the angles are Euler ZYX).
        let e = 1e-6;
        let derivative = |k: usize| {
            let (mut plus, mut minus) = (*x, *x);
            plus[3 + k] += e;
            minus[3 + k] -= e;
            let at = |v: &Vector6<f64>| rotation(v[3], v[4], v[5]).to_rotation_matrix().into_inner();
            (at(&plus) - at(&minus)) / (2.0 * e)
        };
        let dr = [derivative(0), derivative(1), derivative(2)];
        // The residual along unit `direction` of `q = t + r p` from `anchor`.
        let term = |p: &Vec3, q: &Vec3, direction: &Vec3, anchor: &Vec3| {
            let mut jacobian = SMatrix::<f64, 1, 6>::zeros();
            for k in 0..3 {
                jacobian[k] = direction[k];
                jacobian[3 + k] = direction.dot(&(dr[k] * p));
            }
            (direction.dot(&(q - anchor)), jacobian)
        };
        let mut terms: Vec<Term> = scan
            .points
            .par_iter()
            .zip(&scan.normals)
            .filter_map(|(p, n)| {
                let q = t + r * p;
                let m = map.nearest_plane(&q, gate)?;
                if m.normal.dot(&(r * n)) < cos_gate {
                    return None;
                }
                Some(term(p, &q, &m.normal, &m.centroid))
            })
            .collect();
        if let Some(edges) = edges.filter(|e| !e.is_empty()) {
            let across: Vec<[Term; 2]> = scan
                .edges
                .par_iter()
                .filter_map(|p| {
                    let q = t + r * p;
                    let line = edges.line_near(&q, gate)?;
                    let first = line.direction.cross(&Vec3::x()).try_normalize(1e-6);
                    let first = first.or_else(|| line.direction.cross(&Vec3::y()).try_normalize(1e-6))?;
                    let second = line.direction.cross(&first);
                    Some([term(p, &q, &first, &line.point), term(p, &q, &second, &line.point)])
                })
                .collect();
            terms.extend(across.into_iter().flatten());
        }
        terms
    }

    /// The information of the points' covariance plus the floor's:
    /// (L^-1 + F)^-1 = L (I + F L)^-1, defined where L is singular too.
    fn with_floor(&self, information: &Matrix6<f64>) -> Matrix6<f64> {
        let (m, r) = (self.config.floor_m.powi(2), self.config.floor_rad.powi(2));
        let floor = Matrix6::from_diagonal(&Vector6::new(m, m, m, r, r, r));
        let Some(inverse) = (Matrix6::identity() + floor * information).try_inverse() else {
            return Matrix6::zeros();
        };
        let out = information * inverse;
        0.5 * (out + out.transpose())
    }

    /// Huber-weighted J'WJ and J'Wr.
    fn normal_equations(&self, terms: &[Term]) -> (Matrix6<f64>, Vector6<f64>) {
        let threshold = self.config.huber * self.config.point_sigma_m;
        let mut h = Matrix6::zeros();
        let mut g = Vector6::zeros();
        for (r, j) in terms {
            let w = if r.abs() <= threshold { 1.0 } else { threshold / r.abs() };
            h += w * j.transpose() * j;
            g += w * j.transpose() * *r;
        }
        (h, g)
    }
}

/// The farthest any of `points` (robot frame) moves between poses `a` and `b`.
fn largest_shift(points: &[Vec3], a: &Pose3, b: &Pose3) -> f64 {
    let relative = b.inverse() * a;
    points.iter().map(|p| (relative.transform_point(&Point3::from(*p)) - Point3::from(*p)).norm()).fold(0.0, f64::max)
}

/// The information on x, y and yaw alone, height, roll and pitch
/// marginalised out (the Schur complement): what the points say about the
/// horizontal pose whatever the height is. Slicing the block instead would
/// keep what a ramp's floor says about x only given the height, and turn a
/// height error into an x error of height / tan(slope).
fn horizontal_marginal(information: &Matrix6<f64>) -> Matrix6<f64> {
    const KEEP: [usize; 3] = [0, 1, 5];
    const OUT: [usize; 3] = [2, 3, 4];
    let block = |rows: [usize; 3], cols: [usize; 3]| Matrix3::from_fn(|i, j| information[(rows[i], cols[j])]);
    let (aa, ab, bb) = (block(KEEP, KEEP), block(KEEP, OUT), block(OUT, OUT));
    // A pseudo-inverse: height, roll or pitch the points do not observe carry no information to take out.
    let eigen = bb.symmetric_eigen();
    let largest = eigen.eigenvalues.max();
    let mut bb_inverse = Matrix3::zeros();
    for k in 0..3 {
        let value = eigen.eigenvalues[k];
        if value > 1e-9 * largest {
            let v = eigen.eigenvectors.column(k);
            bb_inverse += v * v.transpose() / value;
        }
    }
    let marginal = aa - ab * bb_inverse * ab.transpose();
    let mut out = Matrix6::zeros();
    for (i, &r) in KEEP.iter().enumerate() {
        for (j, &c) in KEEP.iter().enumerate() {
            out[(r, c)] = 0.5 * (marginal[(i, j)] + marginal[(j, i)]);
        }
    }
    out
}

/// The Gauss-Newton step -H^-1 g within the directions the points observe:
/// a corridor leaves its axis where the prediction put it.
fn solve_observable(h: &Matrix6<f64>, g: &Vector6<f64>) -> Option<Vector6<f64>> {
    let eigen = h.symmetric_eigen();
    let largest = eigen.eigenvalues.max();
    if !(largest > 0.0) {
        return None;
    }
    let mut step = Vector6::zeros();
    for k in 0..6 {
        let value = eigen.eigenvalues[k];
        if value > 1e-9 * largest {
            let v = eigen.eigenvectors.column(k);
            step -= v * (v.dot(g) / value);
        }
    }
    Some(step)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::rngs::ChaCha8Rng;
    use rand::{RngExt, SeedableRng};

    #[test]
    fn thinning_keeps_points_whose_range_noise_averages_out() {
        // A wall 5 cm inside a 20 cm cube's face, seen from the origin with
        // 3 cm of range noise: cubes keyed on the noisy points would keep,
        // in the sliver cube beyond the face, only points pushed out.
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        let wall_y = 2.05;
        let points: Vec<Point3<f32>> = (0..12_000)
            .map(|_| {
                let on_wall = Vec3::new(rng.random_range(-3.0..3.0), wall_y, rng.random_range(-1.0..1.5));
                let range = on_wall.norm();
                let noise: f64 = (0..12).map(|_| rng.random_range(-0.5..0.5)).sum::<f64>() * 0.03;
                (on_wall * ((range + noise) / range)).cast::<f32>().into()
            })
            .collect();
        let grid = crate::scan::scan_grid::ScanGrid::new(&points, &Vec3::zeros());
        let estimator =
            crate::scan::normals::NormalEstimator::new(crate::scan::normals::NormalConfig::default()).unwrap();
        let normals = estimator.estimate(&points, &grid).unwrap();
        let config = ScanMatchConfig { max_curvature: 1.0, ..ScanMatchConfig::default() };
        let scan = ScanPoints::select(&config, &points, &normals, &Pose3::identity());
        let mean_offset = |kept: &[Vec3]| kept.iter().map(|p| p.y - wall_y).sum::<f64>() / kept.len() as f64;
        // The mean of n points with 3 cm of noise is known to about 3 cm / sqrt(n).
        let tolerance = 3.0 * 0.03 / (scan.points.len() as f64).sqrt();
        let mean = mean_offset(&scan.points);
        assert!(
            scan.points.len() > 300 && mean.abs() < tolerance,
            "{} points, mean offset {mean} m",
            scan.points.len()
        );
        // The first point seen in each cube of the noisy positions, as this
        // thinning was before: biased well beyond that.
        let mut seen = rustc_hash::FxHashSet::default();
        let first_seen: Vec<Vec3> = points
            .iter()
            .map(|p| p.cast::<f64>().coords)
            .filter(|p| seen.insert((p / 0.2).map(|v| v.floor() as i64)))
            .collect();
        let before = mean_offset(&first_seen);
        let tolerance_before = 3.0 * 0.03 / (first_seen.len() as f64).sqrt();
        assert!(before.abs() > 2.0 * tolerance_before, "first seen per cube: mean offset {before} m");
    }

    /// Points on the floor, the ceiling and four walls of a 6 x 4 x 3 m room
    /// with a 1 m box in a corner (so no direction slides), robot frame at
    /// the room's centre, with normals.
    fn room(rng: &mut ChaCha8Rng) -> ScanPoints {
        let (mut points, mut normals) = (Vec::new(), Vec::new());
        let mut face = |n: Vec3, at: &dyn Fn(f64, f64) -> Vec3, count: usize| {
            for _ in 0..count {
                let (u, v) = (rng.random_range(0.0..1.0), rng.random_range(0.0..1.0));
                points.push(at(u, v));
                normals.push(n);
            }
        };
        face(Vec3::z(), &|u, v| Vec3::new(-3.0 + 6.0 * u, -2.0 + 4.0 * v, -1.0), 600);
        face(-Vec3::z(), &|u, v| Vec3::new(-3.0 + 6.0 * u, -2.0 + 4.0 * v, 2.0), 600);
        face(Vec3::x(), &|u, v| Vec3::new(-3.0, -2.0 + 4.0 * u, -1.0 + 3.0 * v), 400);
        face(-Vec3::x(), &|u, v| Vec3::new(3.0, -2.0 + 4.0 * u, -1.0 + 3.0 * v), 400);
        face(Vec3::y(), &|u, v| Vec3::new(-3.0 + 6.0 * u, -2.0, -1.0 + 3.0 * v), 400);
        face(-Vec3::y(), &|u, v| Vec3::new(-3.0 + 6.0 * u, 2.0, -1.0 + 3.0 * v), 400);
        face(-Vec3::x(), &|u, v| Vec3::new(2.0, 1.0 + u, -1.0 + v), 200);
        face(-Vec3::y(), &|u, v| Vec3::new(2.0 + u, 1.0, -1.0 + v), 200);
        ScanPoints { points, normals, edges: Vec::new() }
    }

    #[test]
    fn a_room_seen_from_a_moved_pose_registers_back_to_that_pose() {
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        let matcher = ScanMatcher::new(ScanMatchConfig::default()).unwrap();
        let mut map = matcher.new_map();
        let first = room(&mut rng);
        map.insert(&first.points, &first.normals, &Pose3::identity());
        // The robot moved; the scan is the room in its new frame.
        let truth = Pose3::new(Vec3::new(0.25, -0.15, 0.03), Vec3::new(0.01, -0.02, 0.12));
        let seen = room(&mut rng);
        let inverse = truth.inverse();
        let scan = ScanPoints {
            points: seen.points.iter().map(|p| (inverse * Point3::from(*p)).coords).collect(),
            normals: seen.normals.iter().map(|n| inverse.rotation * n).collect(),
            edges: Vec::new(),
        };
        let fix = matcher.register(&map, None, &scan, &Vector6::zeros()).expect("a closed room registers");
        let error = fix.difference(&crate::estimation::ekf::pose_entries(&truth));
        assert!(error.fixed_rows::<3>(0).norm() < 2e-3, "translation off by {error:?}");
        assert!(error.fixed_rows::<3>(3).norm() < 1e-3, "rotation off by {error:?}");
        // Exact surfaces; the residue is where a voxel straddles an edge of the room or the box.
        assert!(fix.rms_m < 3e-3 && fix.correspondences > 2000, "{fix:?}");
        // Height, roll and pitch are left to gravity and the corners.
        assert_eq!(fix.information.row(2).norm() + fix.information.column(4).norm(), 0.0);
        // The whitening squares back to the information.
        let w = fix.whitening();
        assert!((w.transpose() * w - fix.information).norm() < 1e-6 * fix.information.norm());
    }

    /// Two walls 2 m apart and a floor along x, 10 m long, with normals.
    fn corridor(seed: u64) -> (Vec<Vec3>, Vec<Vec3>) {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let (mut points, mut normals) = (Vec::new(), Vec::new());
        for _ in 0..1500 {
            let u = rng.random_range(-5.0..5.0);
            let v = rng.random_range(0.0..1.0);
            points.extend([Vec3::new(u, -1.0, v), Vec3::new(u, 1.0, v), Vec3::new(u, 2.0 * v - 1.0, -0.5)]);
            normals.extend([Vec3::y(), -Vec3::y(), Vec3::z()]);
        }
        (points, normals)
    }

    #[test]
    fn a_corridor_gives_no_information_along_its_axis() {
        // Two walls and a floor along x: x cannot be measured.
        let (points, normals) = corridor(12);
        let scan = ScanPoints { points, normals, edges: Vec::new() };
        let matcher = ScanMatcher::new(ScanMatchConfig::default()).unwrap();
        let mut map = matcher.new_map();
        map.insert(&scan.points, &scan.normals, &Pose3::identity());
        let fix = matcher.register(&map, None, &scan, &Vector6::new(0.1, 0.05, 0.0, 0.0, 0.0, 0.0)).unwrap();
        assert!(fix.pose[1].abs() < 2e-3, "y is pinned by the walls: {}", fix.pose[1]);
        assert!(fix.information[(0, 0)] < 1e-6 * fix.information[(1, 1)], "x: {}", fix.information);
    }

    #[test]
    fn an_edge_across_a_corridor_measures_its_axis() {
        // The corridor above, and a door frame's vertical edge at x = 0.5
        // on its left wall: the planes leave x free, the edge pins it.
        let (points, normals) = corridor(14);
        let edges: Vec<Vec3> = (0..100).map(|k| Vec3::new(0.5, -1.0, 0.01 * k as f64)).collect();
        let matcher = ScanMatcher::new(ScanMatchConfig::default()).unwrap();
        let (mut map, mut edge_map) = (matcher.new_map(), matcher.new_edge_map());
        map.insert(&points, &normals, &Pose3::identity());
        edge_map.insert(&edges, &Pose3::identity());
        let scan = ScanPoints { points, normals, edges };
        let start = Vector6::new(0.1, 0.05, 0.0, 0.0, 0.0, 0.0);
        let fix = matcher.register(&map, Some(&edge_map), &scan, &start).unwrap();
        assert!(fix.pose[0].abs() < 2e-3 && fix.pose[1].abs() < 2e-3, "x and y: {:?}", fix.pose);
        assert!(fix.information[(0, 0)] > 1e-3 * fix.information[(1, 1)], "x: {}", fix.information);
        let planes_only = matcher.register(&map, None, &scan, &start).unwrap();
        assert!((planes_only.pose[0] - 0.1).abs() < 1e-9, "without the edge x stays: {}", planes_only.pose[0]);
    }

    #[test]
    fn a_wide_baseline_registers_from_the_last_pose_when_the_carried_motion_misses() {
        // The robot stopped 3 cm past its last pose; the motion carried on
        // predicts 35 cm: beyond a 5 cm gate from the prediction.
        let mut rng = ChaCha8Rng::seed_from_u64(15);
        let narrow = ScanMatchConfig { max_distance_m: 0.05, ..ScanMatchConfig::default() };
        let wide = ScanMatchConfig { wide_baseline_distance_m: Some(0.4), ..narrow.clone() };
        let first = room(&mut rng);
        let truth = Pose3::new(Vec3::new(0.03, 0.0, 0.0), Vec3::zeros());
        let seen = room(&mut rng);
        let inverse = truth.inverse();
        let scan = ScanPoints {
            points: seen.points.iter().map(|p| (inverse * Point3::from(*p)).coords).collect(),
            normals: seen.normals.iter().map(|n| inverse.rotation * n).collect(),
            edges: Vec::new(),
        };
        let predicted = Vector6::new(0.35, 0.0, 0.0, 0.0, 0.0, 0.0);
        let x_after = |config: &ScanMatchConfig| {
            let matcher = ScanMatcher::new(config.clone()).unwrap();
            let mut map = matcher.new_map();
            map.insert(&first.points, &first.normals, &Pose3::identity());
            matcher.register_after(&map, None, &scan, &predicted, Some(&Pose3::identity())).map(|f| f.pose[0])
        };
        let found = x_after(&wide).expect("the wide registration finds the room");
        assert!((found - 0.03).abs() < 2e-3, "wide: x = {found}");
        assert!(x_after(&narrow).is_none_or(|x| (x - 0.03).abs() > 0.05), "narrow: x = {:?}", x_after(&narrow));
    }

    #[test]
    fn a_ramp_floor_says_nothing_about_x_when_the_height_is_left_free() {
        // A 10 degree ramp between two walls along x: a shift along x looks
        // like a change of height; only y and yaw are measured.
        let slope = 10f64.to_radians();
        let mut rng = ChaCha8Rng::seed_from_u64(13);
        let (mut points, mut normals) = (Vec::new(), Vec::new());
        for _ in 0..1500 {
            let u = rng.random_range(-5.0..5.0);
            let v = rng.random_range(0.0..1.0);
            let floor = Vec3::new(u, 2.0 * v - 1.0, u * slope.tan() - 0.5);
            points.extend([Vec3::new(u, -1.0, v), Vec3::new(u, 1.0, v), floor]);
            normals.extend([Vec3::y(), -Vec3::y(), Vec3::new(-slope.sin(), 0.0, slope.cos())]);
        }
        let scan = ScanPoints { points, normals, edges: Vec::new() };
        let matcher = ScanMatcher::new(ScanMatchConfig::default()).unwrap();
        let mut map = matcher.new_map();
        map.insert(&scan.points, &scan.normals, &Pose3::identity());
        let fix = matcher.register(&map, None, &scan, &Vector6::new(0.0, 0.05, 0.0, 0.0, 0.0, 0.0)).unwrap();
        let i = &fix.information;
        assert!(fix.pose[1].abs() < 2e-3, "y is pinned by the walls: {}", fix.pose[1]);
        assert!(i[(0, 0)] < 1e-6 * i[(1, 1)], "x: {i}");
        assert!(i[(5, 5)] > 1e3, "yaw: {i}");
    }

    #[test]
    fn settings_out_of_range_are_named() {
        let bad = |f: &dyn Fn(&mut ScanMatchConfig)| {
            let mut c = ScanMatchConfig::default();
            f(&mut c);
            ScanMatcher::new(c).err().expect("refused").field
        };
        assert_eq!(bad(&|c| c.max_distance_m = 0.8), "scan_match.max_distance_m");
        assert_eq!(bad(&|c| c.point_sigma_m = f64::NAN), "scan_match.point_sigma_m");
        assert_eq!(bad(&|c| c.min_correspondences = 2), "scan_match.min_correspondences");
        assert_eq!(bad(&|c| c.wide_baseline_distance_m = Some(0.1)), "scan_match.wide_baseline_distance_m");
        assert_eq!(bad(&|c| c.wide_baseline_distance_m = Some(0.6)), "scan_match.wide_baseline_distance_m");
        assert_eq!(bad(&|c| c.edge_spacing_m = -1.0), "scan_match.edge_spacing_m");
        assert_eq!(bad(&|c| c.edges_per_voxel = 0), "scan_match.edges_per_voxel");
    }
}
