//! Roles of a recording's topics: found by type when one topic has it,
//! named by a flag otherwise; two candidates are an error that lists them.

use std::collections::BTreeMap;

use datasets::formats::PointCloud;
use datasets::recording::Recording;
use datasets::recording::mcap_export::point_cloud2;
use localize::bag_sequence::{BagOptions, find_roles};

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
