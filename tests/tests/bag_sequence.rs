//! A generated sequence localized from its folder and from the ROS 2
//! recording `datagen --bag` writes of it: the same streams give the same
//! trajectory; and recordings written by other tools (the fixtures of
//! `datasets/tests/data/recordings/`) run with their roles, calibration and
//! unsynchronised camera found from the recording itself.

use datasets::io::recording::mcap_export::write_sequence_mcap;
use datasets::simulator::generate::{DatagenConfig, generate};
use localize::config::LocalizeConfig;
use localize::evaluation::eval::{Alignment, compare};
use localize::input::bag_sequence::{BagOptions, BagSequence};
use localize::input::corner_source::CornerSource;
use localize::input::sequence::{RecordedSequence, SensorSequence, SyncConfig};
use localize::run::{metrics, run_sequence};

fn manifest_dir() -> std::path::PathBuf {
    std::env::var_os("CARGO_MANIFEST_DIR").map_or_else(|| env!("CARGO_MANIFEST_DIR").into(), Into::into)
}

fn fixture(name: &str) -> std::path::PathBuf {
    manifest_dir().join("../datasets/tests/data/recordings").join(name)
}

#[test]
fn a_bag_of_a_generated_sequence_localizes_as_its_folder_does() {
    let dir = tempfile::tempdir().unwrap();
    let mut config = DatagenConfig::default();
    config.detection.images = 2;
    config.detection.train = 1;
    config.sequence.frames = Some(12);
    config.sequence.speed_mps = 0.5;
    generate(dir.path(), &config).unwrap();
    let folder = RecordedSequence::open(&dir.path().join("sequence")).unwrap();
    let bag_path = dir.path().join("sequence.mcap");
    write_sequence_mcap(&dir.path().join("sequence"), &bag_path).unwrap();
    let bag = BagSequence::open(&bag_path, &BagOptions::default(), &SyncConfig::default()).unwrap();

    // The recording gives back the folder's calibration, logs and truth.
    let (a, b) = (folder.calibration(), bag.calibration());
    assert_eq!(a.camera, b.camera);
    assert!((a.robot_from_lidar.to_homogeneous() - b.robot_from_lidar.to_homogeneous()).abs().max() < 1e-12);
    assert!((a.camera_from_lidar.to_homogeneous() - b.camera_from_lidar.to_homogeneous()).abs().max() < 1e-12);
    assert_eq!(folder.imu().len(), bag.imu().len());
    assert_eq!(folder.odometry().len(), bag.odometry().len());
    for (x, y) in folder.imu().iter().zip(bag.imu()) {
        assert!((x.timestamp - y.timestamp).abs() < 1e-9 && x.gyro == y.gyro && x.accel == y.accel);
    }
    let (ta, tb) = (folder.frame_stamps(), bag.frame_stamps());
    assert_eq!(ta.len(), tb.len());
    assert!(ta.iter().zip(&tb).all(|(a, b)| (a - b).abs() < 1e-9));

    let labels = dir.path().join("sequence/labels.json");
    let config = LocalizeConfig::default();
    let from_folder =
        run_sequence(&folder, &mut CornerSource::labels(&labels, 1.0, 3).unwrap(), &config, false).unwrap();
    let from_bag = run_sequence(&bag, &mut CornerSource::labels(&labels, 1.0, 3).unwrap(), &config, false).unwrap();
    let statuses = |r: &localize::run::RunResult| r.frames.iter().map(|f| f.status.label()).collect::<Vec<_>>();
    assert_eq!(statuses(&from_folder), statuses(&from_bag));
    let same = compare(&from_folder.trajectory, &from_bag.trajectory, Alignment::None, 1e-6).unwrap();
    assert_eq!(same.summary.matched, 12);
    assert!(same.summary.ate_rmse < 1e-3, "folder and bag differ by {} m", same.summary.ate_rmse);
    let m = metrics(&bag, &from_bag).unwrap().expect("the bag's /ground_truth");
    let n = metrics(&folder, &from_folder).unwrap().unwrap();
    assert!((m.fused.overall.ate_rmse - n.fused.overall.ate_rmse).abs() < 1e-3);
    assert!(m.fused.overall.ate_rmse < m.odometry_imu.overall.ate_rmse);
}

