//! A recorded sequence with problems: errors that name the file, or an
//! explicit per-frame fallback, never a panic.

use std::path::Path;

use datasets::camera::PinholeCamera;
use datasets::io::formats::{
    Calibration, CocoDataset, ImuSample, OdometrySample, PcdData, PointCloud, write_calibration, write_coco, write_imu,
    write_odometry,
};
use datasets::math::Pose3;
use localize::config::LocalizeConfig;
use localize::estimation::pipeline::FrameStatus;
use localize::input::corner_source::CornerSource;
use localize::input::frame_fault::FrameFault;
use localize::input::sequence::RecordedSequence;
use localize::run::run_sequence;
use nalgebra::Point3;

/// The package folder, read when the test runs (cargo sets it), so that a
/// test binary reused from another checkout still finds its files.
fn manifest_dir() -> std::path::PathBuf {
    std::env::var_os("CARGO_MANIFEST_DIR").map_or_else(|| env!("CARGO_MANIFEST_DIR").into(), Into::into)
}

fn box_room() -> PointCloud {
    // A 6 x 4 x 3 m room around the sensor, a point every 10 cm on each face.
    let mut points = Vec::new();
    let steps = |a: f32, b: f32| ((a * 10.0) as i32..=(b * 10.0) as i32).map(|k| k as f32 / 10.0);
    for u in steps(-3.0, 3.0) {
        for v in steps(-2.0, 2.0) {
            points.push(Point3::new(u, v, -1.0));
        }
        for w in steps(-1.0, 2.0) {
            points.push(Point3::new(u, -2.0, w));
            points.push(Point3::new(u, 2.0, w));
        }
    }
    for v in steps(-2.0, 2.0) {
        for w in steps(-1.0, 2.0) {
            points.push(Point3::new(-3.0, v, w));
            points.push(Point3::new(3.0, v, w));
        }
    }
    PointCloud::new(points, None)
}

/// A still robot: three frames, logs, calibration, no images.
fn write_sequence(dir: &Path) {
    std::fs::create_dir_all(dir.join("cloud")).unwrap();
    for t in ["0.000000", "1.000000", "2.000000"] {
        datasets::io::formats::write_pcd(&dir.join("cloud").join(format!("{t}.pcd")), &box_room(), PcdData::Binary)
            .unwrap();
    }
    let calib = Calibration {
        camera: PinholeCamera { width: 640, height: 480, fx: 525.0, fy: 525.0, cx: 319.5, cy: 239.5 },
        camera_from_lidar: Pose3::identity(),
        robot_from_lidar: Pose3::identity(),
    };
    write_calibration(&dir.join("calib.json"), &calib).unwrap();
    let odometry: Vec<OdometrySample> = (0..30)
        .map(|k| OdometrySample { timestamp: k as f64 * 0.1, x: 0.0, y: 0.0, yaw: 0.0, v: 0.0, omega: 0.0 })
        .collect();
    write_odometry(&dir.join("odom.csv"), &odometry).unwrap();
    let imu: Vec<ImuSample> = (0..150)
        .map(|k| ImuSample { timestamp: k as f64 * 0.02, accel: [0.0, 0.0, 9.80665], gyro: [0.0; 3] })
        .collect();
    write_imu(&dir.join("imu.csv"), &imu).unwrap();
    let labels = CocoDataset { info: None, images: vec![], annotations: vec![], categories: vec![] };
    write_coco(&dir.join("labels.json"), &labels).unwrap();
}

#[test]
fn a_corrupt_cloud_is_a_per_frame_fallback_and_the_run_goes_on() {
    let dir = tempfile::tempdir().unwrap();
    write_sequence(dir.path());
    std::fs::write(dir.path().join("cloud/1.000000.pcd"), b"VERSION 0.7\nFIELDS x y\n").unwrap();
    let sequence = RecordedSequence::open(dir.path()).unwrap();
    assert!(sequence.frames.iter().all(|f| f.image.is_none()));
    let mut source = CornerSource::labels(&dir.path().join("labels.json"), 0.0, 1).unwrap();
    let result = run_sequence(&sequence, &mut source, &LocalizeConfig::default(), false).unwrap();
    assert_eq!(result.trajectory.len(), 3);
    // Labels stand in for a detector: without an image they give no corners.
    let no_image = |s: &FrameStatus| matches!(s, FrameStatus::NoImage { why: FrameFault::NoImageNear { .. }, .. });
    assert!(no_image(&result.frames[0].status), "{:?}", result.frames[0].status);
    assert!(matches!(
        &result.frames[1].status,
        FrameStatus::BadCloud(FrameFault::Unreadable(why)) if why.contains("1.000000.pcd")
    ));
    assert!(no_image(&result.frames[2].status), "{:?}", result.frames[2].status);
    assert_eq!(result.frames[2].planes, 5, "floor and four walls");
    // A still robot stays where it started.
    for pose in &result.trajectory.poses {
        assert!(pose.translation.vector.norm() < 1e-6);
    }
}

