//! Seed inputs: small valid files the project writes itself (always there),
//! plus the files of any folders given (the repository's test recordings,
//! real files of other tools), each routed to the targets that read it.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use datasets::io::formats::{self, PcdData, PlyFormat, PointCloud, Trajectory};
use datasets::io::recording::messages::Encoding;
use datasets::io::recording::{Recording, mcap_export};
use datasets::math::Pose3;
use nalgebra::{Point3, UnitQuaternion, Vector3};

use crate::targets::{Target, message_selector};

/// Seed files larger than this are skipped (a fuzzer's time is better spent
/// on many small inputs; the readers' size handling is reached by mutation).
pub const MAX_SEED_BYTES: u64 = 1 << 20;

/// Every target's seeds: the generated ones, then those found under `dirs`.
pub fn collect(dirs: &[PathBuf]) -> BTreeMap<&'static str, Vec<Vec<u8>>> {
    let mut seeds: BTreeMap<&'static str, Vec<Vec<u8>>> = BTreeMap::new();
    for (target, data) in generated() {
        seeds.entry(target.name()).or_default().push(data);
    }
    let mut files = Vec::new();
    for dir in dirs {
        walk(dir, &mut files);
    }
    files.sort();
    for file in files {
        let Ok(meta) = std::fs::metadata(&file) else { continue };
        if meta.len() > MAX_SEED_BYTES {
            continue;
        }
        let Ok(data) = std::fs::read(&file) else { continue };
        for target in Target::ALL.into_iter().filter(|t| t.accepts(&file)) {
            seeds.entry(target.name()).or_default().push(data.clone());
        }
        let recording = [Target::Mcap, Target::Ros1Bag, Target::Rosbag2Metadata].iter().any(|t| t.accepts(&file));
        // A .db3 is read through its folder's metadata.yaml when it has one.
        let lone_db3 =
            Target::Sqlite3.accepts(&file) && file.parent().is_some_and(|d| !d.join("metadata.yaml").is_file());
        if recording || lone_db3 {
            let source = if file.ends_with("metadata.yaml") { file.parent().unwrap_or(&file) } else { &file };
            seeds.entry(Target::RosMessage.name()).or_default().extend(messages_of(source));
        }
    }
    for list in seeds.values_mut() {
        list.sort();
        list.dedup();
    }
    seeds
}

fn walk(dir: &Path, out: &mut Vec<PathBuf>) {
    let Ok(entries) = std::fs::read_dir(dir) else { return };
    for entry in entries.flatten() {
        let path = entry.path();
        match entry.file_type() {
            Ok(t) if t.is_dir() => walk(&path, out),
            Ok(t) if t.is_file() => out.push(path),
            _ => {}
        }
    }
}

/// Up to a few messages of each known topic of a recording, as
/// `ros_message` inputs (selector byte, then the message).
fn messages_of(path: &Path) -> Vec<Vec<u8>> {
    let Ok(recording) = Recording::open(path) else { return Vec::new() };
    let wanted: Vec<usize> = (0..recording.topics.len()).filter(|&k| recording.topics[k].kind().is_some()).collect();
    let mut out = Vec::new();
    let mut per_topic = vec![0usize; recording.topics.len()];
    let _ = recording.read(&wanted, &mut |m| {
        let topic = &recording.topics[m.topic];
        if per_topic[m.topic] < 3 {
            per_topic[m.topic] += 1;
            let kind = topic.kind().expect("a wanted topic has a kind");
            let mut input = vec![message_selector(kind, topic.encoding)];
            input.extend_from_slice(m.data);
            out.push(input);
        }
        Ok(())
    });
    out
}

fn small_cloud() -> PointCloud {
    let points: Vec<Point3<f32>> =
        (0..24).map(|k| Point3::new(k as f32 * 0.25, (k % 5) as f32 - 2.0, (k % 3) as f32 * 0.5)).collect();
    let mut cloud = PointCloud::new(points, Some((0..24).map(|k| k as f32 / 24.0).collect()));
    cloud.times = Some((0..24).map(|k| k as f32 * 0.004).collect());
    cloud
}

