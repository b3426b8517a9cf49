//! Where a new sequence starts in a saved map: the first scan's planar
//! points scored against the point map at candidate poses (around every
//! keyframe of the run that built the map, at every heading), the best few
//! refined by scan-to-map registration, and the winner accepted only when
//! enough of the scan agrees with the map and no distinct placement agrees
//! nearly as well (a corridor's far end looks like its near end).

use datasets::InvalidSetting;
use datasets::math::{Pose3, Vec3};
use nalgebra::{Matrix6, Vector6};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::estimation::euler::{rotation, wrap};
use crate::estimation::point_map::PointMap;
use crate::estimation::scan_match::{ScanMatchConfig, ScanMatcher, ScanPoints};

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RelocalizeConfig {
    /// Candidate positions: each keyframe and a grid around it this far out
    /// (the start must be about this close to where the mapping run drove).
    pub search_radius_m: f64,
    /// The grid's spacing; registration converges from about half of it.
    pub grid_m: f64,
    /// Headings tried at each position.
    pub yaw_step_deg: f64,
    /// Scan points scored per candidate (an even sample of the scan's).
    pub sample_points: usize,
    /// A scan point agrees with the map when its plane is this close.
    pub agree_m: f64,
    /// Candidates refined by registration, best scores first.
    pub refine: usize,
    /// The least fraction of the scan's wall points (surfaces within 45
    /// degrees of vertical; a floor agrees anywhere on its level) that must
    /// agree with the map.
    pub min_agreement: f64,
    /// A distinct placement agreeing this well relative to the best makes the
    /// start ambiguous.
    pub ambiguity_ratio: f64,
    /// Placements farther apart than this (or `distinct_deg` in heading) are distinct.
    pub distinct_m: f64,
    pub distinct_deg: f64,
    /// Spacing of the keyframes a run keeps in its map (also on turns of `keyframe_turn_deg`).
    pub keyframe_m: f64,
    pub keyframe_turn_deg: f64,
}

impl Default for RelocalizeConfig {
    fn default() -> Self {
        Self {
            search_radius_m: 1.0,
            grid_m: 0.5,
            yaw_step_deg: 10.0,
            sample_points: 300,
            agree_m: 0.1,
            refine: 12,
            min_agreement: 0.5,
            ambiguity_ratio: 0.9,
            distinct_m: 1.0,
            distinct_deg: 20.0,
            keyframe_m: 1.0,
            keyframe_turn_deg: 30.0,
        }
    }
}

impl RelocalizeConfig {
    pub fn validate(&self) -> Result<(), InvalidSetting> {
        let (positive, count) = (InvalidSetting::positive, InvalidSetting::count);
        InvalidSetting::non_negative("search_radius_m", self.search_radius_m, 20.0)?;
        positive("grid_m", self.grid_m, 5.0)?;
        positive("yaw_step_deg", self.yaw_step_deg, 90.0)?;
        count("sample_points", self.sample_points, 10, 100_000)?;
        positive("agree_m", self.agree_m, 2.0)?;
        count("refine", self.refine, 1, 1000)?;
        positive("min_agreement", self.min_agreement, 1.0)?;
        positive("ambiguity_ratio", self.ambiguity_ratio, 1.0)?;
        positive("distinct_m", self.distinct_m, 100.0)?;
        positive("distinct_deg", self.distinct_deg, 180.0)?;
        positive("keyframe_m", self.keyframe_m, 100.0)?;
        positive("keyframe_turn_deg", self.keyframe_turn_deg, 180.0)
    }
}

/// Where the first scan was placed, and how sure that is.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Placement {
    /// World (the map's frame) from robot.
    #[serde(serialize_with = "serialize_pose")]
    pub pose: Pose3,
    /// Fraction of the scan's wall points that agree with the map there.
    pub agreement: f64,
    /// The best distinct placement's agreement (0 when there is none).
    pub runner_up: f64,
    pub candidates: usize,
    /// Covariance of the pose (x, y, z, roll, pitch, yaw): the final
    /// registration's, bounded by the search (a direction the scan does not
    /// observe, a corridor's axis, is as uncertain as the search was wide).
    #[serde(skip)]
    pub covariance: Matrix6<f64>,
}

