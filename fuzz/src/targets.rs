//! One fuzz target per parser. A target feeds arbitrary bytes to the parser
//! as a user's file would reach it. An error is the expected answer to a bad
//! file; a panic, an abort, a hang, or an accepted file whose result breaks
//! the parser's own promises (a point count that does not match its
//! intensities, a NaN that should have been dropped) is a bug.

use std::collections::HashMap;
use std::path::Path;

use datasets::io::formats::{self, NonFinite, PointCloud};
use datasets::io::recording::messages::{self, Encoding, MessageKind};
use datasets::io::recording::{mcap_file, ros1_bag, rosbag2, sqlite3};

#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Target {
    Pcd,
    Ply,
    KittiBin,
    Lzf,
    Trajectory,
    SensorCsv,
    Calib,
    Coco,
    CheckpointConfig,
    Rosbag2Metadata,
    Mcap,
    McapContent,
    Ros1Bag,
    Sqlite3,
    RosMessage,
    Map,
}

impl Target {
    pub const ALL: [Target; 16] = [
        Self::Pcd,
        Self::Ply,
        Self::KittiBin,
        Self::Lzf,
        Self::Trajectory,
        Self::SensorCsv,
        Self::Calib,
        Self::Coco,
        Self::CheckpointConfig,
        Self::Rosbag2Metadata,
        Self::Mcap,
        Self::McapContent,
        Self::Ros1Bag,
        Self::Sqlite3,
        Self::RosMessage,
        Self::Map,
    ];

    pub fn name(self) -> &'static str {
        match self {
            Self::Pcd => "pcd",
            Self::Ply => "ply",
            Self::KittiBin => "kitti_bin",
            Self::Lzf => "lzf",
            Self::Trajectory => "trajectory",
            Self::SensorCsv => "sensor_csv",
            Self::Calib => "calib",
            Self::Coco => "coco",
            Self::CheckpointConfig => "checkpoint_config",
            Self::Rosbag2Metadata => "rosbag2_metadata",
            Self::Mcap => "mcap",
            Self::McapContent => "mcap_content",
            Self::Ros1Bag => "ros1_bag",
            Self::Sqlite3 => "sqlite3",
            Self::RosMessage => "ros_message",
            Self::Map => "map",
        }
    }

    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|t| t.name() == name)
    }

    /// Feeds `data` to the parser; panics only on a bug.
    pub fn run(self, data: &[u8]) {
        match self {
            Self::Pcd => {
                for policy in [NonFinite::Drop, NonFinite::Reject] {
                    if let Ok(cloud) = formats::pcd::read_pcd_bytes(Path::new("fuzz.pcd"), data, policy) {
                        check_cloud(&cloud, policy);
                    }
                }
            }
            Self::Ply => {
                if let Ok(cloud) = formats::ply::read_ply_bytes(Path::new("fuzz.ply"), data, NonFinite::Drop) {
                    check_cloud(&cloud, NonFinite::Drop);
                }
            }
            Self::KittiBin => {
                if let Ok(cloud) = formats::cloud::parse_kitti_bin(Path::new("fuzz.bin"), data, NonFinite::Drop) {
                    check_cloud(&cloud, NonFinite::Drop);
                    assert_eq!(cloud.len() + cloud.dropped_non_finite, data.len() / 16, "every record is a point");
                }
            }
            Self::Lzf => lzf(data),
            Self::Trajectory => trajectory(data),
            Self::SensorCsv => sensor_csv(data),
            Self::Calib => {
                if let Ok(calib) = formats::calib::parse_calibration(Path::new("calib.json"), &text(data)) {
                    assert!(calib.camera.validate().is_ok(), "an accepted camera is valid");
                    assert!(calib.camera_from_lidar.translation.vector.iter().all(|v| v.is_finite()));
                }
            }
            Self::Coco => {
                if let Ok(set) = formats::coco::parse_coco(Path::new("labels.json"), &text(data)) {
                    assert!(set.validate(std::path::Path::new("fuzz")).is_ok(), "an accepted COCO set is valid");
                }
            }
            Self::CheckpointConfig => {
                if let Ok(config) = infer::checkpoint::parse_config(Path::new("config.json"), &text(data)) {
                    assert!(config.validate().is_ok(), "an accepted configuration is valid");
                }
            }
            Self::Rosbag2Metadata => {
                let dir = Path::new("bag");
                if let Ok(meta) = rosbag2::parse_metadata(dir, &dir.join("metadata.yaml"), &text(data)) {
                    assert!(!meta.files.is_empty(), "accepted metadata lists files");
                }
            }
            Self::Mcap => mcap(data),
            Self::McapContent => mcap(&with_mcap_crcs(data)),
            Self::Ros1Bag => ros1(data),
            Self::Sqlite3 => sqlite(data),
            Self::RosMessage => ros_message(data),
            Self::Map => map(data),
        }
    }

    /// Whether a file of this name is an input of the target, for seeding it.
    pub fn accepts(self, path: &Path) -> bool {
        let name = path.file_name().and_then(|n| n.to_str()).unwrap_or_default().to_ascii_lowercase();
        let ext = path.extension().and_then(|e| e.to_str()).unwrap_or_default().to_ascii_lowercase();
        match self {
            Self::Pcd => ext == "pcd",
            Self::Ply => ext == "ply",
            Self::KittiBin => ext == "bin",
            Self::Lzf => false,
            Self::Trajectory => ext == "txt" || ext == "tum" || (ext == "csv" && name.contains("groundtruth")),
            Self::SensorCsv => ext == "csv",
            Self::Calib => name.starts_with("calib") && ext == "json",
            Self::Coco => ext == "json" && !name.starts_with("calib") && name != "config.json",
            Self::CheckpointConfig => name == "config.json",
            Self::Rosbag2Metadata => name == "metadata.yaml",
            Self::Mcap | Self::McapContent => ext == "mcap",
            Self::Ros1Bag => ext == "bag",
            Self::Sqlite3 => ext == "db3",
            Self::RosMessage | Self::Map => false,
        }
    }
}

