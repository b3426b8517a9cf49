//! Writes a sequence folder as a ROS 2 recording (one MCAP file, zstd
//! chunks, CDR messages with their `ros2msg` schemas), the topics a robot
//! would record: `/points` (PointCloud2), `/camera/image_raw/compressed`
//! (the PNG files as they are), `/camera/camera_info`, `/imu`, `/odom`,
//! `/tf_static` and `/ground_truth` (PoseStamped).

use std::collections::BTreeMap;
use std::io::BufWriter;
use std::path::{Path, PathBuf};

use crate::error::{DataError, Result};
use crate::io::formats::{
    CLOUD_EXTENSIONS, Calibration, IMAGE_EXTENSIONS, ImuSample, NonFinite, OdometrySample, Trajectory,
    read_calibration, read_cloud, read_imu, read_odometry, read_tum, stamped_files,
};
use crate::io::recording::wire::{CdrWriter, Header};
use crate::math::{Pose3, Rot3};

pub const LIDAR_FRAME: &str = "lidar_link";
pub const CAMERA_FRAME: &str = "camera_optical_frame";
pub const BASE_FRAME: &str = "base_link";

const HEADER: &str = "MSG: std_msgs/Header\nbuiltin_interfaces/Time stamp\nstring frame_id\n";
const TIME: &str = "MSG: builtin_interfaces/Time\nint32 sec\nuint32 nanosec\n";
const POSE: &str = "MSG: geometry_msgs/Pose\nPoint position\nQuaternion orientation\n";
const POINT: &str = "MSG: geometry_msgs/Point\nfloat64 x\nfloat64 y\nfloat64 z\n";
const QUATERNION: &str = "MSG: geometry_msgs/Quaternion\nfloat64 x 0\nfloat64 y 0\nfloat64 z 0\nfloat64 w 1\n";
const VECTOR3: &str = "MSG: geometry_msgs/Vector3\nfloat64 x\nfloat64 y\nfloat64 z\n";
const SEPARATOR: &str = "================================================================================\n";

/// A `ros2msg` schema: the type's own fields, then each dependency.
fn schema(fields: &str, dependencies: &[&str]) -> String {
    let mut out = fields.to_string();
    for d in dependencies {
        out.push_str(SEPARATOR);
        out.push_str(d);
    }
    out
}

fn schemas() -> Vec<(&'static str, String)> {
    vec![
        (
            "sensor_msgs/msg/PointCloud2",
            schema(
                "std_msgs/Header header\nuint32 height\nuint32 width\nPointField[] fields\nbool is_bigendian\nuint32 point_step\nuint32 row_step\nuint8[] data\nbool is_dense\n",
                &[
                    HEADER,
                    TIME,
                    "MSG: sensor_msgs/PointField\nuint8 INT8=1\nuint8 UINT8=2\nuint8 INT16=3\nuint8 UINT16=4\nuint8 INT32=5\nuint8 UINT32=6\nuint8 FLOAT32=7\nuint8 FLOAT64=8\nstring name\nuint32 offset\nuint8 datatype\nuint32 count\n",
                ],
            ),
        ),
        (
            "sensor_msgs/msg/Image",
            schema(
                "std_msgs/Header header\nuint32 height\nuint32 width\nstring encoding\nuint8 is_bigendian\nuint32 step\nuint8[] data\n",
                &[HEADER, TIME],
            ),
        ),
        (
            "sensor_msgs/msg/CompressedImage",
            schema("std_msgs/Header header\nstring format\nuint8[] data\n", &[HEADER, TIME]),
        ),
        (
            "sensor_msgs/msg/CameraInfo",
            schema(
                "std_msgs/Header header\nuint32 height\nuint32 width\nstring distortion_model\nfloat64[] d\nfloat64[9] k\nfloat64[9] r\nfloat64[12] p\nuint32 binning_x\nuint32 binning_y\nRegionOfInterest roi\n",
                &[
                    HEADER,
                    TIME,
                    "MSG: sensor_msgs/RegionOfInterest\nuint32 x_offset\nuint32 y_offset\nuint32 height\nuint32 width\nbool do_rectify\n",
                ],
            ),
        ),
        (
            "sensor_msgs/msg/Imu",
            schema(
                "std_msgs/Header header\ngeometry_msgs/Quaternion orientation\nfloat64[9] orientation_covariance\ngeometry_msgs/Vector3 angular_velocity\nfloat64[9] angular_velocity_covariance\ngeometry_msgs/Vector3 linear_acceleration\nfloat64[9] linear_acceleration_covariance\n",
                &[HEADER, TIME, QUATERNION, VECTOR3],
            ),
        ),
        (
            "nav_msgs/msg/Odometry",
            schema(
                "std_msgs/Header header\nstring child_frame_id\ngeometry_msgs/PoseWithCovariance pose\ngeometry_msgs/TwistWithCovariance twist\n",
                &[
                    HEADER,
                    TIME,
                    "MSG: geometry_msgs/PoseWithCovariance\nPose pose\nfloat64[36] covariance\n",
                    POSE,
                    POINT,
                    QUATERNION,
                    "MSG: geometry_msgs/TwistWithCovariance\nTwist twist\nfloat64[36] covariance\n",
                    "MSG: geometry_msgs/Twist\nVector3 linear\nVector3 angular\n",
                    VECTOR3,
                ],
            ),
        ),
        (
            "tf2_msgs/msg/TFMessage",
            schema(
                "geometry_msgs/TransformStamped[] transforms\n",
                &[
                    "MSG: geometry_msgs/TransformStamped\nstd_msgs/Header header\nstring child_frame_id\nTransform transform\n",
                    HEADER,
                    TIME,
                    "MSG: geometry_msgs/Transform\nVector3 translation\nQuaternion rotation\n",
                    VECTOR3,
                    QUATERNION,
                ],
            ),
        ),
        (
            "geometry_msgs/msg/PoseStamped",
            schema("std_msgs/Header header\nPose pose\n", &[HEADER, TIME, POSE, POINT, QUATERNION]),
        ),
    ]
}