#[test]
fn duplicate_timestamps_and_bad_names_are_errors_naming_the_file() {
    let dir = tempfile::tempdir().unwrap();
    write_sequence(dir.path());
    std::fs::copy(dir.path().join("cloud/1.000000.pcd"), dir.path().join("cloud/1.0.pcd")).unwrap();
    let error = RecordedSequence::open(dir.path()).err().expect("duplicate stamp");
    assert!(error.to_string().contains("duplicate timestamp 1"), "{error}");
    std::fs::remove_file(dir.path().join("cloud/1.0.pcd")).unwrap();
    std::fs::copy(dir.path().join("cloud/1.000000.pcd"), dir.path().join("cloud/frame.pcd")).unwrap();
    let error = RecordedSequence::open(dir.path()).err().expect("bad name");
    assert!(error.to_string().contains("frame.pcd") && error.to_string().contains("not a timestamp"), "{error}");
}

#[test]
fn a_calibration_that_does_not_parse_is_an_error_naming_it() {
    let dir = tempfile::tempdir().unwrap();
    write_sequence(dir.path());
    std::fs::write(dir.path().join("calib.json"), b"{\"camera\": 3}").unwrap();
    let error = RecordedSequence::open(dir.path()).err().expect("bad calibration");
    assert!(error.to_string().contains("calib.json"), "{error}");
    std::fs::remove_file(dir.path().join("calib.json")).unwrap();
    let error = RecordedSequence::open(dir.path()).err().expect("missing calibration");
    assert!(error.to_string().contains("calib.json"), "{error}");
}

#[test]
fn frames_without_images_fall_back_and_say_why() {
    let checkpoint = manifest_dir().join("../checkpoints/faster-rcnn");
    let dir = tempfile::tempdir().unwrap();
    write_sequence(dir.path());
    let sequence = RecordedSequence::open(dir.path()).unwrap();
    let mut source =
        CornerSource::detector(&checkpoint, infer::backend::ComputeBackend::Flex.device().unwrap(), 0.3).unwrap();
    let result = run_sequence(&sequence, &mut source, &LocalizeConfig::default(), false).unwrap();
    assert_eq!(result.trajectory.len(), 3);
    for (frame, stamp) in result.frames.iter().zip(["0.000000", "1.000000", "2.000000"]) {
        let FrameStatus::NoImage { why, walls, scan } = &frame.status else { panic!("{:?}", frame.status) };
        assert!(why.to_string().contains(&format!("no image within 0.05 s of scan {stamp}")), "{why}");
        // The walls are not trusted yet after so few frames; the scan
        // registers against the first frame's points from the second on.
        assert_eq!(*walls, 0);
        assert_eq!(*scan > 0, stamp != "0.000000", "{}", frame.status.label());
        assert!(frame.status.label().contains("no 2D corners"));
    }
}