fn serialize_pose<S: serde::Serializer>(pose: &Pose3, s: S) -> std::result::Result<S::Ok, S::Error> {
    crate::map_output::pose_array(pose).serialize(s)
}

/// The poses a run keeps for relocalization: the first, then one whenever
/// the robot has moved `keyframe_m` or turned `keyframe_turn_deg` since the
/// last kept.
pub fn keyframes_along(poses: &[Pose3], config: &RelocalizeConfig) -> Vec<Pose3> {
    let mut kept: Vec<Pose3> = Vec::new();
    for pose in poses {
        let far_enough = kept.last().is_none_or(|last| {
            (pose.translation.vector - last.translation.vector).norm() >= config.keyframe_m
                || pose.rotation.angle_to(&last.rotation).to_degrees() >= config.keyframe_turn_deg
        });
        if far_enough {
            kept.push(*pose);
        }
    }
    kept
}

/// Where `scan` (robot frame) lies in `map`, searched around `seeds`
/// (keyframes, or a start the user gave) at headings within
/// `yaw_window_deg` of each seed's (180: all). The error says why none was
/// accepted.
pub fn relocalize(
    map: &PointMap,
    scan: &ScanPoints,
    seeds: &[Pose3],
    yaw_window_deg: f64,
    matching: &ScanMatchConfig,
    config: &RelocalizeConfig,
) -> Result<Placement, String> {
    if seeds.is_empty() {
        return Err("the map keeps no keyframes to search from (a map of an older version): give --start-pose".into());
    }
    // Scored on walls only: a floor agrees with any place on its level.
    let walls = upright(scan);
    if walls.points.len() < matching.min_correspondences {
        return Err(format!("the first scan has {} points on walls, too few to place", walls.points.len()));
    }
    let sample = even_sample(&walls, config.sample_points);
    let candidates = candidates(seeds, yaw_window_deg, config);
    let mut scored: Vec<(f64, Vector6<f64>)> =
        candidates.par_iter().map(|c| (agreement(map, &sample, c, matching, config.agree_m), *c)).collect();
    scored.sort_by(|a, b| b.0.total_cmp(&a.0));
    // The best few distinct candidates, each refined by registration.
    let mut starts: Vec<Vector6<f64>> = Vec::new();
    for (_, c) in &scored {
        if starts.len() >= config.refine {
            break;
        }
        if starts.iter().all(|s| !same_place(s, c, config.grid_m, config.yaw_step_deg)) {
            starts.push(*c);
        }
    }
    let refiner = ScanMatcher::new(ScanMatchConfig { iterations: 30, horizontal_only: false, ..matching.clone() })
        .map_err(|e| e.to_string())?;
    let mut refined: Vec<(f64, Vector6<f64>, Matrix6<f64>)> = starts
        .par_iter()
        .map(|s| {
            let (x, information) =
                refiner.register(map, None, scan, s).map_or((*s, Matrix6::zeros()), |f| (f.pose, f.information));
            (agreement(map, &walls, &x, matching, config.agree_m), x, information)
        })
        .collect();
    refined.sort_by(|a, b| b.0.total_cmp(&a.0));
    let (best_score, best, information) = refined[0];
    let runner = refined.iter().skip(1).find(|(_, x, _)| !same_place(x, &best, config.distinct_m, config.distinct_deg));
    let runner_up = runner.map_or(0.0, |r| r.0);
    let place =
        |x: &Vector6<f64>| format!("({:.2}, {:.2}, {:.2}) m, heading {:.0} deg", x[0], x[1], x[2], x[5].to_degrees());
    if best_score < config.min_agreement {
        return Err(format!(
            "at best {:.0}% of the first scan agrees with the map (at {}), below the {:.0}% required: \
             is this the same building, and does the sequence start within {} m of the mapping run's route?",
            100.0 * best_score,
            place(&best),
            100.0 * config.min_agreement,
            config.search_radius_m
        ));
    }
    if let Some((score, x, _)) = runner
        && *score >= config.ambiguity_ratio * best_score
    {
        return Err(format!(
            "ambiguous: {:.0}% of the first scan agrees with the map at {}, but {:.0}% at {}: \
             give --start-pose near the right one",
            100.0 * best_score,
            place(&best),
            100.0 * score,
            place(x)
        ));
    }
    let pose = crate::estimation::ekf::pose_from_entries(&best);
    let (metres, radians) = (config.search_radius_m.max(config.grid_m), config.yaw_step_deg.to_radians());
    let (m, r) = (metres.powi(-2), radians.powi(-2));
    let search = Matrix6::from_diagonal(&Vector6::new(m, m, m, r, r, r));
    let covariance = (information + search).try_inverse().unwrap_or_else(|| search.map(|v| 1.0 / v));
    Ok(Placement { pose, agreement: best_score, runner_up, candidates: candidates.len(), covariance })
}

