//! The synthetic world checked against its own ground truth: labels project
//! onto their corners, LIDAR points lie on the surfaces, the ramps climb at
//! the configured slope, the levels sit at the configured heights, and the
//! same seed gives the same bytes.

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use datasets::io::formats::{self, NonFinite};
use datasets::math::{Point3, Pose3, Vec3};
use datasets::simulator::generate::{DatagenConfig, generate};
use datasets::simulator::world::World;
use datasets::simulator::world::labels::{LabelConfig, visible_corners};
use datasets::simulator::world::motion::{GRAVITY_MPS2, MotionConfig, heading, simulate_imu, simulate_odometry};
use datasets::simulator::world::rig::Rig;
use datasets::simulator::world::route::{Route, pose_on_floor};

/// A short, fast version of the default data: the whole route at 1 m/s, 2 Hz.
fn small_config() -> DatagenConfig {
    let mut c = DatagenConfig::default();
    c.detection.images = 6;
    c.detection.train = 4;
    c.sequence.speed_mps = 1.0;
    c.sequence.rate_hz = 2.0;
    c
}

/// One generated data set shared by the tests of this file.
fn data() -> &'static (PathBuf, DatagenConfig) {
    static DATA: OnceLock<(PathBuf, DatagenConfig)> = OnceLock::new();
    DATA.get_or_init(|| {
        let dir = tempfile::tempdir().unwrap().keep();
        let config = small_config();
        generate(&dir, &config).unwrap();
        (dir, config)
    })
}

fn world_of(config: &DatagenConfig) -> World {
    // The generator's appearance stream does not change geometry, so any seed gives the same surfaces.
    World::new(&config.world, 0)
}

#[test]
fn labels_project_onto_their_corners_and_see_them() {
    let (dir, config) = data();
    let seq = dir.join("sequence");
    let truth = formats::read_tum(&seq.join("groundtruth.txt")).unwrap();
    let calib = formats::read_calibration(&seq.join("calib.json")).unwrap();
    let labels = formats::read_coco(&seq.join("labels.json")).unwrap();
    let world = world_of(config);
    let robot_from_camera = calib.robot_from_camera();
    let mut checked = 0;
    for image in &labels.images {
        let k = (image.id - 1) as usize;
        let world_from_camera = truth.poses[k] * robot_from_camera;
        let camera_from_world = world_from_camera.inverse();
        let eye = Point3::from(world_from_camera.translation.vector);
        for a in labels.annotations_of(image.id) {
            let point = a.point.expect("corner labels carry their point");
            // The nearest projected world corner is the labeled one, to a pixel.
            let (best, distance_px) = world
                .layout
                .corners
                .iter()
                .filter_map(|c| {
                    let uv = calib.camera.project(&(camera_from_world * Point3::from(c.position)))?;
                    Some((c, ((uv[0] - point[0] as f64).powi(2) + (uv[1] - point[1] as f64).powi(2)).sqrt()))
                })
                .min_by(|a, b| a.1.total_cmp(&b.1))
                .unwrap();
            assert!(distance_px < 1.0, "label {} is {distance_px} px from the nearest corner", a.id);
            assert_eq!(a.corner_type.as_deref(), Some(best.kind.name()));
            // The box is centred on the point unless the image edge clipped it.
            let c = a.bbox();
            let side = config.labels.box_size_px;
            if c.width() == side && c.height() == side {
                assert!((c.centre()[0] - point[0]).abs() < 1e-3 && (c.centre()[1] - point[1]).abs() < 1e-3);
            }
            // Nothing hides the corner: along the ray through the labeled
            // point, the first surface is not clearly nearer than the corner.
            let corner = Point3::from(best.position);
            let ray = (world_from_camera.rotation * calib.camera.ray(point[0] as f64, point[1] as f64)).normalize();
            let distance = (corner - eye).norm();
            let first = world.cast(&eye, &ray, 1e-4, 1e3).map_or(f64::INFINITY, |h| h.t);
            assert!(
                first > distance - (0.01 * distance).max(0.02) - 0.01,
                "label {}: a surface at {first} m hides the corner at {distance} m",
                a.id
            );
            checked += 1;
        }
    }
    assert!(checked > 50, "only {checked} labels along the route");
}