fn ns(seconds: f64) -> i64 {
    (seconds * 1e9).round() as i64
}

fn header(stamp_ns: i64, frame: &str) -> Header {
    Header { stamp_ns, frame_id: frame.to_string() }
}

pub fn point_cloud2(stamp_ns: i64, frame: &str, cloud: &crate::io::formats::PointCloud) -> Vec<u8> {
    let mut w = CdrWriter::new();
    w.header(&header(stamp_ns, frame));
    w.u32(1);
    w.u32(cloud.len() as u32);
    w.u32(4);
    for (k, name) in ["x", "y", "z", "intensity"].iter().enumerate() {
        w.string(name);
        w.u32(4 * k as u32);
        w.u8(7);
        w.u32(1);
    }
    w.u8(0);
    w.u32(16);
    w.u32(16 * cloud.len() as u32);
    let mut data = Vec::with_capacity(16 * cloud.len());
    for (k, p) in cloud.points.iter().enumerate() {
        let i = cloud.intensity.as_ref().map_or(0.0, |v| v[k]);
        for v in [p.x, p.y, p.z, i] {
            data.extend_from_slice(&v.to_le_bytes());
        }
    }
    w.bytes(&data);
    w.u8(1);
    w.finish()
}

/// The `ros2msg` schema text of one of the types written here.
pub fn ros2_schema(type_name: &str) -> Option<String> {
    schemas().into_iter().find(|(name, _)| *name == type_name).map(|(_, text)| text)
}

/// A `16UC1` depth image (millimetres), as RGB-D drivers publish it.
pub fn depth_image_mm(stamp_ns: i64, frame: &str, width: u32, height: u32, millimetres: &[u16]) -> Vec<u8> {
    let mut w = CdrWriter::new();
    w.header(&header(stamp_ns, frame));
    w.u32(height);
    w.u32(width);
    w.string("16UC1");
    w.u8(0);
    w.u32(2 * width);
    let data: Vec<u8> = millimetres.iter().flat_map(|v| v.to_le_bytes()).collect();
    w.bytes(&data);
    w.finish()
}

pub fn compressed_image(stamp_ns: i64, frame: &str, format: &str, data: &[u8]) -> Vec<u8> {
    let mut w = CdrWriter::new();
    w.header(&header(stamp_ns, frame));
    w.string(format);
    w.bytes(data);
    w.finish()
}

pub fn camera_info(stamp_ns: i64, frame: &str, calib: &Calibration) -> Vec<u8> {
    let c = &calib.camera;
    let mut w = CdrWriter::new();
    w.header(&header(stamp_ns, frame));
    w.u32(c.height);
    w.u32(c.width);
    w.string("plumb_bob");
    w.u32(5);
    w.f64s(&[0.0; 5]);
    w.f64s(&[c.fx, 0.0, c.cx, 0.0, c.fy, c.cy, 0.0, 0.0, 1.0]);
    w.f64s(&[1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]);
    w.f64s(&[c.fx, 0.0, c.cx, 0.0, 0.0, c.fy, c.cy, 0.0, 0.0, 0.0, 1.0, 0.0]);
    w.u32(0);
    w.u32(0);
    for _ in 0..4 {
        w.u32(0);
    }
    w.u8(0);
    w.finish()
}

