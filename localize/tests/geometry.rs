//! Planes, corners and normals on clouds with known answers.

use datasets::math::Vec3;
use localize::config::LocalizeConfig;
use nalgebra::Point3;
use rand::rngs::ChaCha8Rng;
use rand::{RngExt, SeedableRng};

/// The package folder, read when the test runs (cargo sets it), so that a
/// test binary reused from another checkout still finds its files.
fn manifest_dir() -> std::path::PathBuf {
    std::env::var_os("CARGO_MANIFEST_DIR").map_or_else(|| env!("CARGO_MANIFEST_DIR").into(), Into::into)
}

/// Points on the inside faces of an axis-aligned room [0, 8] x [0, 5] x [0, 3]
/// with `noise` (uniform, metres) along each face's normal.
fn room(rng: &mut ChaCha8Rng, per_face: usize, noise: f32) -> Vec<Point3<f32>> {
    let (lx, ly, lz) = (8.0f32, 5.0f32, 3.0f32);
    let mut points = Vec::new();
    let n = |rng: &mut ChaCha8Rng| (rng.random::<f32>() - 0.5) * 2.0 * noise;
    for _ in 0..per_face {
        let (a, b, c) = (rng.random::<f32>(), rng.random::<f32>(), rng.random::<f32>());
        points.push(Point3::new(a * lx, b * ly, n(rng))); // floor
        points.push(Point3::new(a * lx, b * ly, lz + n(rng))); // ceiling
        points.push(Point3::new(n(rng), b * ly, c * lz)); // x = 0
        points.push(Point3::new(lx + n(rng), b * ly, c * lz)); // x = 8
        points.push(Point3::new(a * lx, n(rng), c * lz)); // y = 0
        points.push(Point3::new(a * lx, ly + n(rng), c * lz)); // y = 5
    }
    points
}

fn find(
    planes: &[localize::scan::planes::Plane],
    normal: Vec3,
    distance: f64,
) -> Option<&localize::scan::planes::Plane> {
    planes.iter().find(|p| p.normal.dot(&normal) > 0.99 && (p.distance - distance).abs() < 0.1)
}

#[test]
fn a_room_gives_its_six_planes_and_eight_corners() {
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let sensor = Vec3::new(3.0, 2.0, 1.2);
    // In the sensor's frame, as a scan would be.
    let points: Vec<Point3<f32>> = room(&mut rng, 4000, 0.01).into_iter().map(|p| p - sensor.cast::<f32>()).collect();
    let stages = LocalizeConfig::default().geometry_stages().unwrap();
    let result = stages.run(&points, &Vec3::zeros()).unwrap();
    let planes = &result.planes.planes;
    assert_eq!(planes.len(), 6, "{planes:#?}");
    // Expected planes in the sensor frame: normal pointing away from the sensor.
    let expected = [
        (Vec3::new(0.0, 0.0, -1.0), 1.2),
        (Vec3::new(0.0, 0.0, 1.0), 1.8),
        (Vec3::new(-1.0, 0.0, 0.0), 3.0),
        (Vec3::new(1.0, 0.0, 0.0), 5.0),
        (Vec3::new(0.0, -1.0, 0.0), 2.0),
        (Vec3::new(0.0, 1.0, 0.0), 3.0),
    ];
    for (normal, distance) in expected {
        let p = find(planes, normal, distance).unwrap_or_else(|| panic!("no plane {normal:?} {distance}"));
        let angle = p.normal.dot(&normal).min(1.0).acos().to_degrees();
        assert!(angle < 1.0, "plane {normal:?}: {angle} deg off");
        assert!((p.distance - distance).abs() < 0.01, "plane {normal:?}: distance {} vs {distance}", p.distance);
    }
    let corners = &result.corners.corners;
    assert_eq!(corners.len(), 8, "{corners:#?}");
    for x in [0.0, 8.0] {
        for y in [0.0, 5.0] {
            for z in [0.0, 3.0] {
                let truth = Vec3::new(x, y, z) - sensor;
                let error = corners.iter().map(|c| (c.position - truth).norm()).fold(f64::MAX, f64::min);
                assert!(error < 0.02, "corner {truth:?}: nearest found {error} m away");
            }
        }
    }
}