#[test]
fn scans_take_the_nearest_image_within_the_tolerance_on_its_own_clock() {
    let dir = tempfile::tempdir().unwrap();
    write_sequence(dir.path());
    std::fs::create_dir_all(dir.path().join("rgb")).unwrap();
    let image = image::DynamicImage::new_rgb8(640, 480);
    // A camera 20 ms behind the scans, and one image 0.3 s off any scan;
    // zero-padded and nanosecond names read as well as plain ones.
    for name in ["0000000000.020000", "1020000000000000000", "2.3"] {
        datasets::atomic::write_image(&dir.path().join("rgb").join(format!("{name}.png")), &image).unwrap();
    }
    let sequence = RecordedSequence::open(dir.path()).unwrap();
    let taken: Vec<Option<f64>> = sequence.frames.iter().map(|f| f.image.as_ref().map(|i| i.stamp)).collect();
    // 1020000000000000000 ns is 1.02e9 s, far from every scan.
    assert_eq!(taken, [Some(0.02), None, None]);
    let wide = localize::input::sequence::SyncConfig { image_tolerance_s: 0.5, ..Default::default() };
    let sequence = RecordedSequence::open_with(dir.path(), &wide).unwrap();
    let taken: Vec<Option<f64>> = sequence.frames.iter().map(|f| f.image.as_ref().map(|i| i.stamp)).collect();
    assert_eq!(taken, [Some(0.02), None, Some(2.3)]);
    // Epoch nanoseconds keep what an f64 can of them (a quarter microsecond).
    let t = localize::input::sequence::stamp_of_name("1700000000123456789").unwrap();
    assert!((t - 1.7e9 - 0.123_456_789).abs() < 2.5e-7, "{t}");
    assert_eq!(datasets::io::formats::stamped_files::stamp_name(9.5), "0000000009.500000");
    assert!(
        datasets::io::formats::stamped_files::stamp_name(9.5) < datasets::io::formats::stamped_files::stamp_name(10.0),
        "names sort in time order"
    );
    let bad = localize::input::sequence::SyncConfig { image_tolerance_s: f64::NAN, ..Default::default() };
    assert!(RecordedSequence::open_with(dir.path(), &bad).err().unwrap().to_string().contains("image_tolerance_s"));
}

#[test]
fn empty_logs_every_cloud_broken_and_scans_past_the_logs_are_errors() {
    let labels = |dir: &Path| CornerSource::labels(&dir.join("labels.json"), 0.0, 1).unwrap();
    let dir = tempfile::tempdir().unwrap();
    write_sequence(dir.path());
    std::fs::write(dir.path().join("odom.csv"), "timestamp,x,y,yaw,v,omega\n").unwrap();
    let e = RecordedSequence::open(dir.path()).err().unwrap().to_string();
    assert!(e.contains("odom.csv") && e.contains("a header and no rows"), "{e}");

    let dir = tempfile::tempdir().unwrap();
    write_sequence(dir.path());
    for t in ["0.000000", "1.000000", "2.000000"] {
        std::fs::write(dir.path().join(format!("cloud/{t}.pcd")), b"VERSION 0.7\n").unwrap();
    }
    let sequence = RecordedSequence::open(dir.path()).unwrap();
    let e = run_sequence(&sequence, &mut labels(dir.path()), &LocalizeConfig::default(), false).err().unwrap();
    assert!(e.to_string().contains("every one of the 3 clouds is unreadable; the first:"), "{e}");

    // A scan 55 s after the logs end would be extrapolated, not measured.
    let dir = tempfile::tempdir().unwrap();
    write_sequence(dir.path());
    datasets::io::formats::write_pcd(&dir.path().join("cloud/57.0.pcd"), &box_room(), PcdData::Binary).unwrap();
    let sequence = RecordedSequence::open(dir.path()).unwrap();
    let e = run_sequence(&sequence, &mut labels(dir.path()), &LocalizeConfig::default(), false).err().unwrap();
    assert!(e.to_string().contains("1 scans lie more than 1 s outside the odometry log ("), "{e}");
    assert!(e.to_string().contains("odom.csv: "), "the file is named: {e}");

    for noise in [f64::NAN, -1.0] {
        let e = CornerSource::labels(&dir.path().join("labels.json"), noise, 1).err().unwrap().to_string();
        assert!(e.contains("label_noise_px: ") && e.contains("px outside [0, 1000]"), "{e}");
    }
}

#[test]
fn an_image_between_two_scans_serves_both_from_a_bag_as_from_the_folder() {
    use localize::input::sequence::SensorSequence;
    let dir = tempfile::tempdir().unwrap();
    write_sequence(dir.path());
    std::fs::create_dir_all(dir.path().join("rgb")).unwrap();
    let image = image::DynamicImage::new_rgb8(640, 480);
    datasets::atomic::write_image(&dir.path().join("rgb/1.5.png"), &image).unwrap();
    let bag = dir.path().join("still.mcap");
    datasets::io::recording::mcap_export::write_sequence_mcap(dir.path(), &bag).unwrap();
    let sync = localize::input::sequence::SyncConfig { image_tolerance_s: 0.6, ..Default::default() };
    let folder = RecordedSequence::open_with(dir.path(), &sync).unwrap();
    let recording = localize::input::bag_sequence::BagSequence::open(
        &bag,
        &localize::input::bag_sequence::BagOptions::default(),
        &sync,
    )
    .unwrap();
    for sequence in [&folder as &dyn SensorSequence, &recording] {
        let mut taken = Vec::new();
        sequence
            .for_each_frame(&mut |f| {
                let image = f.image.map(|i| (i.stamp, i.image.map(|im| im.width()).unwrap_or(0)));
                taken.push((f.stamp, f.cloud.map(|c| c.len()).unwrap_or(0), image.ok()));
                Ok(())
            })
            .unwrap();
        let points = box_room().len();
        assert_eq!(taken, [(0.0, points, None), (1.0, points, Some((1.5, 640))), (2.0, points, Some((1.5, 640)))]);
    }
}