fn small_trajectory() -> Trajectory {
    let mut t = Trajectory::default();
    for k in 0..6 {
        let rotation = UnitQuaternion::from_euler_angles(0.01 * k as f64, 0.0, 0.3 * k as f64);
        t.push(1.5 + k as f64 * 0.1, Pose3::from_parts(Vector3::new(k as f64, 0.5, 0.1).into(), rotation));
    }
    t
}

/// Written into a temporary folder by a writer that takes a path, and read back.
fn via_file(name: &str, write: impl FnOnce(&Path) -> datasets::Result<()>) -> Vec<u8> {
    let dir = tempfile::tempdir().expect("a temporary folder");
    let path = dir.path().join(name);
    write(&path).expect("writing a seed");
    std::fs::read(&path).expect("reading a seed back")
}

/// Valid inputs of every target, written by the project's own writers.
pub fn generated() -> Vec<(Target, Vec<u8>)> {
    let cloud = small_cloud();
    let trajectory = small_trajectory();
    let mut out = Vec::new();
    for data in [PcdData::Ascii, PcdData::Binary, PcdData::BinaryCompressed] {
        out.push((Target::Pcd, formats::pcd::pcd_bytes(&cloud, data)));
    }
    for format in [PlyFormat::Ascii, PlyFormat::BinaryLittleEndian, PlyFormat::BinaryBigEndian] {
        out.push((Target::Ply, formats::ply::ply_bytes(&cloud, format)));
    }
    out.push((Target::KittiBin, via_file("scan.bin", |p| formats::cloud::write_kitti_bin(p, &cloud))));
    let raw: Vec<u8> = (0..600u32).map(|k| (k % 7 * 31 + k / 50) as u8).collect();
    let mut lzf = (raw.len() as u32).to_le_bytes().to_vec();
    lzf.extend(formats::lzf::compress(&raw));
    out.push((Target::Lzf, lzf));
    out.push((Target::Trajectory, formats::trajectory::tum_text(&trajectory).into_bytes()));
    out.push((Target::Trajectory, via_file("kitti.txt", |p| formats::trajectory::write_kitti(p, &trajectory))));
    out.push((
        Target::Trajectory,
        b"#timestamp,p_x,p_y,p_z,q_w,q_x,q_y,q_z\n1403715273262142976,0.1,0.2,0.3,1,0,0,0\n1403715273267142912,0.1,0.2,0.31,1,0,0,0\n".to_vec(),
    ));
    let odometry = small_odometry();
    out.push((Target::SensorCsv, via_file("odom.csv", |p| formats::write_odometry(p, &odometry))));
    let imu = small_imu();
    out.push((Target::SensorCsv, via_file("imu.csv", |p| formats::write_imu(p, &imu))));
    let calib = small_calibration(&trajectory);
    out.push((Target::Calib, via_file("calib.json", |p| formats::write_calibration(p, &calib))));
    let coco = small_coco();
    out.push((Target::Coco, via_file("labels.json", |p| formats::write_coco(p, &coco))));
    for backbone in [infer::Backbone::FasterRcnn, infer::Backbone::Vgg16, infer::Backbone::Alexnet] {
        let config = infer::DetectorConfig::new(backbone, 0.25);
        out.push((Target::CheckpointConfig, serde_json::to_vec_pretty(&config).expect("a config serialises")));
    }
    out.extend(rosbag2_metadata_seeds().into_iter().map(|m| (Target::Rosbag2Metadata, m)));
    let messages = message_seeds(&cloud, &calib, &imu[1], &odometry[1], &trajectory);
    out.push((Target::McapContent, uncompressed_mcap(&messages)));
    for (kind, data) in messages {
        let mut input = vec![message_selector(kind, Encoding::Cdr)];
        input.extend(data);
        out.push((Target::RosMessage, input));
    }
    out.push((Target::Map, map_folder()));
    out
}

