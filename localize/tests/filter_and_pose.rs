//! The odometry/IMU filter on noiseless inputs, and the pose correction on a
//! known rigid transform.

use datasets::math::{Pose3, Vec3};
use datasets::simulator::world::motion::{MotionConfig, simulate_imu, simulate_odometry};
use localize::estimation::ekf::{Ekf, EkfConfig};
use localize::estimation::pose::{Correspondence, PoseConfig, PoseSolver};
use localize::estimation::sensor_replay::SensorReplay;
use nalgebra::{Translation3, UnitQuaternion};

/// A 2 m radius turn at 0.1 m/s that, from t = 30 s, tilts nose-up over 2 s
/// onto a 10 degree slope and keeps turning while it climbs.
fn truth(t: f64) -> Pose3 {
    let (radius, speed, slope) = (2.0, 0.1, 10f64.to_radians());
    let (start, tilt_time) = (30.0, 2.0);
    let k = slope / tilt_time;
    let tau = (t - start).max(0.0);
    let tilting = tau.min(tilt_time);
    let after = (tau - tilt_time).max(0.0);
    // Path length projected on the ground, and height gained.
    let ground = speed * t.min(start) + speed * (k * tilting).sin() / k + speed * slope.cos() * after;
    let height = speed * (1.0 - (k * tilting).cos()) / k + speed * slope.sin() * after;
    let yaw = ground / radius;
    Pose3::from_parts(
        Translation3::new(radius * yaw.sin(), radius * (1.0 - yaw.cos()), height),
        UnitQuaternion::from_euler_angles(0.0, -k * tilting, yaw),
    )
}

#[test]
fn the_filter_reproduces_the_true_path_from_noiseless_odometry_and_imu() {
    let config = MotionConfig::noiseless();
    let duration = 60.0;
    let odometry = simulate_odometry(&truth, duration, &config, 1);
    let imu = simulate_imu(&truth, duration, &config, 2);
    let mut ekf = Ekf::new(EkfConfig::default(), &truth(0.0), 0.0);
    let mut replay = SensorReplay::new(&odometry, &imu, 0.0);
    for t in [10.0, 29.0, 35.0, 45.0, 59.0] {
        replay.advance(&mut ekf, t);
        let (estimate, actual) = (ekf.pose(), truth(t));
        let error = (estimate.translation.vector - actual.translation.vector).norm();
        let angle = estimate.rotation.angle_to(&actual.rotation).to_degrees();
        // Exact on the flat turn; on the slope the accelerometer reads the
        // path's curvature as tilt, which costs about a centimetre.
        let (max_error, max_angle) = if t < 30.0 { (1e-3, 0.05) } else { (0.02, 0.5) };
        assert!(error < max_error, "t = {t}: {error} m off");
        assert!(angle < max_angle, "t = {t}: {angle} deg off");
    }
}

#[test]
fn a_correction_recovers_a_known_rigid_transform() {
    let truth =
        Pose3::from_parts(Translation3::new(2.0, -1.0, 0.3), UnitQuaternion::from_euler_angles(0.02, -0.05, 0.7));
    // The filter believes it is 25 cm and 6 degrees away, with an uncertainty to match.
    let believed =
        Pose3::from_parts(Translation3::new(2.2, -1.15, 0.3), UnitQuaternion::from_euler_angles(0.0, 0.0, 0.8));
    let mut ekf = Ekf::new(EkfConfig::default(), &believed, 0.0);
    for k in 0..3 {
        ekf.p[(k, k)] = 0.3f64.powi(2);
        ekf.p[(3 + k, 3 + k)] = 0.2f64.powi(2);
    }
    let corners = [
        Vec3::new(3.0, 1.0, -0.7),
        Vec3::new(3.0, -1.5, -0.7),
        Vec3::new(4.0, 1.0, 2.0),
        Vec3::new(-2.0, 2.0, -0.7),
        Vec3::new(5.0, -2.0, 1.0),
    ];
    let matches: Vec<Correspondence> = corners
        .iter()
        .map(|c| Correspondence { in_robot: *c, in_world: (truth * nalgebra::Point3::from(*c)).coords })
        .collect();
    let solver = PoseSolver::new(PoseConfig { corner_sigma_m: 0.001, ..PoseConfig::default() });
    let fix = solver.correct(&mut ekf, &matches).expect("five matches");
    let pose = ekf.pose();
    assert!((pose.translation.vector - truth.translation.vector).norm() < 1e-3, "{pose:?}");
    assert!(pose.rotation.angle_to(&truth.rotation) < 1e-3);
    assert_eq!(fix.inliers, 5);
    // Too few matches: the filter is left alone.
    let before = ekf.x;
    assert!(
        PoseSolver::new(PoseConfig { min_matches: 3, ..PoseConfig::default() })
            .correct(&mut ekf, &matches[..2])
            .is_none()
    );
    assert_eq!(ekf.x, before);
}