#[test]
fn a_generated_building_with_its_own_clocks_reads_as_scans_with_images_and_sweeps() {
    use localize::input::sequence::SensorSequence;
    // Building 1 with a robot's timing: 10 Hz sweeps, a 15 Hz camera 21 ms
    // off the LIDAR's clock, 50 Hz odometry, 200 Hz IMU.
    let dir = tempfile::tempdir().unwrap();
    let mut config = datasets::simulator::generate::DatagenConfig::for_building(1);
    config.detection.images = 0;
    config.detection.train = 0;
    config.sequence.frames = Some(6);
    datasets::simulator::generate::generate(dir.path(), &config).unwrap();
    let sequence = RecordedSequence::open(&dir.path().join("sequence")).unwrap();
    let stamps = sequence.frame_stamps();
    assert_eq!(stamps.len(), 6);
    assert!(stamps.windows(2).all(|w| (w[1] - w[0] - 0.1).abs() < 1e-9), "{stamps:?}");
    // Odometry at 50 Hz and the IMU at 200 Hz to the end of the last sweep.
    let dt = |t: &[f64]| (t[t.len() - 1] - t[0]) / (t.len() - 1) as f64;
    let odometry: Vec<f64> = sequence.odometry().iter().map(|s| s.timestamp).collect();
    let imu: Vec<f64> = sequence.imu().iter().map(|s| s.timestamp).collect();
    assert!((dt(&odometry) - 0.02).abs() < 1e-9 && (dt(&imu) - 0.005).abs() < 1e-9);
    assert!(*imu.last().unwrap() >= stamps[5] + 0.1 - 0.005);
    let mut seen = 0;
    sequence
        .for_each_frame(&mut |frame| {
            let cloud = frame.cloud.expect("readable cloud");
            let times = cloud.times.expect("a sweep keeps its point times");
            assert!(times.iter().all(|&t| (0.0..0.1).contains(&t)));
            assert!(times.last().unwrap() - times[0] > 0.09, "the points span the sweep");
            // The nearest 15 Hz image on the camera's clock: 0.021 + k / 15 s.
            let image = frame.image.expect("an image within 50 ms");
            let k = ((image.stamp - 0.021) * 15.0).round();
            assert!((image.stamp - (0.021 + k / 15.0)).abs() < 1e-6, "image at {}", image.stamp);
            assert!((image.stamp - frame.stamp).abs() <= 1.0 / 30.0 + 1e-6);
            seen += 1;
            Ok(())
        })
        .unwrap();
    assert_eq!(seen, 6);
}

#[test]
fn an_image_of_another_size_than_the_calibration_says_so_in_its_frame() {
    let dir = tempfile::tempdir().unwrap();
    write_sequence(dir.path());
    std::fs::create_dir_all(dir.path().join("rgb")).unwrap();
    image::RgbImage::new(320, 240).save(dir.path().join("rgb/1.000000.png")).unwrap();
    let sequence = RecordedSequence::open(dir.path()).unwrap();
    let checkpoint = manifest_dir().join("../checkpoints/faster-rcnn");
    let mut source =
        CornerSource::detector(&checkpoint, infer::backend::ComputeBackend::Flex.device().unwrap(), 0.3).unwrap();
    let result = run_sequence(&sequence, &mut source, &LocalizeConfig::default(), false).unwrap();
    let FrameStatus::NoImage { why, .. } = &result.frames[1].status else { panic!("{:?}", result.frames[1].status) };
    assert!(
        matches!(why, FrameFault::WrongSize { source, size: [320, 240], expected: [640, 480], .. } if source.contains("1.000000.png")),
        "{why:?}"
    );
    assert!(why.to_string().contains("image is 320x240, the calibration's camera is 640x480"), "{why}");
}