fn text(data: &[u8]) -> String {
    String::from_utf8_lossy(data).into_owned()
}

fn check_cloud(cloud: &PointCloud, policy: NonFinite) {
    if let Some(i) = &cloud.intensity {
        assert_eq!(i.len(), cloud.len(), "one intensity per point");
    }
    if let Some(t) = &cloud.times {
        assert_eq!(t.len(), cloud.len(), "one time per point");
    }
    assert!(cloud.points.iter().all(|p| p.iter().all(|v| v.is_finite())), "non-finite points are dropped");
    if policy == NonFinite::Reject {
        assert_eq!(cloud.dropped_non_finite, 0, "rejecting drops nothing");
    }
}

/// The first 4 bytes (little endian, bounded) give the expected size.
fn lzf(data: &[u8]) {
    if data.len() < 4 {
        return;
    }
    let expected = u32::from_le_bytes(data[..4].try_into().expect("4 bytes")) as usize % (1 << 24);
    if let Ok(out) = formats::lzf::decompress(&data[4..], expected) {
        assert_eq!(out.len(), expected, "decompressed to the declared size");
        let again = formats::lzf::decompress(&formats::lzf::compress(&out), expected).expect("a round trip");
        assert_eq!(again, out, "compress then decompress is the identity");
    }
}

fn trajectory(data: &[u8]) {
    let text = text(data);
    let path = Path::new("trajectory.txt");
    if let Ok((trajectory, _)) = formats::trajectory::parse_trajectory(path, &text) {
        for (stamp, pose) in trajectory.stamps.iter().zip(&trajectory.poses) {
            assert!(stamp.is_finite(), "finite stamps");
            assert!(pose.translation.vector.iter().all(|v| v.is_finite()), "finite positions");
            assert!((pose.rotation.norm() - 1.0).abs() < 1e-6, "unit rotations");
        }
        let _ = trajectory.check_increasing(path);
    }
    let _ = formats::trajectory::parse_kitti(path, &text, Some(&[0.0, 1.0, 2.0]));
}

