//! Decoders of the ROS messages localization reads, one file per family.
//! Each decodes from a [`WireReader`], so one function serves ROS 1 and ROS 2.

pub mod camera_info;
pub mod geometry;
pub mod image;
pub mod point_cloud;

use super::wire::{CdrReader, Ros1Reader, WireReader, WireResult, wire_error};

/// How a topic's messages are serialised.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Encoding {
    /// ROS 2 (`cdr`).
    Cdr,
    /// ROS 1 (`ros1`).
    Ros1,
}

impl Encoding {
    pub fn name(self) -> &'static str {
        match self {
            Self::Cdr => "cdr",
            Self::Ros1 => "ros1",
        }
    }
}

/// Decodes one message with `decode`, whichever the wire format.
pub fn decode<T>(
    encoding: Encoding,
    bytes: &[u8],
    decode: impl for<'a> FnOnce(&mut dyn WireReader<'a>) -> WireResult<T>,
) -> WireResult<T> {
    match encoding {
        Encoding::Cdr => decode(&mut CdrReader::new(bytes)?),
        Encoding::Ros1 => decode(&mut Ros1Reader::new(bytes)),
    }
}

/// The ROS 2 name of a message type (`pkg/msg/Name`), whichever form a
/// recording uses (ROS 1 and MCAP `ros1` schemas write `pkg/Name`).
pub fn canonical_type(name: &str) -> String {
    match name.split('/').collect::<Vec<_>>().as_slice() {
        [package, type_name] => format!("{package}/msg/{type_name}"),
        _ => name.to_string(),
    }
}

/// The message types localization understands, by ROS 2 name.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MessageKind {
    PointCloud2,
    Image,
    CompressedImage,
    CameraInfo,
    Imu,
    Odometry,
    TfMessage,
    PoseStamped,
    PoseWithCovarianceStamped,
}

impl MessageKind {
    pub const ALL: [MessageKind; 9] = [
        Self::PointCloud2,
        Self::Image,
        Self::CompressedImage,
        Self::CameraInfo,
        Self::Imu,
        Self::Odometry,
        Self::TfMessage,
        Self::PoseStamped,
        Self::PoseWithCovarianceStamped,
    ];

    /// The ROS 2 name of its type.
    pub fn type_name(self) -> &'static str {
        match self {
            Self::PointCloud2 => "sensor_msgs/msg/PointCloud2",
            Self::Image => "sensor_msgs/msg/Image",
            Self::CompressedImage => "sensor_msgs/msg/CompressedImage",
            Self::CameraInfo => "sensor_msgs/msg/CameraInfo",
            Self::Imu => "sensor_msgs/msg/Imu",
            Self::Odometry => "nav_msgs/msg/Odometry",
            Self::TfMessage => "tf2_msgs/msg/TFMessage",
            Self::PoseStamped => "geometry_msgs/msg/PoseStamped",
            Self::PoseWithCovarianceStamped => "geometry_msgs/msg/PoseWithCovarianceStamped",
        }
    }

    /// The kind of a type name, in ROS 1 or ROS 2 spelling.
    pub fn of(type_name: &str) -> Option<Self> {
        let canonical = canonical_type(type_name);
        Self::ALL.into_iter().find(|k| k.type_name() == canonical)
    }
}

pub(crate) fn ensure(condition: bool, message: impl FnOnce() -> String) -> WireResult<()> {
    if condition { Ok(()) } else { Err(wire_error(message())) }
}
