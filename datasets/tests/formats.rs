//! Round trips and malformed-file tests for every format, plus files written
//! by other tools (PCL, Open3D, CloudCompare, the TUM tools, evo) from the
//! shared real-data folder `../shared/data` (tests named `real_*`).

use std::path::{Path, PathBuf};

use datasets::DataError;
use datasets::camera::PinholeCamera;
use datasets::io::formats::*;
use datasets::math::Pose3;
use nalgebra::{Point3, Translation3, UnitQuaternion, Vector3};

/// The package folder, read when the test runs (cargo sets it), so that a
/// test binary reused from another checkout still finds its files.
fn manifest_dir() -> std::path::PathBuf {
    std::env::var_os("CARGO_MANIFEST_DIR").map_or_else(|| env!("CARGO_MANIFEST_DIR").into(), Into::into)
}

fn real(rel: &str) -> PathBuf {
    let path = manifest_dir().join("../../shared/data").join(rel);
    assert!(
        path.exists(),
        "real-data file {} is missing: these tests need the shared data folder beside the project",
        path.display()
    );
    path
}

fn sample_cloud(with_intensity: bool) -> PointCloud {
    let points: Vec<Point3<f32>> =
        (0..257).map(|i| Point3::new(i as f32 * 0.25 - 3.0, (i as f32).sin() * 7.123, 1e-3 * i as f32)).collect();
    let intensity = with_intensity.then(|| (0..257).map(|i| (i % 13) as f32 / 13.0).collect());
    let mut cloud = PointCloud::new(points, intensity);
    cloud.viewpoint =
        Pose3::from_parts(Translation3::new(1.0, -2.0, 0.5), UnitQuaternion::from_euler_angles(0.1, -0.2, 0.3));
    cloud
}

fn message(err: DataError) -> String {
    err.to_string()
}

#[test]
fn pcd_round_trips_in_all_three_data_kinds() {
    let dir = tempfile::tempdir().unwrap();
    for with_intensity in [false, true] {
        let cloud = sample_cloud(with_intensity);
        for kind in [PcdData::Ascii, PcdData::Binary, PcdData::BinaryCompressed] {
            let path = dir.path().join(format!("c-{with_intensity}-{kind:?}.pcd"));
            write_pcd(&path, &cloud, kind).unwrap();
            let back = read_pcd(&path, NonFinite::Drop).unwrap();
            assert_eq!(back.points, cloud.points, "{kind:?}");
            assert_eq!(back.intensity, cloud.intensity, "{kind:?}");
            assert!((back.viewpoint.translation.vector - cloud.viewpoint.translation.vector).norm() < 1e-9);
            assert!(back.viewpoint.rotation.angle_to(&cloud.viewpoint.rotation) < 1e-6);
        }
    }
}

#[test]
fn pcd_point_times_round_trip_and_ouster_nanoseconds_read_as_seconds() {
    let dir = tempfile::tempdir().unwrap();
    for with_intensity in [false, true] {
        let mut cloud = sample_cloud(with_intensity);
        cloud.times = Some((0..257).map(|i| i as f32 * 0.1 / 257.0).collect());
        for kind in [PcdData::Ascii, PcdData::Binary, PcdData::BinaryCompressed] {
            let path = dir.path().join(format!("t-{with_intensity}-{kind:?}.pcd"));
            write_pcd(&path, &cloud, kind).unwrap();
            let back = read_pcd(&path, NonFinite::Drop).unwrap();
            assert_eq!(back.points, cloud.points, "{kind:?}");
            assert_eq!(back.intensity, cloud.intensity, "{kind:?}");
            assert_eq!(back.times, cloud.times, "{kind:?}");
        }
    }
    // An Ouster-style `t` field: unsigned nanoseconds after the stamp; a
    // dropped NaN point takes its time with it.
    let text = "VERSION 0.7\nFIELDS x y z t\nSIZE 4 4 4 4\nTYPE F F F U\nCOUNT 1 1 1 1\nWIDTH 3\nHEIGHT 1\n\
                VIEWPOINT 0 0 0 1 0 0 0\nPOINTS 3\nDATA ascii\n1 2 3 0\nnan 0 0 50000000\n4 5 6 99000000\n";
    let path = dir.path().join("ouster.pcd");
    std::fs::write(&path, text).unwrap();
    let cloud = read_pcd(&path, NonFinite::Drop).unwrap();
    assert_eq!(cloud.len(), 2);
    assert_eq!(cloud.times, Some(vec![0.0, 0.099]));
    // Without a time field there are no times.
    write_pcd(&path, &sample_cloud(false), PcdData::Binary).unwrap();
    assert_eq!(read_pcd(&path, NonFinite::Drop).unwrap().times, None);
}