pub fn imu(sample: &ImuSample, frame: &str) -> Vec<u8> {
    let mut w = CdrWriter::new();
    w.header(&header(ns(sample.timestamp), frame));
    w.f64s(&[0.0, 0.0, 0.0, 1.0]);
    // No orientation estimate: covariance[0] = -1, as REP 145 says.
    let mut unknown = [0.0; 9];
    unknown[0] = -1.0;
    w.f64s(&unknown);
    w.f64s(&sample.gyro);
    w.f64s(&[0.0; 9]);
    w.f64s(&sample.accel);
    w.f64s(&[0.0; 9]);
    w.finish()
}

pub fn odometry(sample: &OdometrySample, frame: &str, child: &str) -> Vec<u8> {
    let mut w = CdrWriter::new();
    w.header(&header(ns(sample.timestamp), frame));
    w.string(child);
    let pose = Pose3::from_parts(
        nalgebra::Translation3::new(sample.x, sample.y, 0.0),
        Rot3::from_euler_angles(0.0, 0.0, sample.yaw),
    );
    w.pose(&pose);
    w.f64s(&[0.0; 36]);
    w.f64s(&[sample.v, 0.0, 0.0, 0.0, 0.0, sample.omega]);
    w.f64s(&[0.0; 36]);
    w.finish()
}

pub fn tf_message(transforms: &[(i64, &str, &str, Pose3)]) -> Vec<u8> {
    let mut w = CdrWriter::new();
    w.u32(transforms.len() as u32);
    for (stamp_ns, parent, child, parent_from_child) in transforms {
        w.header(&header(*stamp_ns, parent));
        w.string(child);
        w.pose(parent_from_child);
    }
    w.finish()
}

pub fn pose_stamped(stamp_ns: i64, frame: &str, pose: &Pose3) -> Vec<u8> {
    let mut w = CdrWriter::new();
    w.header(&header(stamp_ns, frame));
    w.pose(pose);
    w.finish()
}

enum Event {
    Cloud(PathBuf),
    Image(PathBuf),
    Imu(usize),
    Odometry(usize),
    Truth(usize),
}

/// What a sequence folder's files hold, and its messages in time order.
struct SequenceLogs {
    calib: Calibration,
    imu_log: Vec<ImuSample>,
    odom_log: Vec<OdometrySample>,
    truth: Trajectory,
    events: Vec<(i64, u8, Event)>,
}

fn read_sequence_logs(dir: &Path) -> Result<SequenceLogs> {
    let calib = read_calibration(&dir.join("calib.json"))?;
    let imu_log = read_imu(&dir.join("imu.csv"))?;
    let odom_log = read_odometry(&dir.join("odom.csv"))?;
    let truth_path = dir.join("groundtruth.txt");
    let truth = if truth_path.is_file() { read_tum(&truth_path)? } else { Trajectory::default() };
    let clouds = stamped_files(&dir.join("cloud"), &CLOUD_EXTENSIONS, "cloud")?;
    let rgb = dir.join("rgb");
    let images = if rgb.is_dir() { stamped_files(&rgb, &IMAGE_EXTENSIONS, "image")? } else { Vec::new() };
    let mut events: Vec<(i64, u8, Event)> = Vec::new();
    // Within one instant: the motion sensors first, as a driver would deliver them.
    events.extend(imu_log.iter().enumerate().map(|(k, s)| (ns(s.timestamp), 0, Event::Imu(k))));
    events.extend(odom_log.iter().enumerate().map(|(k, s)| (ns(s.timestamp), 1, Event::Odometry(k))));
    events.extend(clouds.iter().map(|(t, p)| (ns(*t), 2, Event::Cloud(p.clone()))));
    events.extend(images.iter().map(|(t, p)| (ns(*t), 3, Event::Image(p.clone()))));
    events.extend(truth.stamps.iter().enumerate().map(|(k, t)| (ns(*t), 4, Event::Truth(k))));
    events.sort_by_key(|(t, order, _)| (*t, *order));
    Ok(SequenceLogs { calib, imu_log, odom_log, truth, events })
}

