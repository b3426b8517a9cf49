//! End to end across crates: a generated sequence localized by the
//! `localize` crate, with the shipped detector and with ground-truth corners.

use datasets::simulator::generate::{DatagenConfig, generate};
use localize::config::LocalizeConfig;
use localize::input::corner_source::CornerSource;
use localize::input::sequence::RecordedSequence;
use localize::run::{MapStart, metrics, run_sequence, run_sequence_in_map, truth_in_run_frame, write_outputs};

/// The package folder, read when the test runs (cargo sets it), so that a
/// test binary reused from another checkout still finds its files.
fn manifest_dir() -> std::path::PathBuf {
    std::env::var_os("CARGO_MANIFEST_DIR").map_or_else(|| env!("CARGO_MANIFEST_DIR").into(), Into::into)
}

fn short_sequence(dir: &std::path::Path, frames: usize) -> RecordedSequence {
    short_sequence_with(dir, frames, &|_| {})
}

/// As `short_sequence`, with `change` applied to the settings.
fn short_sequence_with(dir: &std::path::Path, frames: usize, change: &dyn Fn(&mut DatagenConfig)) -> RecordedSequence {
    let mut config = DatagenConfig::default();
    config.detection.images = 2;
    config.detection.train = 1;
    config.sequence.frames = Some(frames);
    // Ten times the paper's speed: 0.5 m between frames, the first 15 m of
    // the route (the first level, the first ramp and part of the second level).
    config.sequence.speed_mps = 0.5;
    change(&mut config);
    generate(dir, &config).unwrap();
    RecordedSequence::open(&dir.join("sequence")).unwrap()
}

#[test]
fn fused_localization_beats_odometry_and_imu_on_a_generated_route() {
    let dir = tempfile::tempdir().unwrap();
    let sequence = short_sequence(dir.path(), 30);
    let mut corners = CornerSource::labels(&dir.path().join("sequence/labels.json"), 2.0, 1).unwrap();
    let config = LocalizeConfig::default();
    let result = run_sequence(&sequence, &mut corners, &config, false).unwrap();
    let m = metrics(&sequence, &result).unwrap().expect("ground truth is there");
    assert_eq!(m.frames, 30);
    let (fused, odometry) = (m.fused.overall, m.odometry_imu.overall);
    assert!(fused.ate_rmse < 0.05, "fused ATE {} m", fused.ate_rmse);
    assert!(fused.ate_rmse < odometry.ate_rmse / 2.0, "fused {} vs odometry/IMU {}", fused.ate_rmse, odometry.ate_rmse);
    assert!(m.fused.levels.iter().any(|l| l.name == "ramps"), "{:?}", m.fused.levels);
    let out = dir.path().join("run");
    write_outputs(&out, &config, &result, sequence.ground_truth.as_ref(), Some(&m)).unwrap();
    for file in ["trajectory.txt", "reference.txt", "frames.csv", "metrics.json", "trajectory.png", "config.json"] {
        assert!(out.join(file).is_file(), "{file} missing");
    }
    let (written, _) = datasets::io::formats::read_trajectory(&out.join("trajectory.txt")).unwrap();
    assert_eq!(written.len(), 30);
    // The map: the point map and the corner landmarks, read back by the PLY reader.
    let map = datasets::io::formats::read_ply(&out.join("map.ply"), datasets::io::formats::NonFinite::Reject).unwrap();
    assert!(result.point_map.len() > 1000, "{} map points", result.point_map.len());
    assert_eq!(map.len(), result.point_map.len() + result.corner_landmarks.len());
    let first = result.point_map[0].position;
    assert!((map.points[0].cast::<f64>().coords - first).norm() < 1e-5);
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("map.json")).unwrap()).unwrap();
    assert_eq!(summary["points"], result.point_map.len());
    assert_eq!(summary["walls"].as_array().unwrap().len(), result.plane_landmarks.len());
    // The route again in that map: its first frame is placed by the map, not taken as the start.
    let saved = localize::map_output::read_map(&out).unwrap();
    assert_eq!(saved.points, result.point_map.iter().map(round_to_f32).collect::<Vec<_>>());
    let in_map = Some(MapStart { map: saved, start: None });
    let again = run_sequence_in_map(&sequence, &mut CornerSource::Off, &config, in_map, false).unwrap();
    let placed = again.placement.expect("the first scan is placed in the map");
    assert!(placed.pose.translation.vector.norm() < 0.03, "placed at {:?}", placed.pose);
    assert!(again.frames[0].scan_correspondences >= 50, "{}", again.frames[0].status.label());
    assert!(!matches!(again.frames[0].status, localize::estimation::pipeline::FrameStatus::FirstFrame));
    let m = metrics(&sequence, &again).unwrap().unwrap();
    assert!(m.fused.overall.ate_rmse < 0.05, "in the map, without the camera: ATE {} m", m.fused.overall.ate_rmse);
}