#[test]
fn pcd_malformed_files_name_the_line_or_byte() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("bad.pcd");
    let header = "VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 2\nHEIGHT 1\nPOINTS 2\n";

    std::fs::write(&p, format!("{header}DATA ascii\n1 2 3\n4 five 6\n")).unwrap();
    let m = message(read_pcd(&p, NonFinite::Drop).unwrap_err());
    assert!(m.contains("bad.pcd:11") && m.contains("`five` is not a number"), "{m}");

    std::fs::write(&p, format!("{header}DATA ascii\n1 2 3\n")).unwrap();
    let m = message(read_pcd(&p, NonFinite::Drop).unwrap_err());
    assert!(m.contains("declares 2 points but the data has 1"), "{m}");

    let mut bytes = format!("{header}DATA binary\n").into_bytes();
    bytes.extend_from_slice(&[0u8; 20]);
    std::fs::write(&p, &bytes).unwrap();
    let m = message(read_pcd(&p, NonFinite::Drop).unwrap_err());
    assert!(m.contains("binary data ends early") && m.contains("need 24 bytes, found 20"), "{m}");

    std::fs::write(&p, "VERSION 0.7\nFIELDS x y z\nSIZE 4 4\nTYPE F F F\nPOINTS 1\nDATA ascii\n1 2 3\n").unwrap();
    let m = message(read_pcd(&p, NonFinite::Drop).unwrap_err());
    assert!(m.contains("bad.pcd:6") && m.contains("SIZE has 2"), "{m}");

    std::fs::write(&p, "VERSION 0.7\nFIELDS a b c\nSIZE 4 4 4\nTYPE F F F\nPOINTS 1\nDATA ascii\n1 2 3\n").unwrap();
    assert!(message(read_pcd(&p, NonFinite::Drop).unwrap_err()).contains("no `x` field"));

    // A compressed block whose LZF stream is corrupt: the error gives its byte offset.
    let good = datasets::io::formats::pcd::pcd_bytes(&sample_cloud(false), PcdData::BinaryCompressed);
    let start = good.windows(5).position(|w| w == b"DATA ").unwrap();
    let data_at = start + good[start..].iter().position(|&b| b == b'\n').unwrap() + 1;
    let mut broken = good.clone();
    broken[data_at + 8] = 0xff; // a back-reference far before the start of the output
    std::fs::write(&p, &broken).unwrap();
    let m = message(read_pcd(&p, NonFinite::Drop).unwrap_err());
    assert!(m.contains(&format!("byte {}", data_at + 8)) && m.contains("LZF"), "{m}");
    std::fs::write(&p, &good[..good.len() - 10]).unwrap();
    assert!(message(read_pcd(&p, NonFinite::Drop).unwrap_err()).contains("truncated"));

    let missing = dir.path().join("missing.pcd");
    assert!(message(read_pcd(&missing, NonFinite::Drop).unwrap_err()).contains("missing.pcd"));
}

#[test]
fn non_finite_points_are_dropped_and_counted_or_rejected() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("nan.pcd");
    std::fs::write(
        &p,
        "FIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nWIDTH 3\nHEIGHT 1\nDATA ascii\n1 2 3\nnan nan nan\n4 5 6\n",
    )
    .unwrap();
    let cloud = read_pcd(&p, NonFinite::Drop).unwrap();
    assert_eq!((cloud.len(), cloud.dropped_non_finite), (2, 1));
    assert_eq!(cloud.points[1], Point3::new(4.0, 5.0, 6.0));
    let m = message(read_pcd(&p, NonFinite::Reject).unwrap_err());
    assert!(m.contains("point 1 has a non-finite coordinate"), "{m}");
}