/// Every grid position within the search radius of every seed (its height,
/// roll and pitch kept: a seed on a ramp is tilted) at every heading of the window.
fn candidates(seeds: &[Pose3], yaw_window_deg: f64, config: &RelocalizeConfig) -> Vec<Vector6<f64>> {
    let steps = (config.search_radius_m / config.grid_m + 1e-9).floor() as i64;
    let yaw_steps = ((yaw_window_deg / config.yaw_step_deg) + 1e-9).floor() as i64;
    let full_turn = yaw_window_deg >= 180.0;
    let mut out = Vec::new();
    for seed in seeds {
        let (roll, pitch, yaw) = seed.rotation.euler_angles();
        let t = seed.translation.vector;
        for i in -steps..=steps {
            for j in -steps..=steps {
                let (dx, dy) = (i as f64 * config.grid_m, j as f64 * config.grid_m);
                if dx.hypot(dy) > config.search_radius_m + 1e-9 {
                    continue;
                }
                let headings: Vec<f64> = if full_turn {
                    let n = (360.0 / config.yaw_step_deg).round().max(1.0) as usize;
                    (0..n).map(|k| yaw + (k as f64 * 360.0 / n as f64).to_radians()).collect()
                } else {
                    (-yaw_steps..=yaw_steps).map(|k| yaw + (k as f64 * config.yaw_step_deg).to_radians()).collect()
                };
                for heading in headings {
                    out.push(Vector6::new(t.x + dx, t.y + dy, t.z, roll, pitch, wrap(heading)));
                }
            }
        }
    }
    out
}

/// The points whose surface is within 45 degrees of vertical.
fn upright(scan: &ScanPoints) -> ScanPoints {
    let (points, normals) =
        scan.points.iter().zip(&scan.normals).filter(|(_, n)| n.z.abs() < std::f64::consts::FRAC_1_SQRT_2).unzip();
    ScanPoints { points, normals, edges: Vec::new() }
}

/// Every k-th point of the scan, about `count` of them.
fn even_sample(scan: &ScanPoints, count: usize) -> ScanPoints {
    let stride = scan.points.len().div_ceil(count).max(1);
    ScanPoints {
        points: scan.points.iter().step_by(stride).copied().collect(),
        normals: scan.normals.iter().step_by(stride).copied().collect(),
        edges: Vec::new(),
    }
}

/// The fraction of `scan`'s points that, placed by `x`, lie within `agree_m`
/// of a map plane facing their way.
fn agreement(map: &PointMap, scan: &ScanPoints, x: &Vector6<f64>, matching: &ScanMatchConfig, agree_m: f64) -> f64 {
    let r = rotation(x[3], x[4], x[5]);
    let t = Vec3::new(x[0], x[1], x[2]);
    let cos_gate = matching.max_normal_angle_deg.to_radians().cos();
    let agreeing = scan
        .points
        .iter()
        .zip(&scan.normals)
        .filter(|(p, n)| {
            let q = t + r * *p;
            map.nearest_plane(&q, matching.max_distance_m).is_some_and(|m| {
                m.normal.dot(&(r * *n)) >= cos_gate && m.normal.dot(&(q - m.centroid)).abs() <= agree_m
            })
        })
        .count();
    agreeing as f64 / scan.points.len().max(1) as f64
}

