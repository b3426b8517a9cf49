//! Cross-crate check of the sequence folder contract (DESIGN.md): a generated
//! sequence reads back through the public readers with one image and one
//! cloud per ground-truth pose, and odometry and IMU cover its time span.

use datasets::io::formats::stamped_files::stamp_name;
use datasets::io::formats::{self, NonFinite};
use datasets::simulator::generate::{DatagenConfig, generate};

#[test]
fn a_generated_sequence_satisfies_the_folder_contract() {
    let dir = tempfile::tempdir().unwrap();
    let mut config = DatagenConfig::default();
    config.detection.images = 2;
    config.detection.train = 1;
    config.sequence.frames = Some(5);
    config.sequence.speed_mps = 0.5;
    generate(dir.path(), &config).unwrap();
    let seq = dir.path().join("sequence");

    let truth = formats::read_tum(&seq.join("groundtruth.txt")).unwrap();
    truth.check_increasing(&seq.join("groundtruth.txt")).unwrap();
    assert_eq!(truth.len(), 5);
    let calib = formats::read_calibration(&seq.join("calib.json")).unwrap();
    for &t in &truth.stamps {
        let image = datasets::atomic::read_image(&seq.join("rgb").join(format!("{}.png", stamp_name(t)))).unwrap();
        assert_eq!((image.width(), image.height()), (calib.camera.width, calib.camera.height));
        let cloud =
            formats::read_cloud(&seq.join("cloud").join(format!("{}.pcd", stamp_name(t))), NonFinite::Reject).unwrap();
        assert!(cloud.len() > 5000);
    }
    let odometry = formats::read_odometry(&seq.join("odom.csv")).unwrap();
    let imu = formats::read_imu(&seq.join("imu.csv")).unwrap();
    let (first, last) = (truth.stamps[0], *truth.stamps.last().unwrap());
    assert!(odometry[0].timestamp <= first && odometry.last().unwrap().timestamp >= last);
    assert!(imu[0].timestamp <= first && imu.last().unwrap().timestamp >= last);
    // Odometry starts where the ground truth starts: the world origin, facing +x.
    let start = truth.poses[0].translation.vector;
    assert!(start.norm() < 1e-9 && odometry[0].x == 0.0 && odometry[0].yaw == 0.0);
    // 4 s at 0.5 m/s is 2 m forward, which the odometry sees to within its drift.
    assert!((odometry.last().unwrap().x - 2.0).abs() < 0.1);
}