#[test]
fn ply_round_trips_in_ascii_and_both_binaries() {
    let dir = tempfile::tempdir().unwrap();
    for with_intensity in [false, true] {
        let mut cloud = sample_cloud(with_intensity);
        cloud.viewpoint = Pose3::identity();
        for format in [PlyFormat::Ascii, PlyFormat::BinaryLittleEndian, PlyFormat::BinaryBigEndian] {
            let path = dir.path().join(format!("c-{with_intensity}-{format:?}.ply"));
            write_ply(&path, &cloud, format).unwrap();
            assert_eq!(read_cloud(&path, NonFinite::Drop).unwrap(), cloud, "{format:?}");
        }
    }
}

#[test]
fn ply_with_doubles_colours_and_faces_as_open3d_writes() {
    // Open3D writes double coordinates, uchar colours and, for meshes, a face list.
    let dir = tempfile::tempdir().unwrap();
    let header = "ply\nformat binary_little_endian 1.0\ncomment Created by Open3D\nelement vertex 2\nproperty double x\nproperty double y\nproperty double z\nproperty uchar red\nproperty uchar green\nproperty uchar blue\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n";
    let mut bytes = header.as_bytes().to_vec();
    for (p, rgb) in [([1.5f64, -2.0, 3.25], [255u8, 0, 0]), ([0.0, 0.5, -1.0], [0, 255, 0])] {
        p.iter().for_each(|v| bytes.extend_from_slice(&v.to_le_bytes()));
        bytes.extend_from_slice(&rgb);
    }
    bytes.push(3);
    [0i32, 1, 0].iter().for_each(|v| bytes.extend_from_slice(&v.to_le_bytes()));
    let path = dir.path().join("o3d.ply");
    std::fs::write(&path, &bytes).unwrap();
    let cloud = read_ply(&path, NonFinite::Drop).unwrap();
    assert_eq!(cloud.points, vec![Point3::new(1.5, -2.0, 3.25), Point3::new(0.0, 0.5, -1.0)]);
    assert!(cloud.intensity.is_none());

    std::fs::write(&path, &bytes[..bytes.len() - 5]).unwrap();
    let m = message(read_ply(&path, NonFinite::Drop).unwrap_err());
    assert!(m.contains("o3d.ply: byte") && m.contains("ends inside the binary body"), "{m}");

    let ascii = "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\nend_header\n1 2 3\n4 oops 6\n";
    std::fs::write(&path, ascii).unwrap();
    let m = message(read_ply(&path, NonFinite::Drop).unwrap_err());
    assert!(m.contains("o3d.ply:9") && m.contains("`oops`"), "{m}");
    std::fs::write(&path, "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nend_header\n1\n").unwrap();
    assert!(message(read_ply(&path, NonFinite::Drop).unwrap_err()).contains("no `y` property"));
}

#[test]
fn kitti_bin_round_trips_and_rejects_a_partial_record() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("scan.bin");
    let mut cloud = sample_cloud(true);
    cloud.viewpoint = Pose3::identity();
    datasets::io::formats::cloud::write_kitti_bin(&path, &cloud).unwrap();
    assert_eq!(read_cloud(&path, NonFinite::Drop).unwrap(), cloud);
    let mut bytes = std::fs::read(&path).unwrap();
    bytes.truncate(bytes.len() - 3);
    std::fs::write(&path, &bytes).unwrap();
    assert!(message(read_cloud(&path, NonFinite::Drop).unwrap_err()).contains("not a multiple of 16"));
    let unknown = dir.path().join("scan.xyz");
    std::fs::write(&unknown, "1 2 3").unwrap();
    assert!(message(read_cloud(&unknown, NonFinite::Drop).unwrap_err()).contains("unknown point cloud extension"));
}

#[test]
fn real_pcl_compressed_room_scans_equal_their_uncompressed_copies() {
    for name in ["room_scan1", "room_scan2"] {
        let packed = read_pcd(&real(&format!("pcl_room_scans/{name}.pcd")), NonFinite::Drop).unwrap();
        let plain = read_pcd(&real(&format!("pcl_room_scans/{name}_binary.pcd")), NonFinite::Drop).unwrap();
        assert!(packed.len() > 112_000, "{name}: {} points", packed.len());
        assert_eq!(packed.points, plain.points, "{name}");
    }
}