fn sensor_csv(data: &[u8]) {
    let text = text(data);
    if let Ok(odometry) = formats::sensor_csv::parse_odometry(Path::new("odom.csv"), &text) {
        assert!(odometry.windows(2).all(|w| w[1].timestamp > w[0].timestamp), "increasing stamps");
        assert!(odometry.iter().all(|s| [s.timestamp, s.x, s.y, s.yaw, s.v, s.omega].iter().all(|v| v.is_finite())));
    }
    if let Ok(imu) = formats::sensor_csv::parse_imu(Path::new("imu.csv"), &text) {
        assert!(imu.windows(2).all(|w| w[1].timestamp > w[0].timestamp), "increasing stamps");
        assert!(imu.iter().all(|s| s.accel.iter().chain(&s.gyro).all(|v| v.is_finite())));
    }
}

/// Decodes a message of a type localization reads, as it would.
fn decode_message(kind: MessageKind, encoding: Encoding, data: &[u8]) {
    use messages::{camera_info, geometry, image, point_cloud};
    match kind {
        MessageKind::PointCloud2 => {
            if let Ok(m) = messages::decode(encoding, data, point_cloud::point_cloud2) {
                check_cloud(&m.cloud, NonFinite::Drop);
            }
        }
        MessageKind::Image => {
            let _ = messages::decode(encoding, data, image::image);
        }
        MessageKind::CompressedImage => {
            let _ = messages::decode(encoding, data, image::compressed_image);
        }
        MessageKind::CameraInfo => {
            let _ = messages::decode(encoding, data, camera_info::camera_info);
        }
        MessageKind::Imu => {
            let _ = messages::decode(encoding, data, geometry::imu);
        }
        MessageKind::Odometry => {
            let _ = messages::decode(encoding, data, geometry::odometry);
        }
        MessageKind::TfMessage => {
            let _ = messages::decode(encoding, data, geometry::tf_message);
        }
        MessageKind::PoseStamped => {
            let _ = messages::decode(encoding, data, geometry::pose_stamped);
        }
        MessageKind::PoseWithCovarianceStamped => {
            let _ = messages::decode(encoding, data, geometry::pose_with_covariance_stamped);
        }
    }
}

pub const MESSAGE_KINDS: [MessageKind; 9] = MessageKind::ALL;

/// The byte that selects a message's kind and wire format in the
/// `ros_message` target (its first byte).
pub fn message_selector(kind: MessageKind, encoding: Encoding) -> u8 {
    let k = MESSAGE_KINDS.iter().position(|&m| m == kind).expect("a listed kind") as u8;
    k * 2 + u8::from(encoding == Encoding::Ros1)
}

fn ros_message(data: &[u8]) {
    let Some((&selector, body)) = data.split_first() else { return };
    let kind = MESSAGE_KINDS[(selector as usize / 2) % MESSAGE_KINDS.len()];
    let encoding = if selector % 2 == 1 { Encoding::Ros1 } else { Encoding::Cdr };
    decode_message(kind, encoding, body);
}

