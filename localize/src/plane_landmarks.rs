//! Plane landmarks: the large planes of the scans (walls, floors, ramps) kept
//! in the world frame. Corners alone are too sparse for an 8-beam LIDAR and a
//! camera that sees ceilings the LIDAR never reaches; walls and floors are in
//! every scan and pin yaw, the across-track position, height, roll and pitch,
//! leaving the corners to pin the along-track position.

use datasets::math::{Pose3, Vec3};
use serde::{Deserialize, Serialize};

use crate::planes::Plane;

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PlaneLandmarkConfig {
    /// Use plane landmarks in the pose at all (off = corners only, the
    /// paper's method).
    pub enabled: bool,
    /// Planes with fewer inliers are not used.
    pub min_inliers: usize,
    /// Association gates between a predicted frame plane and a landmark.
    pub angle_gate_deg: f64,
    pub distance_gate_m: f64,
    /// Standard deviations of a plane measurement: offset and normal.
    pub distance_sigma_m: f64,
    pub normal_sigma_rad: f64,
    /// An observation's weight in the landmark falls off with the range of
    /// the plane's points: w = inliers / (1 + (range / range_scale_m)^2). A
    /// small attitude error moves a far plane's offset a lot.
    pub range_scale_m: f64,
    /// Once its observations weigh this much (in range-weighted inliers), a
    /// landmark stops moving, so that the map does not follow the pose it
    /// corrects. Far observations weigh little and do not use it up.
    pub max_weight: f64,
    /// A landmark is used once seen this many times with its observations
    /// agreeing to these spreads (offset standard deviation, normal spread):
    /// a surface that really is there is seen the same way frame after frame;
    /// a plane fitted across a floor and the start of a ramp is not.
    pub min_observations: u32,
    pub max_offset_spread_m: f64,
    pub max_normal_spread_deg: f64,
    /// Use only planes within this angle of vertical (walls), in the robot
    /// frame. Floors and ramps seen from afar, first mapped with the attitude
    /// error of that moment, pull the height more than the IMU's own pitch does.
    pub max_wall_tilt_deg: f64,
}

impl Default for PlaneLandmarkConfig {
    fn default() -> Self {
        Self {
            enabled: true,
            min_inliers: 150,
            angle_gate_deg: 4.0,
            distance_gate_m: 0.25,
            distance_sigma_m: 0.02,
            normal_sigma_rad: 0.01,
            range_scale_m: 3.0,
            max_weight: 2000.0,
            min_observations: 3,
            max_offset_spread_m: 0.02,
            max_normal_spread_deg: 1.0,
            max_wall_tilt_deg: 5.0,
        }
    }
}

/// A plane of the world: points p with normal . p = distance.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PlaneLandmark {
    pub normal: Vec3,
    pub distance: f64,
    pub observations: u32,
    /// Inlier-weighted sums of the observed normals and offsets.
    normal_sum: Vec3,
    distance_sum: f64,
    distance_square_sum: f64,
    weight: f64,
}

impl PlaneLandmark {
    /// Weighted standard deviation of the observed offsets.
    pub fn offset_spread_m(&self) -> f64 {
        (self.distance_square_sum / self.weight - self.distance * self.distance).max(0.0).sqrt()
    }
    /// Angular spread of the observed normals (from their mean resultant length).
    pub fn normal_spread_deg(&self) -> f64 {
        let resultant = (self.normal_sum.norm() / self.weight).min(1.0);
        (2.0 * (1.0 - resultant)).sqrt().to_degrees()
    }
}

/// A frame plane expressed in the robot frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RobotPlane {
    pub normal: Vec3,
    /// A point on the plane (the inliers' centroid).
    pub point: Vec3,
    pub inliers: usize,
}

impl RobotPlane {
    pub fn from_lidar(plane: &Plane, robot_from_lidar: &Pose3) -> Self {
        Self {
            normal: robot_from_lidar.rotation * plane.normal,
            point: (robot_from_lidar * nalgebra::Point3::from(plane.centroid)).coords,
            inliers: plane.inliers.len(),
        }
    }