#[test]
fn a_sequence_that_starts_elsewhere_is_placed_in_an_earlier_runs_map() {
    let dir = tempfile::tempdir().unwrap();
    // The map: the first 15 m of the route, LIDAR and odometry/IMU only.
    let mapping = short_sequence(&dir.path().join("mapping"), 30);
    let config = LocalizeConfig::default();
    let built = run_sequence(&mapping, &mut CornerSource::Off, &config, false).unwrap();
    let out = dir.path().join("map-run");
    write_outputs(&out, &config, &built, truth_in_run_frame(&mapping, &built).as_ref(), None).unwrap();
    let map = localize::map_output::read_map(&out).unwrap();
    assert!(map.keyframes.len() >= 12, "{} keyframes along 15 m", map.keyframes.len());
    assert_eq!(map.truth_origin, Some(datasets::math::Pose3::identity()));
    // Another day: other noise and people, the robot starting 6.3 m along the route.
    let later = short_sequence_with(&dir.path().join("later"), 14, &|c| {
        c.seed = 8;
        c.sequence.start_m = 6.3;
    });
    let first_truth = later.ground_truth.as_ref().unwrap().poses[0];
    assert!((first_truth.translation.vector.x - 6.3).abs() < 1e-9, "{first_truth:?}");
    let in_map = Some(MapStart { map: map.clone(), start: None });
    let run = run_sequence_in_map(&later, &mut CornerSource::Off, &config, in_map, false).unwrap();
    let placed = run.placement.expect("placed");
    let error = first_truth.inverse() * placed.pose;
    assert!(error.translation.vector.norm() < 0.05, "placed {:?}, truth {first_truth:?}", placed.pose);
    assert!(error.rotation.angle() < 1f64.to_radians(), "heading off by {} rad", error.rotation.angle());
    let m = metrics(&later, &run).unwrap().expect("the map knows its ground-truth origin");
    assert!(m.fused.overall.ate_rmse < 0.05, "in the map: ATE {} m", m.fused.overall.ate_rmse);
    // Per level: the levels under the robot's true positions in the building.
    let levels = localize::evaluation::levels::LevelMap::read(&dir.path().join("later/sequence/world.json")).unwrap();
    let mut expected: Vec<String> =
        later.ground_truth.as_ref().unwrap().positions().filter_map(|p| levels.segment_at(p.x, p.y)).collect();
    expected.sort();
    expected.dedup();
    let names: Vec<String> = m.fused.levels.iter().map(|l| l.name.clone()).collect();
    assert_eq!(names, expected);
    // A start given where the map has nothing (30 m off the route) is searched only near there: refused.
    let wrong =
        datasets::math::Pose3::from_parts(datasets::math::Vec3::new(6.3, 30.0, 0.0).into(), first_truth.rotation);
    let refused =
        run_sequence_in_map(&later, &mut CornerSource::Off, &config, Some(MapStart { map, start: Some(wrong) }), false);
    let why = match refused {
        Ok(r) => panic!("placed at {:?}", r.placement),
        Err(e) => e.to_string(),
    };
    assert!(why.contains("placing the first scan") && why.contains("agrees with the map"), "{why}");
}