fn small_odometry() -> Vec<formats::OdometrySample> {
    (0..5)
        .map(|k| formats::OdometrySample {
            timestamp: k as f64 * 0.02,
            x: k as f64 * 0.01,
            y: 0.0,
            yaw: 0.1,
            v: 0.5,
            omega: 0.0,
        })
        .collect()
}

fn small_imu() -> Vec<formats::ImuSample> {
    (0..5)
        .map(|k| formats::ImuSample { timestamp: k as f64 * 0.005, accel: [0.1, 0.0, 9.81], gyro: [0.0, 0.0, 0.01] })
        .collect()
}

fn small_calibration(trajectory: &formats::Trajectory) -> formats::Calibration {
    formats::Calibration {
        camera: datasets::camera::PinholeCamera { width: 640, height: 480, fx: 525.0, fy: 525.0, cx: 319.5, cy: 239.5 },
        camera_from_lidar: trajectory.poses[2],
        robot_from_lidar: trajectory.poses[1],
    }
}

fn small_coco() -> formats::CocoDataset {
    formats::CocoDataset {
        info: None,
        images: vec![formats::CocoImage { id: 1, file_name: "0000000001.500000.png".into(), width: 640, height: 480 }],
        annotations: vec![formats::CocoAnnotation {
            id: 1,
            image_id: 1,
            category_id: 1,
            bbox: [100.0, 120.0, 16.0, 16.0],
            area: 256.0,
            iscrowd: 0,
            corner_type: Some("floor".into()),
            point: Some([108.0, 128.0]),
        }],
        categories: vec![formats::CocoCategory { id: 1, name: "corner".into(), supercategory: None }],
    }
}

/// metadata.yaml files: a plain one, anchors and aliases that expand a
/// little, and a billion-node one the reader must refuse before expanding it.
fn rosbag2_metadata_seeds() -> Vec<Vec<u8>> {
    vec![
        b"rosbag2_bagfile_information:\n  version: 5\n  storage_identifier: mcap\n  relative_file_paths:\n    - bag_0.mcap\n  compression_format: zstd\n  compression_mode: FILE\n".to_vec(),
        b"rosbag2_bagfile_information:\n  version: 5\n  storage_identifier: &s sqlite3\n  relative_file_paths: &f\n    - bag_0.db3\n  files: *f\n  custom: [*s, *s, *f]\n".to_vec(),
        alias_bomb(9, 10).into_bytes(),
    ]
}

/// One message of every kind the readers decode, as CDR.
fn message_seeds(
    cloud: &formats::PointCloud,
    calib: &formats::Calibration,
    imu: &formats::ImuSample,
    odometry: &formats::OdometrySample,
    trajectory: &formats::Trajectory,
) -> [(datasets::io::recording::MessageKind, Vec<u8>); 7] {
    [
        (datasets::io::recording::MessageKind::PointCloud2, mcap_export::point_cloud2(1_500_000_000, "lidar", cloud)),
        (
            datasets::io::recording::MessageKind::CompressedImage,
            mcap_export::compressed_image(1_500_000_000, "camera", "png", &tiny_png()),
        ),
        (datasets::io::recording::MessageKind::CameraInfo, mcap_export::camera_info(1_500_000_000, "camera", calib)),
        (datasets::io::recording::MessageKind::Imu, mcap_export::imu(imu, "imu")),
        (datasets::io::recording::MessageKind::Odometry, mcap_export::odometry(odometry, "odom", "base_link")),
        (
            datasets::io::recording::MessageKind::TfMessage,
            mcap_export::tf_message(&[(1_500_000_000, "base_link", "lidar", trajectory.poses[3])]),
        ),
        (
            datasets::io::recording::MessageKind::PoseStamped,
            mcap_export::pose_stamped(1_500_000_000, "map", &trajectory.poses[4]),
        ),
    ]
}