#[test]
fn real_organized_kinect_clouds_drop_their_nans_on_purpose() {
    let cloud = read_pcd(&real("pcl_room_scans/capture0001.pcd"), NonFinite::Drop).unwrap();
    assert!(cloud.dropped_non_finite > 0);
    assert_eq!(cloud.len() + cloud.dropped_non_finite, 640 * 480);
    assert!(read_pcd(&real("pcl_room_scans/capture0001.pcd"), NonFinite::Reject).is_err());
    // x y z rgb, compressed: rgb is skipped.
    let table = read_pcd(&real("pcl_room_scans/table_scene_mug_stereo_textured.pcd"), NonFinite::Drop).unwrap();
    assert_eq!(table.len() + table.dropped_non_finite, 640 * 480);
}

#[test]
fn real_open3d_and_labelled_pcds_load() {
    let fragment = read_pcd(&real("open3d_rgbd_samples/fragment.pcd"), NonFinite::Drop).unwrap();
    assert_eq!(fragment.len() + fragment.dropped_non_finite, 113_662);
    let office = read_pcd(&real("bobkov_office_rooms/room1_gt_fine.pcd"), NonFinite::Drop).unwrap();
    assert_eq!(office.len() + office.dropped_non_finite, 237_907);
}

#[test]
fn real_cloudcompare_ply_and_kitti_scan_load() {
    let source = read_cloud(&real("small_gicp_lidar_pair/source.ply"), NonFinite::Drop).unwrap();
    assert_eq!(source.len(), 69_792);
    assert_eq!(source.intensity.as_ref().map(Vec::len), Some(69_792));
    let velodyne = read_cloud(&real("kitti_object_3frames/training/velodyne/000000.bin"), NonFinite::Drop).unwrap();
    assert!(velodyne.len() > 100_000);
    // A Velodyne HDL-64 sees tens of metres around the car.
    let far = velodyne.points.iter().map(|p| p.coords.norm()).fold(0.0f32, f32::max);
    assert!((40.0..130.0).contains(&far), "max range {far}");
}

#[test]
fn tum_round_trips_and_reports_bad_lines() {
    let dir = tempfile::tempdir().unwrap();
    let mut t = Trajectory::default();
    for k in 0..20 {
        let pose = Pose3::from_parts(
            Translation3::new(k as f64 * 0.1, -0.03 * k as f64, 0.5),
            UnitQuaternion::from_euler_angles(0.01 * k as f64, 0.0, 0.2 * k as f64),
        );
        t.push(1_305_031_102.160_407 + k as f64 * 0.033, pose);
    }
    let path = dir.path().join("traj.txt");
    write_tum(&path, &t).unwrap();
    let (back, format) = read_trajectory(&path).unwrap();
    assert_eq!(format, TrajectoryFormat::Tum);
    assert_eq!(back.len(), 20);
    for (a, b) in back.poses.iter().zip(&t.poses) {
        assert!((a.translation.vector - b.translation.vector).norm() < 1e-8);
        assert!(a.rotation.angle_to(&b.rotation) < 1e-8);
    }
    for (a, b) in back.stamps.iter().zip(&t.stamps) {
        assert!((a - b).abs() < 1e-6);
    }

    std::fs::write(&path, "# comment\n1.0 0 0 0 0 0 0 1\n2.0 0 0 0 0 0 0\n").unwrap();
    let m = message(read_tum(&path).unwrap_err());
    assert!(m.contains("traj.txt:3") && m.contains("expected 8 values"), "{m}");
    std::fs::write(&path, "1.0 0 0 0 0 0 0 0\n").unwrap();
    assert!(message(read_tum(&path).unwrap_err()).contains("zero length"));
    std::fs::write(&path, "1.0 0 0 nan 0 0 0 1\n").unwrap();
    assert!(message(read_tum(&path).unwrap_err()).contains("non-finite"));
    std::fs::write(&path, "1.0 0 0 0 0 0 0 1\n1.0 1 0 0 0 0 0 1\n").unwrap();
    let dup = read_tum(&path).unwrap();
    assert!(message(dup.check_increasing(&path).unwrap_err()).contains("duplicate timestamp at pose 1"));
    // As TUM's motion-capture files have them: one stamp, poses 1 mm and 0.6 degrees apart.
    std::fs::write(&path, "1.0 0 0 0 0 0 0 1\n1.0 0.001 0 0 0.0052 0 0 1\n2.0 0 0 0 0 0 0 1\n").unwrap();
    assert_eq!(read_tum(&path).unwrap().check_increasing(&path).unwrap(), 1);
    // 2 degrees apart is past the tolerance.
    std::fs::write(&path, "1.0 0 0 0 0 0 0 1\n1.0 0 0 0 0.0175 0 0 1\n").unwrap();
    let m = message(read_tum(&path).unwrap().check_increasing(&path).unwrap_err());
    assert!(m.contains("2.01 degrees apart") && m.contains("at most 0.01 m and 1 degree"), "{m}");
    std::fs::write(&path, "2.0 0 0 0 0 0 0 1\n1.0 0 0 0 0 0 0 1\n").unwrap();
    assert!(message(read_tum(&path).unwrap().check_increasing(&path).unwrap_err()).contains("decreasing"));
}