/// A map point as `map.ply` stores it (single precision).
fn round_to_f32(p: &localize::estimation::point_map::MapPoint) -> localize::estimation::point_map::MapPoint {
    localize::estimation::point_map::MapPoint {
        position: p.position.map(|v| v as f32 as f64),
        normal: p.normal.map(|v| v as f32 as f64),
    }
}

#[test]
fn without_the_camera_scan_matching_keeps_the_lidar_estimate_well_ahead_of_odometry() {
    let dir = tempfile::tempdir().unwrap();
    let sequence = short_sequence(dir.path(), 30);
    let result = run_sequence(&sequence, &mut CornerSource::Off, &LocalizeConfig::default(), false).unwrap();
    let m = metrics(&sequence, &result).unwrap().expect("ground truth is there");
    let (fused, odometry) = (m.fused.overall, m.odometry_imu.overall);
    assert!(fused.ate_rmse < odometry.ate_rmse / 2.0, "LIDAR {} vs odometry/IMU {}", fused.ate_rmse, odometry.ate_rmse);
    // Every frame after the first registered against the point map.
    for frame in &result.frames[1..] {
        assert!(frame.scan_correspondences >= 50, "{:?}", frame.status);
        assert!(frame.status.label().contains("camera left out"), "{}", frame.status.label());
    }
    // The hall's floor levelled the attitude on some frames.
    assert!(result.frames.iter().any(|f| f.level_floor));
    // The paper's estimator has nothing but odometry/IMU and walls here.
    let paper = run_sequence(&sequence, &mut CornerSource::Off, &LocalizeConfig::paper_estimator(), false).unwrap();
    assert!(paper.frames.iter().all(|f| f.scan_correspondences == 0 && !f.level_floor));
}

#[test]
fn a_lidar_blackout_and_a_camera_that_stops_leave_the_run_going_and_bounded() {
    use localize::input::sensor_faults::{SensorFaults, WithChanges};
    let dir = tempfile::tempdir().unwrap();
    let sequence = short_sequence(dir.path(), 30);
    let labels = dir.path().join("sequence/labels.json");
    let faults = SensorFaults { lidar_gaps: vec![[8.0, 14.0]], camera_stop_s: Some(20.0), ..SensorFaults::default() };
    let faulty = WithChanges { inner: Box::new(sequence), truth: None, faults };
    let mut corners = CornerSource::labels(&labels, 2.0, 1).unwrap();
    let result = run_sequence(&faulty, &mut corners, &LocalizeConfig::default(), false).unwrap();
    // One scan a second: those at 8..13 s are lost, the run goes on after them.
    assert_eq!(result.frames.len(), 24);
    let after = result.frames.iter().find(|f| f.stamp > 7.5).unwrap();
    assert!((after.stamp - 14.0).abs() < 1e-9 && (after.scan_gap_s - 7.0).abs() < 1e-9, "{after:?}");
    assert_eq!(localize::run::longest_scan_gap(&result.frames), Some((after.scan_gap_s, after.stamp)));
    assert!(
        matches!(after.status, localize::estimation::pipeline::FrameStatus::Fused { .. }),
        "{}",
        after.status.label()
    );
    // From 20 s on, no image: LIDAR only, and frames.csv says why.
    for frame in &result.frames {
        let stopped = frame.status.label().contains("camera stopped");
        assert_eq!(stopped, frame.stamp >= 20.0, "{} at {}", frame.status.label(), frame.stamp);
    }
    let csv = localize::run::frames_csv(&result.frames);
    assert!(csv.lines().any(|l| l.starts_with("14.000000,7.000,")), "{csv}");
    // The error stays well within the odometry/IMU's.
    let m = metrics(&faulty, &result).unwrap().expect("ground truth is there");
    let (fused, odometry) = (m.fused.overall, m.odometry_imu.overall);
    assert!(fused.ate_rmse < odometry.ate_rmse / 2.0, "fused {} vs odometry/IMU {}", fused.ate_rmse, odometry.ate_rmse);
}

