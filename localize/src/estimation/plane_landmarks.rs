//! Plane landmarks: the large walls of the scans, kept in the world frame.
//! Corners alone are too sparse for an 8-beam LIDAR and a camera that sees
//! ceilings the LIDAR never reaches; walls are in every scan and pin yaw and
//! the across-track position, leaving the corners and the scan registration
//! to pin the along-track position. A landmark is placed by the pose of the
//! frames that saw it and so carries that pose's error; walls near square
//! with the first frame's are held square with them, so that a heading error
//! is not copied from wall to wall.

use datasets::math::{Pose3, Vec3};
use serde::{Deserialize, Serialize};

use crate::scan::planes::Plane;

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
    /// Walls: planes within this angle of vertical, in the robot frame.
    pub max_wall_tilt_deg: f64,
    /// Walls within this angle of parallel or perpendicular to the
    /// building's axis (the walls of the map's first frame) correct poses
    /// as exactly so (0: off). Buildings are mostly rectilinear; without it
    /// each new wall inherits the heading error of the moment it was mapped
    /// and hands it on.
    pub rectilinear_gate_deg: f64,
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
            rectilinear_gate_deg: 2.0,
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
    /// Weighted sum of the observed planes' centroids (absent in maps
    /// written before it was kept): where a squared-up wall pivots.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    point_sum: Option<Vec3>,
}

impl PlaneLandmark {
    /// Whether every number of it is finite and its weight positive (a map
    /// file may say otherwise).
    pub fn is_valid(&self) -> bool {
        let finite = |v: &Vec3| v.iter().all(|x| x.is_finite());
        // A weight near zero divides the sums into infinities (spreads of inf).
        self.weight >= 1e-9
            && finite(&self.normal)
            && finite(&self.normal_sum)
            && self.point_sum.as_ref().is_none_or(finite)
            && [self.distance, self.distance_sum, self.distance_square_sum, self.weight].iter().all(|x| x.is_finite())
            && self.offset_spread_m().is_finite()
            && self.normal_spread_deg().is_finite()
    }

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
    /// The building's axis (radians, modulo 90 degrees): the walls of the
    /// first frame that has any, seen from the pose the map starts at.
    pub axis: Option<f64>,
}

impl PlaneMap {
    pub fn new(config: PlaneLandmarkConfig) -> Self {
        Self { config, landmarks: Vec::new(), axis: None }
    }

    /// Big enough and steep enough: a wall. Floors and ramps seen from afar,
    /// first mapped with the attitude error of that moment, pull the height
    /// more than the IMU's own pitch does (held level, a floor still did on
    /// the paper's building).
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

    /// Landmark `k`'s plane as it corrects poses: (normal, offset), squared
    /// with the building's axis when within the gate of it (turned about
    /// the centroid of its observations).
    pub fn plane(&self, k: usize) -> (Vec3, f64) {
        let l = &self.landmarks[k];
        let (Some(axis_angle), Some(point_sum)) = (self.axis, l.point_sum) else { return (l.normal, l.distance) };
        let gate = self.config.rectilinear_gate_deg.to_radians();
        if gate <= 0.0 {
            return (l.normal, l.distance);
        }
        let quarter = std::f64::consts::FRAC_PI_2;
        let angle = l.normal.y.atan2(l.normal.x);
        let turns = ((angle - axis_angle) / quarter).round();
        let squared = axis_angle + turns * quarter;
        if crate::estimation::euler::wrap(angle - squared).abs() > gate {
            return (l.normal, l.distance);
        }
        let horizontal = l.normal.x.hypot(l.normal.y);
        let normal = Vec3::new(horizontal * squared.cos(), horizontal * squared.sin(), l.normal.z);
        (normal, normal.dot(&(point_sum / l.weight)))
    }