#[test]
fn occluded_corners_are_not_labeled() {
    let world = world_of(&DatagenConfig::default());
    let rig = Rig::default();
    // The robot at the start of the route, facing the first box (x 2.5..3.1, y 1.3..1.9, 0.7 m high).
    let robot = pose_on_floor(&world.layout, [0.5, 1.6], 0.0).unwrap();
    let world_from_camera = robot * rig.robot_from_camera;
    let labels = visible_corners(&world, &rig.camera, &world_from_camera, &LabelConfig::default(), 0.0);
    let labeled = |p: [f64; 3]| {
        labels.iter().any(|l| {
            let c = world.layout.corners[l.corner].position;
            (0..3).all(|k| (c[k] - p[k]).abs() < 1e-9)
        })
    };
    assert!(labeled([2.5, 1.3, 0.0]) && labeled([2.5, 1.9, 0.0]), "the near bottom corners are visible");
    assert!(labeled([2.5, 1.3, 0.7]) && labeled([2.5, 1.9, 0.7]), "the near top corners are visible");
    assert!(!labeled([3.1, 1.3, 0.0]) && !labeled([3.1, 1.9, 0.0]), "the far bottom corners are behind the box");
}

#[test]
fn every_corner_is_where_three_surfaces_meet() {
    let world = world_of(&DatagenConfig::default());
    let surfaces = &world.layout.surfaces;
    assert!(world.layout.corners.len() > 60);
    for c in &world.layout.corners {
        let p = Point3::from(c.position);
        let touching: Vec<&Vec3> = surfaces
            .iter()
            .filter(|s| s.plane_distance(&p).abs() < 1e-9 && s.contains_projection(&p, 1e-6))
            .map(|s| &s.normal)
            .collect();
        // Three distinct planes: their normals span 3D.
        let spans =
            touching.iter().any(|a| touching.iter().any(|b| touching.iter().any(|c| a.cross(b).dot(c).abs() > 0.1)));
        assert!(
            spans,
            "{:?} corner at {:?} touches {} surfaces without three independent planes",
            c.kind,
            c.position,
            touching.len()
        );
    }
}

#[test]
fn lidar_points_lie_on_the_surfaces_within_the_noise() {
    let (dir, config) = data();
    let seq = dir.join("sequence");
    let truth = formats::read_tum(&seq.join("groundtruth.txt")).unwrap();
    let calib = formats::read_calibration(&seq.join("calib.json")).unwrap();
    let world = world_of(config);
    let sigma = config.lidar.range_noise_m;
    let mut distances = Vec::new();
    for k in (0..truth.len()).step_by(7) {
        let name = datasets::io::formats::stamped_files::stamp_name(truth.stamps[k]);
        let cloud = formats::read_cloud(&seq.join("cloud").join(format!("{name}.pcd")), NonFinite::Reject).unwrap();
        assert!(cloud.len() > 8 * 1000, "frame {k}: {} points", cloud.len());
        let world_from_lidar = truth.poses[k] * calib.robot_from_lidar;
        for p in cloud.points.iter().step_by(5) {
            let q = world_from_lidar * Point3::new(p.x as f64, p.y as f64, p.z as f64);
            let d = world
                .layout
                .surfaces
                .iter()
                .filter(|s| s.contains_projection(&q, 0.15))
                .map(|s| s.plane_distance(&q).abs())
                .fold(f64::INFINITY, f64::min);
            distances.push(d);
        }
    }
    let n = distances.len() as f64;
    let rms = (distances.iter().map(|d| d * d).sum::<f64>() / n).sqrt();
    let within = distances.iter().filter(|&&d| d < 4.0 * sigma).count() as f64 / n;
    assert!(rms < 1.2 * sigma, "RMS distance {rms} m for range noise {sigma} m");
    assert!(within > 0.995, "only {:.2}% of points within 4 sigma", within * 100.0);
}