#[test]
fn real_tum_kitti_and_euroc_files_are_detected_and_read() {
    let (gt, f) = read_trajectory(&real("evo_trajectories/freiburg1_xyz-groundtruth.txt")).unwrap();
    assert_eq!(f, TrajectoryFormat::Tum);
    assert_eq!(gt.len(), 3000);
    gt.check_increasing(Path::new("gt")).unwrap();
    let (est, _) = read_trajectory(&real("evo_trajectories/freiburg1_xyz-rgbdslam.txt")).unwrap();
    assert!((est.stamps[0] - 1_305_031_102.160_407).abs() < 1e-6);
    assert!((est.poses[0].translation.vector - Vector3::new(1.344379, 0.627206, 1.661754)).norm() < 1e-9);

    let (kitti, f) = read_trajectory(&real("evo_trajectories/KITTI_00_gt.txt")).unwrap();
    assert_eq!(f, TrajectoryFormat::Kitti);
    assert_eq!(kitti.len(), 4541);
    assert!(
        (kitti.poses[1].translation.vector - Vector3::new(-4.690294e-02, -2.839928e-02, 8.586941e-01)).norm() < 1e-9
    );
    let timed = datasets::io::formats::trajectory::read_kitti(
        &real("evo_trajectories/KITTI_00_gt.txt"),
        Some(&real("evo_trajectories/KITTI_00_gt_times.txt")),
    )
    .unwrap();
    assert!((timed.stamps[1] - 0.1037359).abs() < 1e-9);

    let (euroc, f) = read_trajectory(&real("evo_trajectories/V102_groundtruth.csv")).unwrap();
    assert_eq!(f, TrajectoryFormat::Euroc);
    assert!((euroc.stamps[0] - 1_403_715_524.907_143).abs() < 1e-6);
    let q = euroc.poses[0].rotation.quaternion();
    assert!((q.w - 0.161996).abs() < 1e-5 && (q.i - 0.789985).abs() < 1e-5);
}