    /// The plane in the world, seen from `world_from_robot`: (normal, offset)
    /// with the normal's sign free.
    pub fn in_world(&self, world_from_robot: &Pose3) -> (Vec3, f64) {
        let n = world_from_robot.rotation * self.normal;
        let p = (world_from_robot * nalgebra::Point3::from(self.point)).coords;
        (n, n.dot(&p))
    }
}

#[derive(Debug, Clone, Default)]
pub struct PlaneMap {
    pub config: PlaneLandmarkConfig,
    pub landmarks: Vec<PlaneLandmark>,
}

impl PlaneMap {
    pub fn new(config: PlaneLandmarkConfig) -> Self {
        Self { config, landmarks: Vec::new() }
    }

    /// Big enough, and steep enough when only walls are wanted.
    fn usable(&self, plane: &RobotPlane) -> bool {
        let tilt_deg = 90.0 - plane.normal.z.abs().min(1.0).acos().to_degrees();
        plane.inliers >= self.config.min_inliers && tilt_deg <= self.config.max_wall_tilt_deg
    }

    /// Whether landmark `k` is seen consistently enough to correct poses.
    pub fn is_trusted(&self, k: usize) -> bool {
        let (l, c) = (&self.landmarks[k], &self.config);
        l.observations >= c.min_observations
            && l.offset_spread_m() <= c.max_offset_spread_m
            && l.normal_spread_deg() <= c.max_normal_spread_deg
    }

    /// For each frame plane, the landmark it is (within both gates, the
    /// nearest in offset), with the normal's sign matched to the landmark's.
    pub fn associate(&self, planes: &[RobotPlane], world_from_robot: &Pose3) -> Vec<Option<usize>> {
        let cos_gate = self.config.angle_gate_deg.to_radians().cos();
        let mut taken = vec![false; self.landmarks.len()];
        let mut out = vec![None; planes.len()];
        // Larger planes choose first.
        let mut order: Vec<usize> = (0..planes.len()).collect();
        order.sort_by_key(|&i| std::cmp::Reverse(planes[i].inliers));
        for i in order {
            if !self.usable(&planes[i]) {
                continue;
            }
            let (n, d) = planes[i].in_world(world_from_robot);
            let best = self
                .landmarks
                .iter()
                .enumerate()
                .filter(|(k, _)| !taken[*k])
                .filter_map(|(k, l)| {
                    let dot = n.dot(&l.normal);
                    let gap = (d * dot.signum() - l.distance).abs();
                    (dot.abs() > cos_gate && gap < self.config.distance_gate_m).then_some((k, gap))
                })
                .min_by(|a, b| a.1.total_cmp(&b.1));
            if let Some((k, _)) = best {
                taken[k] = true;
                out[i] = Some(k);
            }
        }
        out
    }

    /// Adds observations made from `world_from_robot` (usually the corrected pose).
    pub fn observe(&mut self, planes: &[RobotPlane], association: &[Option<usize>], world_from_robot: &Pose3) {
        for (plane, a) in planes.iter().zip(association) {
            if !self.usable(plane) {
                continue;
            }
            let (mut n, mut d) = plane.in_world(world_from_robot);
            let range = plane.point.norm();
            let w = plane.inliers as f64 / (1.0 + (range / self.config.range_scale_m).powi(2));
            match a {
                Some(k) => {
                    let l = &mut self.landmarks[*k];
                    l.observations += 1;
                    if l.weight >= self.config.max_weight {
                        continue;
                    }
                    if n.dot(&l.normal) < 0.0 {
                        n = -n;
                        d = -d;
                    }
                    l.normal_sum += w * n;
                    l.distance_sum += w * d;
                    l.distance_square_sum += w * d * d;
                    l.weight += w;
                    l.normal = l.normal_sum.normalize();
                    l.distance = l.distance_sum / l.weight;
                }
                None => self.landmarks.push(PlaneLandmark {
                    normal: n,
                    distance: d,
                    observations: 1,
                    normal_sum: w * n,
                    distance_sum: w * d,
                    distance_square_sum: w * d * d,
                    weight: w,
                }),
            }
        }
    }
}