#[test]
fn in_a_long_featureless_corridor_the_run_stays_within_the_odometry_and_imu() {
    let dir = tempfile::tempdir().unwrap();
    // 30 m of corridor seen by a 20 m LIDAR: in its middle neither end is in range.
    let mut config = DatagenConfig::for_corridor(30.0);
    config.detection.images = 2;
    config.detection.train = 1;
    config.sequence.rate_hz = 2.0;
    config.sequence.camera_rate_hz = None;
    config.sequence.camera_delay_s = 0.0;
    config.lidar.max_range_m = 20.0;
    generate(dir.path(), &config).unwrap();
    let sequence = RecordedSequence::open(&dir.path().join("sequence")).unwrap();
    let mut corners = CornerSource::labels(&dir.path().join("sequence/labels.json"), 2.0, 1).unwrap();
    let result = run_sequence(&sequence, &mut corners, &LocalizeConfig::default(), false).unwrap();
    assert!(result.frames.len() > 50, "{} frames", result.frames.len());
    // Every frame after the first is corrected by scan points, and by walls
    // once the wall landmarks are trusted.
    for frame in &result.frames[1..] {
        assert!(frame.scan_correspondences >= 50, "{}", frame.status.label());
        assert!(frame.plane_correspondences >= 2 || frame.stamp < 3.0, "{}", frame.status.label());
    }
    let m = metrics(&sequence, &result).unwrap().expect("ground truth is there");
    let (fused, odometry) = (m.fused.overall, m.odometry_imu.overall);
    // Along the corridor no better than the wheels can be asked for, but
    // never worse; across it, the walls hold it.
    assert!(fused.rmse_x <= odometry.rmse_x, "x: fused {} vs odometry/IMU {}", fused.rmse_x, odometry.rmse_x);
    assert!(fused.rmse_y < 0.02 && fused.rmse_y < odometry.rmse_y / 5.0, "y: {} vs {}", fused.rmse_y, odometry.rmse_y);
    assert!(fused.ate_rmse < odometry.ate_rmse, "fused {} vs odometry/IMU {}", fused.ate_rmse, odometry.ate_rmse);
}

#[test]
fn the_shipped_detectors_run_inside_localization() {
    let dir = tempfile::tempdir().unwrap();
    let sequence = short_sequence(dir.path(), 4);
    let truth = datasets::io::formats::read_coco(&dir.path().join("sequence/labels.json")).unwrap();
    // Each backbone's shipped checkpoint is of that backbone and finds corners.
    for backbone in ["faster-rcnn", "vgg16", "alexnet"] {
        let checkpoint = manifest_dir().join("../checkpoints").join(backbone);
        let config = infer::checkpoint::read_config(&checkpoint).unwrap();
        assert_eq!(config.backbone.name(), backbone);
        let mut detector =
            CornerSource::detector(&checkpoint, infer::backend::ComputeBackend::Flex.device().unwrap(), 0.3).unwrap();
        // Its corners lie on the generator's true corners: most of them within 20 px.
        let (mut near, mut all) = (0, 0);
        for image in &truth.images {
            let path = dir.path().join("sequence").join(&image.file_name);
            let stem = path.file_stem().unwrap().to_str().unwrap().to_string();
            let picture = datasets::atomic::read_image(&path).unwrap();
            let (found, _) = detector.corners(&stem, Some(&picture));
            let truth_points: Vec<[f32; 2]> = truth.annotations_of(image.id).filter_map(|a| a.point).collect();
            for p in found.unwrap() {
                all += 1;
                near +=
                    usize::from(truth_points.iter().any(|t| (t[0] as f64 - p[0]).hypot(t[1] as f64 - p[1]) <= 20.0));
            }
        }
        assert!(all >= 4 && near as f64 >= 0.5 * all as f64, "{backbone}: {near} of {all} corners near a true one");
        let result = run_sequence(&sequence, &mut detector, &LocalizeConfig::default(), false).unwrap();
        let found = result.frames.iter().map(|f| f.detections).sum::<usize>();
        assert_eq!(found, all, "{backbone}: the run saw the detector's corners");
    }
    // A detector of another kind of file is refused with the path named.
    let error =
        CornerSource::detector(dir.path(), infer::backend::ComputeBackend::Flex.device().unwrap(), 0.3).err().unwrap();
    assert!(error.to_string().contains(&dir.path().display().to_string()), "{error}");
}