    /// The inlier-weighted mean direction, modulo 90 degrees, of the usable
    /// planes within the gate of the largest one's.
    fn axis_of(&self, planes: &[RobotPlane], world_from_robot: &Pose3) -> Option<f64> {
        let quarter = std::f64::consts::FRAC_PI_2;
        let usable: Vec<(f64, f64)> = planes
            .iter()
            .filter(|p| self.usable(p))
            .map(|p| {
                let n = world_from_robot.rotation * p.normal;
                (n.y.atan2(n.x), p.inliers as f64)
            })
            .collect();
        let &(reference, _) = usable.iter().max_by(|a, b| a.1.total_cmp(&b.1))?;
        let gate = self.config.rectilinear_gate_deg.to_radians();
        let (mut sum, mut weight) = (0.0, 0.0);
        for (angle, w) in usable {
            let offset = angle - reference;
            let gap = crate::estimation::euler::wrap(offset - (offset / quarter).round() * quarter);
            if gap.abs() <= gate {
                sum += w * gap;
                weight += w;
            }
        }
        Some(reference + sum / weight)
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
        if self.axis.is_none() {
            self.axis = self.axis_of(planes, world_from_robot);
        }
        for (plane, a) in planes.iter().zip(association) {
            if !self.usable(plane) {
                continue;
            }
            let (mut n, mut d) = plane.in_world(world_from_robot);
            let centroid = (world_from_robot * nalgebra::Point3::from(plane.point)).coords;
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
                    if let Some(sum) = &mut l.point_sum {
                        *sum += w * centroid;
                    }
                }
                None => self.landmarks.push(PlaneLandmark {
                    normal: n,
                    distance: d,
                    observations: 1,
                    normal_sum: w * n,
                    distance_sum: w * d,
                    distance_square_sum: w * d * d,
                    weight: w,
                    point_sum: Some(w * centroid),
                }),
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A plane seen from the identity pose: normal `angle` from x (tilted up
    /// by `tilt`), through `point`.
    fn plane_at(angle: f64, tilt: f64, point: Vec3, inliers: usize) -> RobotPlane {
        let normal = Vec3::new(angle.cos() * tilt.cos(), angle.sin() * tilt.cos(), tilt.sin());
        RobotPlane { normal, point, inliers }
    }

    fn observed_three_times(map: &mut PlaneMap, planes: &[RobotPlane], pose: &Pose3) {
        for _ in 0..3 {
            let association = map.associate(planes, pose);
            map.observe(planes, &association, pose);
        }
    }

    #[test]
    fn the_first_frames_walls_set_the_axis_and_later_walls_near_it_are_squared_with_it() {
        let axis = 0.2;
        let quarter = std::f64::consts::FRAC_PI_2;
        let mut map = PlaneMap::new(PlaneLandmarkConfig::default());
        // The first frame: two walls, the smaller 0.1 degree off square; the
        // axis is their inlier-weighted mean. A third, too small to be used,
        // does not count.
        let first = [
            plane_at(axis, 0.0, Vec3::new(3.0, 0.0, 1.0), 300),
            plane_at(axis + quarter + 0.1f64.to_radians(), 0.0, Vec3::new(0.0, 2.0, 1.0), 200),
            plane_at(axis + quarter + 1f64.to_radians(), 0.0, Vec3::new(0.0, -2.0, 1.0), 100),
        ];
        observed_three_times(&mut map, &first, &Pose3::identity());
        let expected_axis = axis + 0.4 * 0.1f64.to_radians();
        assert!((map.axis.unwrap() - expected_axis).abs() < 1e-12, "{:?}", map.axis);
        // Later, a wall mapped under a 1.5 degree heading error (within the
        // 2 degree gate) and a partition 10 degrees off the axis.
        let centroid = Vec3::new(-4.0, 1.0, 1.2);
        let later = [
            plane_at(axis + 2.0 * quarter + 1.5f64.to_radians(), 0.0, centroid, 400),
            plane_at(axis + 10f64.to_radians(), 0.0, Vec3::new(1.0, -3.0, 1.0), 200),
        ];
        observed_three_times(&mut map, &later, &Pose3::identity());
        assert_eq!(map.landmarks.len(), 4, "two walls of the first frame and two later");
        let (normal, distance) = map.plane(2);
        let squared = expected_axis + 2.0 * quarter;
        assert!((normal - Vec3::new(squared.cos(), squared.sin(), 0.0)).norm() < 1e-9, "{normal}");
        assert!((distance - normal.dot(&centroid)).abs() < 1e-9, "{distance}");
        let partition = &map.landmarks[3];
        assert_eq!(map.plane(3), (partition.normal, partition.distance));
        // The gate at 0 turns it off.
        map.config.rectilinear_gate_deg = 0.0;
        assert_eq!(map.plane(2), (map.landmarks[2].normal, map.landmarks[2].distance));
    }
}