#[test]
fn recordings_of_other_tools_find_their_roles_calibration_and_images() {
    for name in ["rosbag2_mcap", "rosbag2_sqlite3", "bare_lz4.mcap", "ros1_bz2.bag", "ros1_lz4.bag"] {
        let bag = BagSequence::open(&fixture(name), &BagOptions::default(), &SyncConfig::default())
            .unwrap_or_else(|e| panic!("{name}: {e}"));
        let topics = &bag.recording.topics;
        assert_eq!(topics[bag.roles.lidar].name, "/points");
        assert_eq!(topics[bag.roles.imu.unwrap()].name, "/imu");
        assert_eq!(topics[bag.roles.ground_truth.unwrap()].name, "/ground_truth");
        let c = bag.calibration();
        // base_link -> lidar_link is a translation; the camera is the optical frame.
        assert!((c.robot_from_lidar.translation.vector - nalgebra::Vector3::new(0.1, 0.0, 0.4)).norm() < 1e-12);
        assert_eq!((c.camera.fx, c.camera.fy, c.camera.cx, c.camera.cy), (40.0, 41.0, 15.5, 11.5));
        let camera_in_robot = c.robot_from_camera().translation.vector;
        assert!((camera_in_robot - nalgebra::Vector3::new(0.15, 0.02, 0.3)).norm() < 1e-12, "{name}");
        // The optical frame looks along the robot's x axis.
        let forward = c.robot_from_camera().rotation * nalgebra::Vector3::z();
        assert!((forward - nalgebra::Vector3::x()).norm() < 1e-9, "{name}: {forward:?}");
        // imu_link is turned 90 degrees about z: its x is the robot's y.
        let e: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(fixture("expected.json")).unwrap()).unwrap();
        let gyro = &e["imu"][0]["gyro"];
        let g = |k: usize| gyro[k].as_f64().unwrap();
        let got = bag.imu()[0].gyro;
        assert!(
            (got[0] + g(1)).abs() < 1e-12 && (got[1] - g(0)).abs() < 1e-12 && (got[2] - g(2)).abs() < 1e-12,
            "{name}"
        );
        // 30 Hz camera 13 ms after each scan: every scan has an image within 50 ms.
        assert!(bag.notes.iter().any(|n| n.contains("10 of 10 scans have an image")), "{name}: {:?}", bag.notes);
        let mut frames = Vec::new();
        bag.for_each_frame(&mut |f| {
            let image = f.image.as_ref().map_err(|e| e.clone()).map(|i| (i.stamp, i.image.is_ok()));
            frames.push((
                f.stamp,
                f.cloud.as_ref().map(|c| (c.len(), c.times.is_some())).map_err(|e| e.clone()),
                image,
            ));
            Ok(())
        })
        .unwrap();
        assert_eq!(frames.len(), 10);
        for (stamp, cloud, image) in &frames {
            let (points, timed) = cloud.clone().unwrap();
            assert!(points >= 11 && timed, "{name}: {points} points");
            let (image_stamp, decoded) = image.clone().unwrap();
            assert!(decoded, "{name}");
            assert!((image_stamp - stamp - 0.013).abs() < 1e-6, "{name}: image {image_stamp} for scan {stamp}");
        }
    }
    // A tighter tolerance leaves the scans without images, and says so.
    let tight = SyncConfig { image_tolerance_s: 0.01, ..SyncConfig::default() };
    let bag = BagSequence::open(&fixture("ros1_plain.bag"), &BagOptions::default(), &tight).unwrap();
    assert!(bag.notes.iter().any(|n| n.contains("0 of 10 scans")), "{:?}", bag.notes);
}

#[test]
fn a_named_topic_of_the_wrong_type_or_a_missing_one_is_a_clear_error() {
    let open = |options: BagOptions| BagSequence::open(&fixture("rosbag2_mcap"), &options, &SyncConfig::default());
    let e = open(BagOptions { lidar_topic: Some("/imu".into()), ..Default::default() }).err().unwrap().to_string();
    assert!(e.contains("--lidar-topic /imu: the topic is sensor_msgs/msg/Imu"), "{e}");
    let e = open(BagOptions { image_topic: Some("/nope".into()), ..Default::default() }).err().unwrap().to_string();
    assert!(e.contains("--image-topic /nope: no such topic"), "{e}");
    let e = open(BagOptions { base_frame: Some("chassis".into()), ..Default::default() }).err().unwrap().to_string();
    assert!(
        e.contains("`chassis`") && e.contains("frames: base_link, camera_optical_frame, imu_link, lidar_link"),
        "{e}"
    );
    // A recording without clouds cannot be localized.
    let tf_only = manifest_dir().join("../../shared/data/ros_recordings/tf_example.bag");
    if tf_only.exists() {
        let e = BagSequence::open(&tf_only, &BagOptions::default(), &SyncConfig::default()).err().unwrap().to_string();
        assert!(e.contains("no sensor_msgs/msg/PointCloud2 topic"), "{e}");
    }
}
