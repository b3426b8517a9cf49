//! The 3D corners of the scans (three planes meeting, `corners.rs`),
//! followed in the world over a run at the poses the run estimated. A
//! corner of the building is seen again and again at one place from poses
//! along the route; a corner of a person or of anything that moves is not.
//! What survives (`CornerTracks::persistent`) is what `autolabel` projects
//! into the images.

use std::collections::HashMap;

use datasets::math::{Pose3, Vec3};
use serde::{Deserialize, Serialize};

use datasets::InvalidSetting;

use crate::scan::geometry::Geometry;

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CornerTrackConfig {
    /// A scan's corner joins the nearest track within this distance.
    pub gate_m: f64,
    /// Persistent: seen in at least this many scans...
    pub min_scans: usize,
    /// ...from robot positions at least this far apart...
    pub min_baseline_m: f64,
    /// ...with its observations within this RMS distance of their mean.
    pub max_spread_m: f64,
    /// Each of a corner's three planes must spread its points this far
    /// around the corner (RMS distance from their centroid, `structural_corners`):
    /// walls, floors, ceilings and large boxes, not the seat of a chair.
    pub min_plane_extent_m: f64,
}

impl Default for CornerTrackConfig {
    fn default() -> Self {
        Self { gate_m: 0.15, min_scans: 3, min_baseline_m: 0.5, max_spread_m: 0.04, min_plane_extent_m: 0.25 }
    }
}

impl CornerTrackConfig {
    pub fn validate(&self) -> Result<(), InvalidSetting> {
        InvalidSetting::positive("gate_m", self.gate_m, 2.0)?;
        if self.min_scans < 2 {
            return Err(InvalidSetting::field("min_scans", "must be at least 2 (one scan proves nothing persists)"));
        }
        if !(self.min_baseline_m >= 0.0 && self.min_baseline_m.is_finite()) {
            return Err(InvalidSetting::field("min_baseline_m", format!("{} m is not a length", self.min_baseline_m)));
        }
        if !(self.max_spread_m > 0.0 && self.max_spread_m < self.gate_m) {
            return Err(InvalidSetting::field(
                "max_spread_m",
                format!("{} m must lie in (0, gate_m = {} m)", self.max_spread_m, self.gate_m),
            ));
        }
        InvalidSetting::non_negative("min_plane_extent_m", self.min_plane_extent_m, 10.0)?;
        Ok(())
    }
}

/// The corners of a scan's geometry (in the robot frame) whose three planes
/// each spread at least `min_extent_m` around the corner: the RMS distance
/// from their centroid of the plane's points within 1 m of the corner (or
/// 30 % of its range, as the corner extractor's support). A plane is
/// infinite: a chair's seat shares its plane with every other seat, but not
/// the floor space around it.
pub fn structural_corners(geometry: &Geometry, robot_from_lidar: &Pose3, min_extent_m: f64) -> Vec<Vec3> {
    let local_extent = |corner: &Vec3, k: usize| {
        let radius = 1.0f64.max(0.3 * corner.norm());
        let near: Vec<Vec3> = geometry.planes.planes[k]
            .inliers
            .iter()
            .map(|&i| geometry.points[i as usize].cast::<f64>().coords)
            .filter(|p| (p - corner).norm() <= radius)
            .collect();
        if near.len() < 3 {
            return 0.0;
        }
        let centroid = near.iter().sum::<Vec3>() / near.len() as f64;
        (near.iter().map(|p| (p - centroid).norm_squared()).sum::<f64>() / near.len() as f64).sqrt()
    };
    geometry
        .corners
        .corners
        .iter()
        .filter(|c| c.planes.iter().all(|&k| local_extent(&c.position, k) >= min_extent_m))
        .map(|c| (robot_from_lidar * nalgebra::Point3::from(c.position)).coords)
        .collect()
}