#[test]
fn walls_alone_recover_position_and_heading() {
    use localize::estimation::plane_landmarks::{PlaneLandmarkConfig, PlaneMap, RobotPlane};
    use localize::estimation::pose::{PlaneCorrespondence, PlaneSigmas};
    let truth = Pose3::from_parts(Translation3::new(1.0, 0.5, 0.0), UnitQuaternion::from_euler_angles(0.0, 0.0, 0.3));
    // Four walls of a 6 x 4 m room: (outward normal, offset) in the world.
    let walls = [
        (Vec3::new(1.0, 0.0, 0.0), 3.0),
        (Vec3::new(-1.0, 0.0, 0.0), 3.0),
        (Vec3::new(0.0, 1.0, 0.0), 2.0),
        (Vec3::new(0.0, -1.0, 0.0), 2.0),
    ];
    // What the robot sees: each wall's normal and a point of it, robot frame.
    let seen: Vec<RobotPlane> = walls
        .iter()
        .map(|(n, d)| {
            let point_world = n * *d + Vec3::new(0.0, 0.0, 1.0) + n.cross(&Vec3::z()) * 0.7;
            RobotPlane {
                normal: truth.rotation.inverse() * n,
                point: (truth.inverse() * nalgebra::Point3::from(point_world)).coords,
                inliers: 500,
            }
        })
        .collect();
    // Mapped from the true pose three times: trusted landmarks.
    let mut map = PlaneMap::new(PlaneLandmarkConfig::default());
    for _ in 0..3 {
        let association = map.associate(&seen, &truth);
        map.observe(&seen, &association, &truth);
    }
    assert_eq!(map.landmarks.len(), 4);
    assert!((0..4).all(|k| map.is_trusted(k)));
    let believed =
        Pose3::from_parts(Translation3::new(1.12, 0.42, 0.0), UnitQuaternion::from_euler_angles(0.0, 0.0, 0.33));
    let association = map.associate(&seen, &believed);
    assert!(association.iter().all(Option::is_some), "{association:?}");
    let matches: Vec<PlaneCorrespondence> = seen
        .iter()
        .zip(&association)
        .map(|(p, a)| {
            let l = &map.landmarks[a.unwrap()];
            PlaneCorrespondence {
                normal_in_robot: p.normal,
                point_in_robot: p.point,
                normal_in_world: l.normal,
                distance_in_world: l.distance,
            }
        })
        .collect();
    // Position and heading uncertain; roll and pitch known (gravity levels
    // them), as in the filter.
    let mut ekf = Ekf::new(EkfConfig::default(), &believed, 0.0);
    for k in 0..3 {
        ekf.p[(k, k)] = 0.2f64.powi(2);
    }
    ekf.p[(5, 5)] = 0.1f64.powi(2);
    let solver = PoseSolver::new(PoseConfig::default());
    solver
        .correct_with_planes(&mut ekf, &[], &matches, PlaneSigmas { distance_m: 0.001, normal_rad: 0.001 }, None)
        .expect("four walls");
    let pose = ekf.pose();
    let xy_error = (pose.translation.vector - truth.translation.vector).xy().norm();
    assert!(xy_error < 2e-3, "{xy_error} m off");
    let (_, _, yaw) = pose.rotation.euler_angles();
    assert!((yaw - 0.3).abs() < 1e-3, "yaw {yaw}");
}

#[test]
fn horizontal_only_corrections_leave_height_and_tilt_to_the_imu() {
    let truth = Pose3::from_parts(Translation3::new(2.0, -1.0, 0.3), UnitQuaternion::from_euler_angles(0.0, 0.0, 0.7));
    let believed =
        Pose3::from_parts(Translation3::new(2.1, -1.1, 0.35), UnitQuaternion::from_euler_angles(0.01, -0.02, 0.75));
    let mut ekf = Ekf::new(EkfConfig::default(), &believed, 0.0);
    for k in 0..6 {
        ekf.p[(k, k)] = 0.1f64.powi(2);
    }
    let before = ekf.x;
    let matches: Vec<Correspondence> =
        [Vec3::new(3.0, 1.0, -0.7), Vec3::new(3.0, -1.5, 0.7), Vec3::new(-2.0, 2.0, 1.0)]
            .iter()
            .map(|c| Correspondence { in_robot: *c, in_world: (truth * nalgebra::Point3::from(*c)).coords })
            .collect();
    let solver = PoseSolver::new(PoseConfig { horizontal_only: true, corner_sigma_m: 0.001, ..PoseConfig::default() });
    solver.correct(&mut ekf, &matches).expect("three matches");
    for k in [2, 3, 4] {
        assert!((ekf.x[k] - before[k]).abs() < 1e-12, "state {k} moved: {} -> {}", before[k], ekf.x[k]);
    }
    // x, y and yaw moved toward the truth.
    assert!((ekf.x[0] - 2.0).abs() < 0.05 && (ekf.x[1] + 1.0).abs() < 0.05, "{:?}", ekf.x);
    assert!((ekf.x[5] - 0.7).abs() < 0.02);
}
