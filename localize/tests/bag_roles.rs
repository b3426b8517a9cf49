//! Roles of a recording's topics: found by type when one topic has it,
//! named by a flag otherwise; two candidates are an error that lists them.

use std::collections::BTreeMap;

use datasets::io::formats::PointCloud;
use datasets::io::recording::Recording;
use datasets::io::recording::mcap_export::point_cloud2;
use localize::input::bag_sequence::{BagOptions, find_roles};

/// An MCAP with two PointCloud2 topics and nothing else.
fn two_lidars(path: &std::path::Path) {
    let file = std::io::BufWriter::new(std::fs::File::create(path).unwrap());
    let mut writer = mcap::WriteOptions::new().profile("ros2").create(file).unwrap();
    let schema = writer.add_schema("sensor_msgs/msg/PointCloud2", "ros2msg", b"").unwrap();
    let cloud = PointCloud::new(vec![nalgebra::Point3::new(1.0, 2.0, 3.0)], None);
    for (k, topic) in ["/velodyne_points", "/ouster/points"].iter().enumerate() {
        let channel = writer.add_channel(schema, topic, "cdr", &BTreeMap::new()).unwrap();
        let header =
            mcap::records::MessageHeader { channel_id: channel, sequence: k as u32, log_time: 5, publish_time: 5 };
        writer.write_to_known_channel(&header, &point_cloud2(5, "lidar", &cloud)).unwrap();
    }
    writer.finish().unwrap();
}

#[test]
fn two_candidate_topics_are_an_error_listing_both_until_one_is_named() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("two.mcap");
    two_lidars(&path);
    let recording = Recording::open(&path).unwrap();
    let e = find_roles(&recording, &BagOptions::default()).unwrap_err().to_string();
    assert!(
        e.contains("several topics could be the LIDAR: /ouster/points (sensor_msgs/msg/PointCloud2), /velodyne_points (sensor_msgs/msg/PointCloud2); choose one with --lidar-topic"),
        "{e}"
    );
    let named = BagOptions { lidar_topic: Some("/ouster/points".into()), ..Default::default() };
    // A recording of LIDARs alone is a LIDAR-only rig: no IMU, no wheels.
    let (roles, notes) = find_roles(&recording, &named).unwrap();
    assert_eq!(recording.topics[roles.lidar].name, "/ouster/points");
    assert_eq!((roles.imu, roles.odometry), (None, None));
    assert!(notes.iter().any(|n| n.starts_with("imu") && n.ends_with("none")), "{notes:?}");
}

#[test]
fn scans_whose_stamps_are_never_set_are_an_error_not_a_one_pose_trajectory() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("zero.mcap");
    let file = std::io::BufWriter::new(std::fs::File::create(&path).unwrap());
    let mut writer = mcap::WriteOptions::new().profile("ros2").create(file).unwrap();
    let schema = writer.add_schema("sensor_msgs/msg/PointCloud2", "ros2msg", b"").unwrap();
    let channel = writer.add_channel(schema, "/points", "cdr", &BTreeMap::new()).unwrap();
    let cloud = PointCloud::new(vec![nalgebra::Point3::new(1.0, 2.0, 3.0)], None);
    // Logged 0.1 s apart, every header stamp 0.
    for k in 0..20u32 {
        let t = 1_000_000_000 + u64::from(k) * 100_000_000;
        let header = mcap::records::MessageHeader { channel_id: channel, sequence: k, log_time: t, publish_time: t };
        writer.write_to_known_channel(&header, &point_cloud2(0, "lidar", &cloud)).unwrap();
    }
    writer.finish().unwrap();
    drop(writer);
    let options = BagOptions::default();
    let error = localize::input::bag_sequence::BagSequence::open(&path, &options, &Default::default())
        .err()
        .unwrap()
        .to_string();
    assert!(error.contains("zero.mcap") && error.contains("19 of the 20 messages of /points repeat"), "{error}");
}