#[test]
fn ramps_climb_at_the_configured_slope() {
    let (dir, config) = data();
    let truth = formats::read_tum(&dir.join("sequence/groundtruth.txt")).unwrap();
    let world = world_of(config);
    let on_ramp: Vec<bool> = truth
        .poses
        .iter()
        .map(|p| {
            let v = p.translation.vector;
            let h = heading(p);
            // All four wheels on the ramp.
            [(0.2, 0.0), (-0.2, 0.0), (0.0, 0.2), (0.0, -0.2)].iter().all(|(f, l)| {
                let (x, y) = (v.x + h.cos() * f - h.sin() * l, v.y + h.sin() * f + h.cos() * l);
                world.layout.region_at(x, y).is_some_and(|r| r.level.is_none())
            })
        })
        .collect();
    let mut slopes = Vec::new();
    for k in 1..truth.len() {
        if on_ramp[k] && on_ramp[k - 1] {
            let (a, b) = (truth.poses[k - 1].translation.vector, truth.poses[k].translation.vector);
            slopes.push(((b.z - a.z) / (b.xy() - a.xy()).norm()).atan().to_degrees());
        }
        if on_ramp[k] {
            let forward = truth.poses[k].rotation * Vec3::x();
            slopes.push(forward.z.asin().to_degrees());
        }
    }
    assert!(slopes.len() >= 4, "{} ramp samples", slopes.len());
    for s in slopes {
        assert!((s - config.world.ramp_slope_deg).abs() < 0.01, "slope {s} deg");
    }
}

#[test]
fn the_route_visits_three_levels_at_their_heights() {
    let (dir, config) = data();
    let truth = formats::read_tum(&dir.join("sequence/groundtruth.txt")).unwrap();
    // Heights where the robot stands level for several frames.
    let mut plateaus: Vec<f64> = Vec::new();
    for w in truth.poses.windows(3) {
        let z: Vec<f64> = w.iter().map(|p| p.translation.vector.z).collect();
        if (z[0] - z[1]).abs() < 1e-9 && (z[1] - z[2]).abs() < 1e-9 && !plateaus.iter().any(|p| (p - z[0]).abs() < 1e-6)
        {
            plateaus.push(z[0]);
        }
    }
    plateaus.sort_by(f64::total_cmp);
    assert_eq!(plateaus.len(), 3, "plateaus {plateaus:?}");
    for (p, h) in plateaus.iter().zip(config.world.level_heights_m) {
        assert!((p - h).abs() < 1e-9, "level at {p} m, configured {h} m");
    }
}

fn files_under(dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    for entry in std::fs::read_dir(dir).unwrap() {
        let path = entry.unwrap().path();
        if path.is_dir() { out.extend(files_under(&path)) } else { out.push(path) }
    }
    out.sort();
    out
}

#[test]
fn same_seed_same_bytes_other_seed_other_images() {
    let mut config = DatagenConfig::default();
    config.detection.images = 3;
    config.detection.train = 2;
    config.sequence.frames = Some(3);
    let (a, b, c) = (tempfile::tempdir().unwrap(), tempfile::tempdir().unwrap(), tempfile::tempdir().unwrap());
    generate(a.path(), &config).unwrap();
    generate(b.path(), &config).unwrap();
    let files = files_under(a.path());
    assert!(files.len() > 15);
    for f in &files {
        let rel = f.strip_prefix(a.path()).unwrap();
        assert_eq!(std::fs::read(f).unwrap(), std::fs::read(b.path().join(rel)).unwrap(), "{} differs", rel.display());
    }
    config.seed += 1;
    generate(c.path(), &config).unwrap();
    let image = "detection/images/000000.png";
    assert_ne!(std::fs::read(a.path().join(image)).unwrap(), std::fs::read(c.path().join(image)).unwrap());
    // No temporary files are left behind.
    assert!(files.iter().all(|f| !f.file_name().unwrap().to_string_lossy().starts_with(".tmp")));
}