#[test]
fn odometry_and_imu_csv_round_trip_and_report_problems() {
    let dir = tempfile::tempdir().unwrap();
    let odo: Vec<OdometrySample> = (0..10)
        .map(|k| OdometrySample {
            timestamp: k as f64 * 0.1,
            x: 0.005 * k as f64,
            y: 0.0,
            yaw: 0.01 * k as f64,
            v: 0.05,
            omega: 0.1,
        })
        .collect();
    let path = dir.path().join("odom.csv");
    write_odometry(&path, &odo).unwrap();
    let back = read_odometry(&path).unwrap();
    assert_eq!(back.len(), 10);
    assert!((back[7].x - odo[7].x).abs() < 1e-9 && (back[7].yaw - odo[7].yaw).abs() < 1e-9);

    let imu: Vec<ImuSample> = (0..5)
        .map(|k| ImuSample { timestamp: k as f64 * 0.02, accel: [0.1, -0.2, 9.81], gyro: [0.0, 0.001, -0.3] })
        .collect();
    let ipath = dir.path().join("imu.csv");
    write_imu(&ipath, &imu).unwrap();
    assert_eq!(read_imu(&ipath).unwrap(), imu);

    // Columns are found by name: another order and an extra column load.
    std::fs::write(&path, "v,timestamp,x,y,yaw,omega,extra\n0.05,0.0,1,2,3,4,99\n").unwrap();
    let o = read_odometry(&path).unwrap();
    assert_eq!((o[0].v, o[0].x, o[0].omega), (0.05, 1.0, 4.0));
    std::fs::write(&path, "timestamp,x,y,yaw,v\n0,0,0,0,0\n").unwrap();
    assert!(message(read_odometry(&path).unwrap_err()).contains("no `omega` column"));
    std::fs::write(&path, "timestamp,x,y,yaw,v,omega\n1,0,0,0,0,0\n0.5,0,0,0,0,0\n").unwrap();
    let m = message(read_odometry(&path).unwrap_err());
    assert!(m.contains("odom.csv:3") && m.contains("does not increase"), "{m}");
    std::fs::write(&path, "timestamp,x,y,yaw,v,omega\n1,0,NaN,0,0,0\n").unwrap();
    assert!(message(read_odometry(&path).unwrap_err()).contains("column `y`"));
}

#[test]
fn calibration_round_trips_and_rejects_bad_matrices() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("calib.json");
    let calib = Calibration {
        camera: PinholeCamera::kinect(),
        camera_from_lidar: Pose3::from_parts(
            Translation3::new(0.0, 0.3, -0.1),
            UnitQuaternion::from_euler_angles(-1.5, 0.0, -1.5),
        ),
        robot_from_lidar: Pose3::from_parts(Translation3::new(0.0, 0.0, 0.75), UnitQuaternion::identity()),
    };
    write_calibration(&path, &calib).unwrap();
    let back = read_calibration(&path).unwrap();
    assert_eq!(back.camera, calib.camera);
    assert!((back.camera_from_lidar.translation.vector - calib.camera_from_lidar.translation.vector).norm() < 1e-12);
    assert!(back.camera_from_lidar.rotation.angle_to(&calib.camera_from_lidar.rotation) < 1e-9);

    let text = std::fs::read_to_string(&path).unwrap();
    std::fs::write(&path, text.replacen("525.0", "-1.0", 1)).unwrap();
    let focal = message(read_calibration(&path).unwrap_err());
    assert!(focal.contains("camera.fx: focal length -1 px outside [1, 64000]"), "{focal}");
    // Absurd but finite: a focal length of 1e300 pixels, a principal point a kilometre of pixels away.
    for (from, to, expected) in [("525.0", "1e300", "camera.fx: focal length 1e300"), ("319.5", "1e6", "camera.cx")] {
        std::fs::write(&path, text.replacen(from, to, 1)).unwrap();
        let m = message(read_calibration(&path).unwrap_err());
        assert!(m.contains("calib.json") && m.contains(expected), "{m}");
    }
    let bad = r#"{"camera": {"width": 640, "height": 480, "fx": 525, "fy": 525, "cx": 319.5, "cy": 239.5},
        "camera_from_lidar": [[2,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]]}"#;
    std::fs::write(&path, bad).unwrap();
    assert!(message(read_calibration(&path).unwrap_err()).contains("camera_from_lidar is not a rigid transform"));
    std::fs::write(&path, "{\"camera\": {\"width\": 640,\n \"heigth\": 480}}").unwrap();
    let m = message(read_calibration(&path).unwrap_err());
    assert!(m.contains("calib.json") && m.contains("line 2"), "{m}");
}