#[test]
fn labels_give_no_corners_for_an_unreadable_image_or_one_they_do_not_list() {
    let dir = tempfile::tempdir().unwrap();
    write_sequence(dir.path());
    std::fs::create_dir_all(dir.path().join("rgb")).unwrap();
    let image = image::DynamicImage::new_rgb8(640, 480);
    for name in ["0.000000", "1.000000", "2.000000"] {
        datasets::atomic::write_image(&dir.path().join("rgb").join(format!("{name}.png")), &image).unwrap();
    }
    // Frame 1's image is corrupt; frame 2's is not in the labels file.
    std::fs::write(dir.path().join("rgb/1.000000.png"), b"\x89PNG broken").unwrap();
    let image_entry =
        |id: u64, name: &str| datasets::io::formats::CocoImage { id, file_name: name.into(), width: 640, height: 480 };
    let corner = datasets::io::formats::CocoAnnotation {
        id: 1,
        image_id: 1,
        category_id: 1,
        bbox: [300.0, 200.0, 16.0, 16.0],
        area: 256.0,
        iscrowd: 0,
        corner_type: None,
        point: Some([308.0, 208.0]),
    };
    let labels = CocoDataset {
        info: None,
        images: vec![image_entry(0, "0.000000.png"), image_entry(1, "1.000000.png")],
        annotations: vec![corner],
        categories: vec![datasets::io::formats::CocoCategory { id: 1, name: "corner".into(), supercategory: None }],
    };
    write_coco(&dir.path().join("labels.json"), &labels).unwrap();
    let sequence = RecordedSequence::open(dir.path()).unwrap();
    let mut source = CornerSource::labels(&dir.path().join("labels.json"), 0.0, 1).unwrap();
    let mut corners = |k: usize| {
        let frame = &sequence.frames[k];
        let stem = frame.image.as_ref().map(|i| i.path.file_stem().unwrap().to_string_lossy().into_owned()).unwrap();
        let loaded = frame.image.as_ref().map(|i| image::open(&i.path));
        source.corners(&stem, loaded.as_ref().and_then(|r| r.as_ref().ok())).0
    };
    assert_eq!(corners(0), Ok(vec![]), "listed, without corners");
    assert_eq!(corners(1), Err(FrameFault::NoImage), "the image does not decode");
    assert_eq!(corners(2), Err(FrameFault::NotInLabels { stem: "2.000000".into() }));
    // Through the whole run, the corrupt image is that frame's reason.
    let result = run_sequence(&sequence, &mut source, &LocalizeConfig::default(), false).unwrap();
    assert!(
        matches!(&result.frames[1].status, FrameStatus::NoImage { why: FrameFault::Unreadable(why), .. } if why.contains("1.000000.png")),
        "{:?}",
        result.frames[1].status
    );
    assert!(matches!(&result.frames[2].status, FrameStatus::NoImage { why: FrameFault::NotInLabels { .. }, .. }));
}

#[test]
fn a_hole_in_the_odometry_log_is_reported_with_its_length_and_end() {
    use localize::input::sequence::SensorSequence;
    let dir = tempfile::tempdir().unwrap();
    write_sequence(dir.path());
    let sequence = RecordedSequence::open(dir.path()).unwrap();
    assert!(localize::run::log_gaps(&sequence).is_empty(), "10 Hz odometry and 50 Hz IMU without holes");
    // The odometry stops between 0.5 s and 2.0 s.
    let odometry: Vec<OdometrySample> = (0..30)
        .map(|k| k as f64 * 0.1)
        .filter(|t| !(0.55..1.95).contains(t))
        .map(|timestamp| OdometrySample { timestamp, x: 0.0, y: 0.0, yaw: 0.0, v: 0.0, omega: 0.0 })
        .collect();
    write_odometry(&dir.path().join("odom.csv"), &odometry).unwrap();
    let sequence = RecordedSequence::open(dir.path()).unwrap();
    let gaps = localize::run::log_gaps(&sequence);
    assert_eq!(gaps.len(), 1, "{gaps:?}");
    let (log, gap, end) = gaps[0];
    assert_eq!(log, localize::input::sequence::MotionLog::Odometry);
    assert!(sequence.log_source(log).ends_with("odom.csv"), "{}", sequence.log_source(log));
    assert!((gap - 1.5).abs() < 1e-9 && (end - 2.0).abs() < 1e-9, "{gap} s before {end} s");
}