/// A temporary file beside `out` (what a killed export left there removed
/// first), readable as an ordinary file once renamed.
fn temporary_beside(out: &Path) -> Result<tempfile::NamedTempFile> {
    let parent = crate::atomic::folder_of(out);
    std::fs::create_dir_all(parent).map_err(|e| DataError::io(parent, e))?;
    // What a killed export of this bag left goes first.
    crate::atomic::remove_stale_siblings(out, ".mcap")?;
    let prefix = crate::atomic::sibling_prefix(out);
    let mut builder = tempfile::Builder::new();
    builder.prefix(&prefix).suffix(".mcap");
    // Temporary files are private (0600); the recording is an ordinary file.
    #[cfg(unix)]
    builder.permissions(std::os::unix::fs::PermissionsExt::from_mode(0o644));
    builder.tempfile_in(parent).map_err(|e| DataError::io(parent, e))
}

/// Writes the sequence folder `dir` as the MCAP file `out`, atomically.
pub fn write_sequence_mcap(dir: &Path, out: &Path) -> Result<usize> {
    let SequenceLogs { calib, imu_log, odom_log, truth, events } = read_sequence_logs(dir)?;
    let start = events.first().map_or(0, |e| e.0);

    // Written beside the target under a temporary name, renamed when whole.
    let tmp = temporary_beside(out)?;
    let file = tmp.as_file().try_clone().map_err(|e| DataError::io(out, e))?;
    let mcap_error = |e: mcap::McapError| DataError::invalid(out, format!("writing MCAP: {e}"));
    let mut writer = mcap::WriteOptions::new()
        .compression(Some(mcap::Compression::Zstd))
        .profile("ros2")
        .create(BufWriter::new(file))
        .map_err(mcap_error)?;
    let mut schema_ids = BTreeMap::new();
    for (name, text) in schemas() {
        schema_ids.insert(name, writer.add_schema(name, "ros2msg", text.as_bytes()).map_err(mcap_error)?);
    }
    let mut channel = |topic: &str, type_name: &str| {
        writer.add_channel(schema_ids[type_name], topic, "cdr", &BTreeMap::new()).map_err(mcap_error)
    };
    let points = channel("/points", "sensor_msgs/msg/PointCloud2")?;
    let image = channel("/camera/image_raw/compressed", "sensor_msgs/msg/CompressedImage")?;
    let info = channel("/camera/camera_info", "sensor_msgs/msg/CameraInfo")?;
    let imu_channel = channel("/imu", "sensor_msgs/msg/Imu")?;
    let odom_channel = channel("/odom", "nav_msgs/msg/Odometry")?;
    let tf_static = channel("/tf_static", "tf2_msgs/msg/TFMessage")?;
    let truth_channel = channel("/ground_truth", "geometry_msgs/msg/PoseStamped")?;
    let mut sequence = 0u32;
    let mut write = |writer: &mut mcap::Writer<BufWriter<std::fs::File>>, channel_id: u16, t: i64, data: &[u8]| {
        sequence += 1;
        let header = mcap::records::MessageHeader { channel_id, sequence, log_time: t as u64, publish_time: t as u64 };
        writer.write_to_known_channel(&header, data).map_err(mcap_error)
    };
    let tf = tf_message(&[
        (start, BASE_FRAME, LIDAR_FRAME, calib.robot_from_lidar),
        (start, BASE_FRAME, CAMERA_FRAME, calib.robot_from_camera()),
    ]);
    write(&mut writer, tf_static, start, &tf)?;
    let bar = crate::cli::progress(events.len(), "bag");
    let mut written = 1;
    for (t, _, event) in &events {
        let t = *t;
        match event {
            Event::Imu(k) => write(&mut writer, imu_channel, t, &imu(&imu_log[*k], BASE_FRAME))?,
            Event::Odometry(k) => write(&mut writer, odom_channel, t, &odometry(&odom_log[*k], "odom", BASE_FRAME))?,
            Event::Truth(k) => write(&mut writer, truth_channel, t, &pose_stamped(t, "map", &truth.poses[*k]))?,
            Event::Cloud(path) => {
                let cloud = read_cloud(path, NonFinite::Drop)?;
                write(&mut writer, points, t, &point_cloud2(t, LIDAR_FRAME, &cloud))?;
            }
            Event::Image(path) => {
                let bytes = crate::atomic::read_bytes(path)?;
                let format = if path.extension().is_some_and(|e| e == "png") { "png" } else { "jpeg" };
                write(
                    &mut writer,
                    image,
                    t,
                    &compressed_image(t, CAMERA_FRAME, &format!("rgb8; {format} compressed bgr8"), &bytes),
                )?;
                write(&mut writer, info, t, &camera_info(t, CAMERA_FRAME, &calib))?;
                written += 1;
            }
        }
        written += 1;
        bar.inc(1);
    }
    writer.finish().map_err(mcap_error)?;
    drop(writer);
    bar.finish_and_clear();
    tmp.persist(out).map_err(|e| DataError::io(out, e.error))?;
    Ok(written)
}