/// One corner followed over the scans that saw it.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct CornerTrack {
    /// Mean of the observations (world).
    pub position: Vec3,
    pub scans: usize,
    /// RMS distance of the observations from their mean.
    pub spread_m: f64,
    /// Largest distance between two robot positions that saw it (bounded
    /// below by the distance between the first and the farthest).
    pub baseline_m: f64,
    pub first_stamp: f64,
    pub last_stamp: f64,
    #[serde(skip)]
    sum: Vec3,
    #[serde(skip)]
    square_sum: f64,
    #[serde(skip)]
    first_robot: Vec3,
    #[serde(skip)]
    last_scan: u64,
}

impl CornerTrack {
    fn new(position: Vec3, robot: Vec3, stamp: f64, scan: u64) -> Self {
        Self {
            position,
            scans: 1,
            spread_m: 0.0,
            baseline_m: 0.0,
            first_stamp: stamp,
            last_stamp: stamp,
            sum: position,
            square_sum: position.norm_squared(),
            first_robot: robot,
            last_scan: scan,
        }
    }

    fn add(&mut self, position: Vec3, robot: Vec3, stamp: f64, scan: u64) {
        self.scans += 1;
        self.sum += position;
        self.square_sum += position.norm_squared();
        self.position = self.sum / self.scans as f64;
        let variance = self.square_sum / self.scans as f64 - self.position.norm_squared();
        self.spread_m = variance.max(0.0).sqrt();
        self.baseline_m = self.baseline_m.max((robot - self.first_robot).norm());
        self.last_stamp = stamp;
        self.last_scan = scan;
    }
}

/// Tracks of the scans' corners, with a grid of cells one gate wide for the
/// nearest-track search.
#[derive(Debug, Clone)]
pub struct CornerTracks {
    pub config: CornerTrackConfig,
    pub tracks: Vec<CornerTrack>,
    cells: HashMap<[i64; 3], Vec<usize>>,
    scans: u64,
}

impl CornerTracks {
    pub fn new(config: CornerTrackConfig) -> Self {
        Self { config, tracks: Vec::new(), cells: HashMap::new(), scans: 0 }
    }

    fn cell(&self, p: &Vec3) -> [i64; 3] {
        let g = self.config.gate_m;
        [(p.x / g).floor() as i64, (p.y / g).floor() as i64, (p.z / g).floor() as i64]
    }

    /// The corners of one scan (robot frame) placed by the scan's pose. A
    /// track takes at most one corner of a scan (the nearest).
    pub fn observe(&mut self, stamp: f64, world_from_robot: &Pose3, corners_in_robot: &[Vec3]) {
        self.scans += 1;
        let scan = self.scans;
        let robot = world_from_robot.translation.vector;
        let gate = self.config.gate_m;
        for c in corners_in_robot {
            let p = (world_from_robot * nalgebra::Point3::from(*c)).coords;
            if !p.iter().all(|v| v.is_finite()) {
                continue;
            }
            let [x, y, z] = self.cell(&p);
            let mut best: Option<(f64, usize)> = None;
            for dx in -1..=1 {
                for dy in -1..=1 {
                    for dz in -1..=1 {
                        for &k in self.cells.get(&[x + dx, y + dy, z + dz]).into_iter().flatten() {
                            let d = (self.tracks[k].position - p).norm();
                            if d < gate && self.tracks[k].last_scan != scan && best.is_none_or(|(b, _)| d < b) {
                                best = Some((d, k));
                            }
                        }
                    }
                }
            }
            match best {
                Some((_, k)) => {
                    let before = self.cell(&self.tracks[k].position);
                    self.tracks[k].add(p, robot, stamp, scan);
                    let after = self.cell(&self.tracks[k].position);
                    if before != after {
                        self.cells.get_mut(&before).expect("indexed").retain(|&i| i != k);
                        self.cells.entry(after).or_default().push(k);
                    }
                }
                None => {
                    self.cells.entry([x, y, z]).or_default().push(self.tracks.len());
                    self.tracks.push(CornerTrack::new(p, robot, stamp, scan));
                }
            }
        }
    }

    /// The tracks seen often enough, from far enough apart, at one place.
    pub fn persistent(&self) -> Vec<CornerTrack> {
        self.tracks.iter().filter(|t| self.persists(t)).cloned().collect()
    }