fn same_place(a: &Vector6<f64>, b: &Vector6<f64>, metres: f64, degrees: f64) -> bool {
    let d = a - b;
    d.fixed_rows::<3>(0).norm() < metres && wrap(d[5]).abs().to_degrees() < degrees
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::rngs::ChaCha8Rng;
    use rand::{RngExt, SeedableRng};

    /// Points and normals on the walls and floor of an L-shaped room (no
    /// symmetry that maps it onto itself), in the world frame.
    fn l_room(rng: &mut ChaCha8Rng) -> (Vec<Vec3>, Vec<Vec3>) {
        // Outline: (0,0) (8,0) (8,3) (3,3) (3,7) (0,7).
        let corners = [[0.0, 0.0], [8.0, 0.0], [8.0, 3.0], [3.0, 3.0], [3.0, 7.0], [0.0, 7.0]];
        let (mut points, mut normals) = (Vec::new(), Vec::new());
        for k in 0..corners.len() {
            let (a, b): ([f64; 2], [f64; 2]) = (corners[k], corners[(k + 1) % corners.len()]);
            let length = (b[0] - a[0]).hypot(b[1] - a[1]);
            // Inward normal of a counter-clockwise outline.
            let normal = Vec3::new(-(b[1] - a[1]) / length, (b[0] - a[0]) / length, 0.0);
            for _ in 0..(length * 150.0) as usize {
                let s = rng.random_range(0.0..1.0);
                let z = rng.random_range(0.0..2.5);
                points.push(Vec3::new(a[0] + s * (b[0] - a[0]), a[1] + s * (b[1] - a[1]), z));
                normals.push(normal);
            }
        }
        for _ in 0..3000 {
            let p = Vec3::new(rng.random_range(0.0..8.0), rng.random_range(0.0..7.0), 0.0);
            if p.x > 3.0 && p.y > 3.0 {
                continue;
            }
            points.push(p);
            normals.push(Vec3::z());
        }
        (points, normals)
    }

    fn map_of(points: &[Vec3], normals: &[Vec3]) -> PointMap {
        let mut map = PointMap::new(0.5, 20, 0.05);
        map.insert(points, normals, &Pose3::identity());
        map
    }

    #[test]
    fn the_first_scan_is_placed_where_it_was_taken_from_a_keyframe_a_metre_away() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let (points, normals) = l_room(&mut rng);
        let map = map_of(&points, &normals);
        // The robot stands at (1.7, 4.6) facing 130 degrees; it sees the points
        // within 6 m, in its own frame, with 1 cm of noise.
        let truth = Pose3::from_parts(Vec3::new(1.7, 4.6, 0.0).into(), rotation(0.0, 0.0, 130f64.to_radians()));
        let inverse = truth.inverse();
        let mut scan = ScanPoints::default();
        for (p, n) in points.iter().zip(&normals).step_by(3) {
            if (p - truth.translation.vector).norm() < 6.0 {
                let noise = Vec3::new(rng.random_range(-0.01..0.01), rng.random_range(-0.01..0.01), 0.0);
                scan.points.push((inverse * nalgebra::Point3::from(*p)).coords + noise);
                scan.normals.push(inverse.rotation * n);
            }
        }
        // Keyframes of an earlier run: along x at y = 1.5, then up the L's arm.
        let keyframes: Vec<Pose3> =
            [[1.0, 1.5, 0.0], [2.0, 1.5, 0.0], [1.5, 2.5, 90.0], [1.5, 3.5, 90.0], [1.5, 5.5, 90.0]]
                .iter()
                .map(|k| Pose3::from_parts(Vec3::new(k[0], k[1], 0.0).into(), rotation(0.0, 0.0, k[2].to_radians())))
                .collect();
        let config = RelocalizeConfig::default();
        let placed = relocalize(&map, &scan, &keyframes, 180.0, &ScanMatchConfig::default(), &config).unwrap();
        let error = truth.inverse() * placed.pose;
        assert!(error.translation.vector.norm() < 0.03, "placed at {:?}", placed.pose);
        assert!(error.rotation.angle() < 0.5f64.to_radians(), "heading off by {} rad", error.rotation.angle());
        assert!(placed.agreement > 0.9 && placed.runner_up < 0.9 * placed.agreement, "{placed:?}");
        // Searched from keyframes too far away, it is refused, not misplaced.
        let far = [Pose3::from_parts(Vec3::new(6.5, 1.5, 0.0).into(), rotation(0.0, 0.0, 0.0))];
        let refused = relocalize(&map, &scan, &far, 180.0, &ScanMatchConfig::default(), &config);
        assert!(refused.as_ref().is_err_and(|e| e.contains("agrees with the map")), "{refused:?}");
    }

    #[test]
    fn a_long_corridor_start_is_ambiguous_and_said_to_be() {
        // Two parallel walls and a floor, 40 m long: every place along it looks the same.
        let mut rng = ChaCha8Rng::seed_from_u64(4);
        let (mut points, mut normals) = (Vec::new(), Vec::new());
        for _ in 0..20_000 {
            let x = rng.random_range(0.0..40.0);
            let z = rng.random_range(0.0..2.5);
            let side = if rng.random_bool(0.5) { 1.0 } else { -1.0 };
            points.push(Vec3::new(x, side * 1.1, z));
            normals.push(Vec3::new(0.0, -side, 0.0));
            points.push(Vec3::new(x, rng.random_range(-1.1..1.1), 0.0));
            normals.push(Vec3::z());
        }
        let map = map_of(&points, &normals);
        let scan = ScanPoints {
            points: points.iter().filter(|p| (p.x - 20.0).abs() < 5.0).map(|p| p - Vec3::new(20.0, 0.0, 0.0)).collect(),
            normals: points.iter().zip(&normals).filter(|(p, _)| (p.x - 20.0).abs() < 5.0).map(|(_, n)| *n).collect(),
            edges: Vec::new(),
        };
        let keyframes: Vec<Pose3> =
            (0..40).map(|k| Pose3::from_parts(Vec3::new(k as f64, 0.0, 0.0).into(), rotation(0.0, 0.0, 0.0))).collect();
        let placed =
            relocalize(&map, &scan, &keyframes, 180.0, &ScanMatchConfig::default(), &RelocalizeConfig::default());
        assert!(placed.as_ref().is_err_and(|e| e.starts_with("ambiguous")), "{placed:?}");
    }

    #[test]
    fn keyframes_are_kept_every_metre_and_on_turns() {
        let config = RelocalizeConfig::default();
        let pose = |x: f64, yaw_deg: f64| {
            Pose3::from_parts(Vec3::new(x, 0.0, 0.0).into(), rotation(0.0, 0.0, yaw_deg.to_radians()))
        };
        // 0.25 m steps for 3 m, then a turn on the spot in 11 degree steps.
        let mut poses: Vec<Pose3> = (0..=12).map(|k| pose(0.25 * k as f64, 0.0)).collect();
        poses.extend((1..=9).map(|k| pose(3.0, 11.0 * k as f64)));
        let kept = keyframes_along(&poses, &config);
        let xs: Vec<f64> = kept.iter().map(|p| p.translation.vector.x).collect();
        assert_eq!(xs, vec![0.0, 1.0, 2.0, 3.0, 3.0, 3.0, 3.0]);
        let yaws: Vec<f64> = kept[3..].iter().map(|p| p.rotation.euler_angles().2.to_degrees().round()).collect();
        assert_eq!(yaws, vec![0.0, 33.0, 66.0, 99.0]);
    }
}