#[test]
fn a_ten_degree_ramp_is_a_plane_tilted_by_ten_degrees_with_an_edge_at_the_floor() {
    let mut rng = ChaCha8Rng::seed_from_u64(4);
    let slope = 10f64.to_radians();
    let mut points = Vec::new();
    for _ in 0..6000 {
        let (a, b) = (rng.random::<f64>(), rng.random::<f64>());
        // Flat floor for x in [-4, 0], ramp rising along +x for x in [0, 4].
        let x = -4.0 + 8.0 * a;
        let y = -2.0 + 4.0 * b;
        let z = if x < 0.0 { 0.0 } else { x * slope.tan() };
        let noise = (rng.random::<f64>() - 0.5) * 0.01;
        points.push(Point3::new(x as f32, y as f32, (z - 0.7 + noise) as f32));
    }
    let stages = LocalizeConfig::default().geometry_stages().unwrap();
    let result = stages.run(&points, &Vec3::zeros()).unwrap();
    let planes = &result.planes.planes;
    assert_eq!(planes.len(), 2, "{planes:#?}");
    let tilt = |p: &localize::scan::planes::Plane| p.normal.z.abs().min(1.0).acos().to_degrees();
    let mut tilts: Vec<f64> = planes.iter().map(tilt).collect();
    tilts.sort_by(f64::total_cmp);
    assert!(tilts[0] < 0.3, "floor tilted {} deg", tilts[0]);
    assert!((tilts[1] - 10.0).abs() < 0.3, "ramp tilted {} deg", tilts[1]);
    let edges = &result.corners.edges;
    assert_eq!(edges.len(), 1);
    let edge = &edges[0];
    assert!((edge.angle_deg - 10.0).abs() < 0.3);
    // The edge is the line x = 0, z = -0.7 (along y).
    assert!(edge.direction.y.abs() > 0.999, "{:?}", edge.direction);
    assert!(edge.point.x.abs() < 0.03 && (edge.point.z + 0.7).abs() < 0.01, "{:?}", edge.point);
}

#[test]
fn normals_point_toward_the_sensor() {
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let points: Vec<Point3<f32>> = room(&mut rng, 1500, 0.0).into_iter().collect();
    let sensor = Vec3::new(4.0, 2.5, 1.5);
    let grid = localize::scan::scan_grid::ScanGrid::new(&points, &sensor);
    let estimator = localize::scan::normals::NormalEstimator::new(Default::default()).unwrap();
    let normals = estimator.estimate(&points, &grid).unwrap();
    let mut facing = 0;
    for (p, n) in points.iter().zip(&normals) {
        if n.normal.dot(&(sensor - p.cast::<f64>().coords)) > 0.0 {
            facing += 1;
        }
    }
    assert_eq!(facing, points.len());
    // Mid-face points of the floor have the floor's normal.
    let floor =
        points.iter().zip(&normals).filter(|(p, _)| p.z == 0.0 && p.x > 1.0 && p.x < 7.0 && p.y > 1.0 && p.y < 4.0);
    for (_, n) in floor {
        assert!(n.normal.z > 0.999, "{:?}", n.normal);
    }
}

#[test]
fn bad_clouds_are_errors_not_panics() {
    let stages = LocalizeConfig::default().geometry_stages().unwrap();
    let empty = stages.run(&[], &Vec3::zeros());
    assert!(empty.is_err_and(|e| e.to_string().contains("no finite points")));
    let few: Vec<Point3<f32>> = (0..10).map(|i| Point3::new(i as f32, 0.0, 0.0)).collect();
    let error = stages.run(&few, &Vec3::zeros()).err().expect("10 points < 40 neighbours");
    assert!(error.to_string().contains("fewer than the 40 neighbours"), "{error}");
}

#[test]
fn real_room_scan_has_floor_ceiling_and_walls() {
    let path = manifest_dir().join("../../shared/data/pcl_room_scans/room_scan1.pcd");
    let cloud = datasets::io::formats::read_cloud(&path, datasets::io::formats::NonFinite::Drop)
        .unwrap_or_else(|e| panic!("{e} (the shared data folder is needed for this test)"));
    let stages = LocalizeConfig::default().geometry_stages().unwrap();
    let result = stages.run(&cloud.points, &Vec3::zeros()).unwrap();
    let planes = &result.planes.planes;
    // The data's README: ceiling z = +1.68 m, floor z = -1.27 m, a room about
    // 4.5 m wide along y.
    let horizontal = |d: f64| planes.iter().any(|p| p.normal.z.abs() > 0.999 && (p.distance - d).abs() < 0.05);
    assert!(horizontal(1.27), "no floor at z = -1.27: {planes:#?}");
    assert!(horizontal(1.66), "no ceiling at z = +1.68");
    let walls: Vec<&localize::scan::planes::Plane> =
        planes.iter().filter(|p| p.normal.z.abs() < 0.05 && p.inliers.len() > 1000).collect();
    assert!(walls.len() >= 3, "{walls:#?}");
    let (ny, py) = (
        walls.iter().find(|p| p.normal.y < -0.99).expect("a wall at -y"),
        walls.iter().find(|p| p.normal.y > 0.99).expect("a wall at +y"),
    );
    let width = ny.distance + py.distance;
    assert!((width - 4.5).abs() < 0.1, "room width {width}");
}