/// A metadata.yaml whose aliases nest `levels` deep, each `width` wide:
/// `width^levels` nodes once expanded.
pub fn alias_bomb(levels: usize, width: usize) -> String {
    let mut yaml = String::from("a0: &a0 [x]\n");
    for level in 1..=levels {
        let refs = vec![format!("*a{}", level - 1); width].join(", ");
        yaml.push_str(&format!("a{level}: &a{level} [{refs}]\n"));
    }
    yaml.push_str(&format!(
        "rosbag2_bagfile_information:\n  version: 5\n  storage_identifier: mcap\n  relative_file_paths: *a{levels}\n"
    ));
    yaml
}

/// One MCAP with uncompressed chunks (and their CRCs), one message of each
/// kind on a topic of its type: the `mcap_content` target's seed.
fn uncompressed_mcap(messages: &[(datasets::io::recording::MessageKind, Vec<u8>)]) -> Vec<u8> {
    let mut out = std::io::Cursor::new(Vec::new());
    let mut writer =
        mcap::WriteOptions::new().compression(None).profile("ros2").create(&mut out).expect("an MCAP writer");
    for (k, (kind, data)) in messages.iter().enumerate() {
        let schema = writer.add_schema(kind.type_name(), "ros2msg", b"").expect("a schema");
        let channel = writer
            .add_channel(schema, &format!("/topic{k}"), "cdr", &std::collections::BTreeMap::new())
            .expect("a channel");
        let header = mcap::records::MessageHeader {
            channel_id: channel,
            sequence: k as u32,
            log_time: 1_500_000_000 + k as u64,
            publish_time: 1_500_000_000 + k as u64,
        };
        writer.write_to_known_channel(&header, data).expect("a message");
    }
    writer.finish().expect("a finished MCAP");
    drop(writer);
    out.into_inner()
}

/// A small map as `localize run` writes it (the `map` target's layout:
/// map.json, NUL, map.ply).
fn map_folder() -> Vec<u8> {
    use localize::map_output::{SavedMap, write_map};
    let corner = serde_json::json!({"position": [1.0, 2.0, 1.5], "observations": 3,
        "sum": [3.0, 6.0, 4.5], "square_sum": 21.76, "used": 3});
    let wall = serde_json::json!({"normal": [1.0, 0.0, 0.0], "distance": 2.0, "observations": 3,
        "normal_sum": [3.0, 0.0, 0.0], "distance_sum": 6.0, "distance_square_sum": 12.01,
        "weight": 3.0, "point_sum": [6.0, 1.5, 3.0]});
    let trajectory = small_trajectory();
    let map = SavedMap {
        corners: vec![serde_json::from_value(corner).expect("a corner")],
        walls: vec![serde_json::from_value(wall).expect("a wall")],
        wall_axis: Some(0.1),
        points: (0..4)
            .map(|k| localize::estimation::point_map::MapPoint {
                position: datasets::math::Vec3::new(2.0, k as f64 * 0.1, 1.0),
                normal: -datasets::math::Vec3::x(),
            })
            .collect(),
        keyframes: trajectory.poses[..3].to_vec(),
        truth_origin: Some(trajectory.poses[1]),
    };
    let dir = tempfile::tempdir().expect("a temporary folder");
    write_map(dir.path(), &map).expect("a map writes");
    let mut bytes = std::fs::read(dir.path().join("map.json")).expect("map.json");
    bytes.push(0);
    bytes.extend(std::fs::read(dir.path().join("map.ply")).expect("map.ply"));
    bytes
}

fn tiny_png() -> Vec<u8> {
    let image =
        image::DynamicImage::ImageLuma8(image::GrayImage::from_fn(8, 6, |x, y| image::Luma([(x * 30 + y) as u8])));
    let mut bytes = std::io::Cursor::new(Vec::new());
    image.write_to(&mut bytes, image::ImageFormat::Png).expect("a PNG encodes");
    bytes.into_inner()
}