#[test]
fn coco_round_trips_and_checks_references() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("train.json");
    let data = CocoDataset {
        info: None,
        images: vec![CocoImage { id: 1, file_name: "images/000001.png".into(), width: 640, height: 480 }],
        annotations: vec![CocoAnnotation {
            id: 7,
            image_id: 1,
            category_id: 1,
            bbox: [100.0, 120.0, 40.0, 40.0],
            area: 1600.0,
            iscrowd: 0,
            corner_type: Some("floor".into()),
            point: Some([120.0, 140.0]),
        }],
        categories: vec![CocoCategory { id: 1, name: "corner".into(), supercategory: None }],
    };
    write_coco(&path, &data).unwrap();
    assert_eq!(read_coco(&path).unwrap(), data);

    // A file from another tool: extra fields, no corner attributes.
    std::fs::write(&path, r#"{"info": {"year": 2024}, "licenses": [], "images": [{"id": 3, "file_name": "a.jpg", "width": 10, "height": 10, "license": 0}],
        "annotations": [{"id": 1, "image_id": 3, "category_id": 2, "bbox": [1, 2, 3, 4], "area": 12, "iscrowd": 0, "segmentation": []}],
        "categories": [{"id": 2, "name": "corner", "supercategory": "corner"}]}"#).unwrap();
    let other = read_coco(&path).unwrap();
    assert_eq!(other.annotations[0].bbox(), datasets::bbox::BBox::new(1.0, 2.0, 4.0, 6.0));

    let mut broken = data.clone();
    broken.annotations[0].image_id = 99;
    write_coco(&path, &broken).unwrap();
    assert!(message(read_coco(&path).unwrap_err()).contains("unknown image 99"));
    // Boxes of zero size or outside their image are errors, not AP 0.
    for (bbox, expected) in [
        ([10.0, 10.0, 0.0, 5.0], "zero-size bbox"),
        ([600.0, 10.0, 96.0, 96.0], "outside its 640x480 image"),
        ([-50.0, 10.0, 20.0, 20.0], "outside its 640x480 image"),
    ] {
        let mut broken = data.clone();
        broken.images[0].width = 640;
        broken.images[0].height = 480;
        broken.annotations[0].bbox = bbox;
        write_coco(&path, &broken).unwrap();
        let m = message(read_coco(&path).unwrap_err());
        assert!(m.contains(expected) && m.contains("train.json"), "{m}");
    }
    std::fs::write(&path, "{\"images\": [}").unwrap();
    let m = message(read_coco(&path).unwrap_err());
    assert!(m.contains("train.json") && m.contains("line 1"), "{m}");
}

#[test]
fn declared_sizes_beyond_the_data_are_errors_not_allocations() {
    let dir = tempfile::tempdir().unwrap();
    let header = |points: &str, size: &str, data: &str| {
        format!(
            "VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\n{size}\nPOINTS {points}\nDATA {data}\n"
        )
    };
    let write = |name: &str, text: String, body: &[u8]| {
        let path = dir.path().join(name);
        let mut bytes = text.into_bytes();
        bytes.extend_from_slice(body);
        std::fs::write(&path, bytes).unwrap();
        path
    };
    let huge = (1u64 << 62).to_string();
    for (name, points, size, data) in [
        ("trillion.pcd", "1000000000000", "WIDTH 1000000000000\nHEIGHT 1", "binary"),
        ("two62.pcd", huge.as_str(), &*format!("WIDTH {huge}\nHEIGHT 1"), "binary"),
        ("compressed.pcd", "1000000000000", "WIDTH 1000000000000\nHEIGHT 1", "binary_compressed"),
        ("ascii.pcd", "1000000000000", "WIDTH 1000000000000\nHEIGHT 1", "ascii"),
    ] {
        let path = write(name, header(points, size, data), &[0u8; 24]);
        let e = message(read_cloud(&path, NonFinite::Drop).unwrap_err());
        assert!(e.contains(name), "{name}: {e}");
    }
    let overflow = write("overflow.pcd", header("1", "WIDTH 18446744073709551615\nHEIGHT 2", "binary"), &[0u8; 12]);
    assert!(message(read_cloud(&overflow, NonFinite::Drop).unwrap_err()).contains("overflows"));
    let zero =
        "VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 0 1 1\nWIDTH 1\nHEIGHT 1\nPOINTS 1\nDATA ascii\n";
    for data in ["ascii", "binary"] {
        let path = write(&format!("count0-{data}.pcd"), zero.replace("DATA ascii", &format!("DATA {data}")), b"1 2\n");
        assert!(message(read_cloud(&path, NonFinite::Drop).unwrap_err()).contains("field `x` has COUNT 0"), "{data}");
    }
    // A count lower than the data: the rest is not silently ignored.
    let low = write("low.pcd", header("1", "WIDTH 1\nHEIGHT 1", "binary"), &[1u8; 24]);
    assert!(message(read_cloud(&low, NonFinite::Drop).unwrap_err()).contains("after the 1 points the header declares"));
    // Zeros after the points are PCL's page padding.
    let padded = write("padded.pcd", header("1", "WIDTH 1\nHEIGHT 1", "binary"), &[0u8; 4096]);
    assert_eq!(read_cloud(&padded, NonFinite::Drop).unwrap().len(), 1);
    let ply = |count: &str, body: &[u8]| {
        let mut bytes = format!(
            "ply\nformat binary_little_endian 1.0\nelement vertex {count}\nproperty float x\nproperty float y\nproperty float z\nend_header\n"
        )
        .into_bytes();
        bytes.extend_from_slice(body);
        bytes
    };
    let path = dir.path().join("huge.ply");
    std::fs::write(&path, ply("1000000000000", &[0u8; 24])).unwrap();
    assert!(message(read_cloud(&path, NonFinite::Drop).unwrap_err()).contains("file ends inside the binary body"));
    std::fs::write(&path, ply("1", &[0u8; 24])).unwrap();
    assert!(message(read_cloud(&path, NonFinite::Drop).unwrap_err()).contains("12 bytes after the items"));
    std::fs::write(&path, ply("2", &[0u8; 24])).unwrap();
    assert_eq!(read_cloud(&path, NonFinite::Drop).unwrap().len(), 2);
}