#[test]
fn detection_set_has_the_requested_splits_and_canny_inputs() {
    let (dir, config) = data();
    let det = dir.join("detection");
    let train = formats::read_coco(&det.join("train.json")).unwrap();
    let test = formats::read_coco(&det.join("test.json")).unwrap();
    assert_eq!(
        (train.images.len(), test.images.len()),
        (config.detection.train, config.detection.images - config.detection.train)
    );
    for im in train.images.iter().chain(&test.images) {
        let rgb = datasets::atomic::read_image(&det.join(&im.file_name)).unwrap();
        assert_eq!((rgb.width(), rgb.height()), (640, 480));
        let canny =
            datasets::atomic::read_image(&det.join(im.file_name.replace("images/", "canny/"))).unwrap().to_luma8();
        assert_eq!(canny.dimensions(), (224, 224));
        let edges = canny.pixels().filter(|p| p[0] > 0).count();
        assert!(edges > 200 && edges < 224 * 224 / 3, "{edges} edge pixels in {}", im.file_name);
    }
}

#[test]
fn noiseless_odometry_follows_the_route_and_the_imu_feels_the_ramp() {
    let config = DatagenConfig::default();
    let world = world_of(&config);
    let route = Route::new(&world.layout.route, config.sequence.turn_radius_m);
    let speed = 0.5;
    let pose_at = |t: f64| -> Pose3 {
        let (xy, h) = route.at(speed * t.max(0.0));
        pose_on_floor(&world.layout, xy, h).unwrap()
    };
    let silent = MotionConfig::noiseless();
    // Level 1 is flat and straight: odometry equals the truth there.
    let odo = simulate_odometry(&pose_at, 60.0, &silent, 1);
    for s in odo.iter().filter(|s| s.timestamp <= 14.0) {
        let truth = pose_at(s.timestamp).translation.vector;
        assert!(
            (s.x - truth.x).abs() < 1e-6 && (s.y - truth.y).abs() < 1e-6,
            "t {}: {} vs {}",
            s.timestamp,
            s.x,
            truth.x
        );
    }
    // On the flat, the IMU feels gravity only; on the first ramp, gravity tilts forward by the slope.
    let imu = simulate_imu(&pose_at, 40.0, &silent, 1);
    let slope = config.world.ramp_slope_deg.to_radians();
    let ramp_x = (7.5 + 0.2, 7.5 + config.world.ramp_run(0.5) - 0.2);
    for s in &imu {
        let x = pose_at(s.timestamp).translation.vector.x;
        // (The first samples see the start from standstill.)
        if x < 7.0 && s.timestamp > 0.05 {
            assert!((s.accel[2] - GRAVITY_MPS2).abs() < 1e-6 && s.accel[0].abs() < 1e-6 && s.gyro[1].abs() < 1e-9);
        }
        if x > ramp_x.0 + 0.1 && x < ramp_x.1 - 0.1 {
            assert!((s.accel[0] - GRAVITY_MPS2 * slope.sin()).abs() < 1e-6, "ax {} on the ramp", s.accel[0]);
        }
    }
    // With the default noise, odometry drifts but stays plausible.
    let noisy = simulate_odometry(&pose_at, 56.0, &MotionConfig::default(), 3);
    let end = noisy.last().unwrap();
    let truth = pose_at(end.timestamp).translation.vector;
    let drift = ((end.x - truth.x).powi(2) + (end.y - truth.y).powi(2)).sqrt();
    assert!(drift > 1e-3 && drift < 2.0, "drift {drift} m after {} m", speed * 56.0);
}