/// Visits every message of the container and decodes the known ones.
fn decode_all(
    topics: &[datasets::io::recording::TopicInfo],
    visit: impl FnOnce(&mut datasets::io::recording::RawVisitor<'_>),
) {
    let by_name: HashMap<&str, (Option<MessageKind>, Encoding)> =
        topics.iter().map(|t| (t.name.as_str(), (t.kind(), t.encoding))).collect();
    let mut on_message = |name: &str, _time: i64, data: &[u8]| {
        if let Some(&(Some(kind), encoding)) = by_name.get(name) {
            decode_message(kind, encoding, data);
        }
        Ok(())
    };
    visit(&mut on_message);
}

fn mcap(data: &[u8]) {
    let path = Path::new("fuzz.mcap");
    if let Ok(topics) = mcap_file::topics(path, data) {
        decode_all(&topics, |visit| {
            let _ = mcap_file::visit(path, data, visit);
        });
    }
}

fn ros1(data: &[u8]) {
    let path = Path::new("fuzz.bag");
    let Ok(bag) = ros1_bag::Ros1Bag::new(path, data) else { return };
    if let Ok(topics) = bag.topics() {
        decode_all(&topics, |visit| {
            let _ = bag.visit(visit);
        });
    }
}

/// SQLite reads from a file: the bytes go to one temporary file per thread.
fn sqlite(data: &[u8]) {
    thread_local! {
        static FILE: tempfile::NamedTempFile =
            tempfile::Builder::new().suffix(".db3").tempfile().expect("a temporary file");
    }
    FILE.with(|file| {
        std::fs::write(file.path(), data).expect("writing the temporary file");
        if let Ok(topics) = sqlite3::topics(file.path()) {
            decode_all(&topics, |visit| {
                let _ = sqlite3::visit(file.path(), visit);
            });
        }
    });
}

/// The MCAP with the CRCs of its uncompressed chunks and of its data section
/// recomputed, so that a mutation of a chunk's messages reaches the message
/// readers instead of stopping at the CRC check. Records are walked as far
/// as their lengths allow; the rest is left as it is.
pub fn with_mcap_crcs(data: &[u8]) -> Vec<u8> {
    const MAGIC: usize = 8;
    const CHUNK: u8 = 0x06;
    const DATA_END: u8 = 0x0F;
    let mut out = data.to_vec();
    let mut at = MAGIC;
    while at + 9 <= out.len() {
        let op = out[at];
        let len = u64::from_le_bytes(out[at + 1..at + 9].try_into().expect("8 bytes"));
        let body = at + 9;
        let Some(end) = usize::try_from(len).ok().and_then(|l| body.checked_add(l)).filter(|&e| e <= out.len()) else {
            break;
        };
        if op == CHUNK {
            fix_chunk_crc(&mut out[body..end]);
        } else if op == DATA_END && end - body >= 4 {
            let crc = crc32fast::hash(&out[..at]);
            out[body..body + 4].copy_from_slice(&crc.to_le_bytes());
        }
        at = end;
    }
    out
}

/// An uncompressed chunk's body: times (16 bytes), uncompressed size (8),
/// uncompressed CRC (4), compression (length-prefixed), records (length-prefixed).
fn fix_chunk_crc(body: &mut [u8]) {
    let u32_at = |b: &[u8], i: usize| b.get(i..i + 4).map(|s| u32::from_le_bytes(s.try_into().expect("4 bytes")));
    let Some(compression_len) = u32_at(body, 28) else { return };
    if compression_len != 0 || body.len() < 40 {
        return;
    }
    let records = &body[40..];
    let (size, crc) = (records.len() as u64, crc32fast::hash(records));
    body[16..24].copy_from_slice(&size.to_le_bytes());
    body[24..28].copy_from_slice(&crc.to_le_bytes());
    body[32..40].copy_from_slice(&size.to_le_bytes());
}

/// A map folder as `localize run --map` reads it: `map.json`, a NUL byte,
/// then `map.ply` (JSON text holds no raw NUL). An accepted map keeps the
/// reader's promises: poses, points, normals, corners and walls a run can
/// compute with.
fn map(data: &[u8]) {
    thread_local! {
        static DIR: tempfile::TempDir = tempfile::tempdir().expect("a temporary folder");
    }
    let split = data.iter().position(|&b| b == 0).unwrap_or(data.len());
    let (json, ply) = (&data[..split], data.get(split + 1..).unwrap_or(&[]));
    DIR.with(|dir| {
        std::fs::write(dir.path().join("map.json"), json).expect("writing map.json");
        std::fs::write(dir.path().join("map.ply"), ply).expect("writing map.ply");
        let Ok(map) = localize::map_output::read_map(dir.path()) else { return };
        let finite = |v: &datasets::math::Vec3| v.iter().all(|x| x.is_finite());
        for pose in map.keyframes.iter().chain(&map.truth_origin) {
            assert!(finite(&pose.translation.vector) && (pose.rotation.norm() - 1.0).abs() < 1e-9, "a keyframe");
        }
        for p in &map.points {
            assert!(finite(&p.position) && (p.normal.norm() - 1.0).abs() < 1e-2, "a map point: {p:?}");
        }
        for c in &map.corners {
            assert!(finite(&c.position) && c.spread_m().is_finite(), "a corner: {c:?}");
        }
        for w in &map.walls {
            let spreads = [w.offset_spread_m(), w.normal_spread_deg()];
            assert!(
                finite(&w.normal) && w.distance.is_finite() && spreads.iter().all(|s| s.is_finite()),
                "a wall: {w:?}"
            );
        }
        assert!(map.wall_axis.is_none_or(f64::is_finite), "the wall axis");
    });
}