#[cfg(unix)]
#[test]
fn a_fifo_is_refused_at_once_instead_of_waiting_for_a_writer() {
    let dir = tempfile::tempdir().unwrap();
    let fifo = dir.path().join("scan.pcd");
    let made = std::process::Command::new("mkfifo").arg(&fifo).status().expect("mkfifo runs");
    assert!(made.success());
    let e = message(read_cloud(&fifo, NonFinite::Drop).unwrap_err());
    assert!(e.contains("scan.pcd") && e.contains("not a regular file"), "{e}");
    let e = datasets::io::recording::Recording::open(&fifo).unwrap_err().to_string();
    assert!(e.contains("not a regular file"), "{e}");
}

/// Inputs the fuzzer found: each was a hang, a panic or a wrong result.
#[test]
fn fuzzer_findings_are_errors_naming_the_file() {
    // A binary PLY element without properties and 10^12 items: walked item
    // by item, it hung; the counts are now checked against the file first.
    let ply = b"ply\nformat binary_little_endian 1.0\nelement ghost 1000000000000\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\nend_header\n\0\0\0\0\0\0\0\0\0\0\0\0";
    let e = ply::read_ply_bytes(Path::new("ghost.ply"), ply, NonFinite::Drop).unwrap_err().to_string();
    assert!(e.contains("ghost.ply") && e.contains("no properties"), "{e}");
    let ply = b"ply\nformat binary_little_endian 1.0\nelement vertex 1000000\nproperty float x\nproperty float y\nproperty float z\nend_header\n\0\0\0\0";
    let e = ply::read_ply_bytes(Path::new("short.ply"), ply, NonFinite::Drop).unwrap_err().to_string();
    assert!(e.contains("short.ply") && e.contains("at least 12000000 bytes"), "{e}");
    // A quaternion with a component of 1e308: its length overflowed, and the
    // "normalised" rotation was NaN.
    let tum = "0 0 0 0 0 1e308 0 1\n";
    let e = trajectory::parse_tum(Path::new("big.txt"), tum).unwrap_err().to_string();
    assert!(e.contains("big.txt:1") && e.contains("quaternion length"), "{e}");
    let almost = "0 0 0 0 0 0 0 0.99\n";
    assert!(trajectory::parse_tum(Path::new("ok.txt"), almost).is_ok(), "a rounded unit quaternion reads");
}