    /// The tracks seen in more than one scan that did not persist: maybe a
    /// corner of the building seen too seldom, maybe one that moved.
    pub fn passing(&self) -> Vec<CornerTrack> {
        self.tracks.iter().filter(|t| t.scans >= 2 && !self.persists(t)).cloned().collect()
    }

    fn persists(&self, t: &CornerTrack) -> bool {
        let c = &self.config;
        t.scans >= c.min_scans && t.baseline_m >= c.min_baseline_m && t.spread_m <= c.max_spread_m
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{RngExt, SeedableRng};

    #[test]
    fn a_fixed_corner_seen_along_a_route_persists_and_a_moving_one_does_not() {
        let config = CornerTrackConfig::default();
        let mut tracks = CornerTracks::new(config.clone());
        let mut rng = rand::rngs::ChaCha8Rng::seed_from_u64(3);
        let fixed = Vec3::new(4.0, 1.0, 2.5);
        for k in 0..20 {
            // The robot drives along x, turning slowly; the corner is seen with 1 cm noise.
            let pose = Pose3::from_parts(
                Vec3::new(0.1 * k as f64, 0.0, 0.0).into(),
                nalgebra::UnitQuaternion::from_euler_angles(0.0, 0.0, 0.02 * k as f64),
            );
            let noise = Vec3::new(rng.random_range(-0.01..0.01), rng.random_range(-0.01..0.01), 0.0);
            let in_robot = |p: Vec3| (pose.inverse() * nalgebra::Point3::from(p)).coords;
            // A person 2 m ahead of the robot walks with it: a corner that moves 10 cm a scan.
            let walker = Vec3::new(0.1 * k as f64 + 2.0 + 0.1 * k as f64, -1.0, 1.0);
            tracks.observe(k as f64 * 0.1, &pose, &[in_robot(fixed + noise), in_robot(walker)]);
        }
        let kept = tracks.persistent();
        assert_eq!(kept.len(), 1, "{kept:?}");
        assert!((kept[0].position - fixed).norm() < 0.01, "{:?}", kept[0].position);
        assert_eq!(kept[0].scans, 20);
        assert!((kept[0].baseline_m - 1.9).abs() < 1e-9 && kept[0].spread_m < 0.01 && kept[0].spread_m > 0.0);
        // The walker's corners left at least ten tracks behind, none persistent.
        assert!(tracks.tracks.len() >= 11, "{}", tracks.tracks.len());
        // Each seen once (it moves 20 cm a scan, beyond the gate): none passing either.
        assert!(tracks.passing().is_empty());
    }

    #[test]
    fn a_standing_robot_proves_nothing_persists() {
        let mut tracks = CornerTracks::new(CornerTrackConfig::default());
        for k in 0..30 {
            tracks.observe(k as f64, &Pose3::identity(), &[Vec3::new(2.0, 0.0, 1.0)]);
        }
        assert_eq!(tracks.tracks[0].scans, 30);
        assert!(tracks.persistent().is_empty(), "no baseline: a person standing still would pass");
        assert_eq!(tracks.passing().len(), 1);
    }

    #[test]
    fn two_corners_of_one_scan_never_join_one_track() {
        let mut tracks = CornerTracks::new(CornerTrackConfig::default());
        let (a, b) = (Vec3::new(2.0, 0.0, 1.0), Vec3::new(2.05, 0.0, 1.0));
        tracks.observe(0.0, &Pose3::identity(), &[a]);
        tracks.observe(0.1, &Pose3::identity(), &[a, b]);
        assert_eq!(tracks.tracks.len(), 2);
        assert_eq!(tracks.tracks[0].scans, 2);
    }

    #[test]
    fn settings_out_of_range_are_named() {
        let bad = CornerTrackConfig { max_spread_m: 0.5, ..Default::default() };
        assert!(bad.validate().unwrap_err().to_string().contains("max_spread_m"));
        let bad = CornerTrackConfig { min_scans: 1, ..Default::default() };
        assert!(bad.validate().unwrap_err().to_string().contains("min_scans"));
        CornerTrackConfig::default().validate().unwrap();
    }
}
