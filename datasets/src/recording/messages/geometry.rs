//! Motion and pose messages: `sensor_msgs/Imu`, `nav_msgs/Odometry`,
//! `tf2_msgs/TFMessage`, `geometry_msgs/PoseStamped` and
//! `geometry_msgs/PoseWithCovarianceStamped`.

use crate::math::{Pose3, Rot3, Vec3};
use crate::recording::wire::{Header, WireReader, WireResult, wire_error};

/// `sensor_msgs/Imu`, in the IMU's own frame (`header.frame_id`).
#[derive(Debug, Clone, PartialEq)]
pub struct ImuMessage {
    pub header: Header,
    /// `None` when the driver marks it unknown (covariance[0] = -1).
    pub orientation: Option<Rot3>,
    pub angular_velocity: Vec3,
    pub linear_acceleration: Vec3,
}

pub fn imu(r: &mut dyn WireReader<'_>) -> WireResult<ImuMessage> {
    let header = r.header()?;
    let q = r.f64s(4)?;
    let orientation_covariance = r.f64s(9)?;
    let angular_velocity = r.vector3()?;
    let _ = r.f64s(9)?;
    let linear_acceleration = r.vector3()?;
    let _ = r.f64s(9)?;
    let raw = nalgebra::Quaternion::new(q[3], q[0], q[1], q[2]);
    let orientation = (orientation_covariance[0] != -1.0 && raw.norm() > 1e-6).then(|| Rot3::from_quaternion(raw));
    for (name, v) in [("angular_velocity", &angular_velocity), ("linear_acceleration", &linear_acceleration)] {
        if !v.iter().all(|x| x.is_finite()) {
            return Err(wire_error(format!("{name} {v:?} is not finite")));
        }
    }
    Ok(ImuMessage { header, orientation, angular_velocity, linear_acceleration })
}

/// `nav_msgs/Odometry`: the pose of `child_frame_id` in `header.frame_id`,
/// and the twist in `child_frame_id`.
#[derive(Debug, Clone, PartialEq)]
pub struct OdometryMessage {
    pub header: Header,
    pub child_frame_id: String,
    pub pose: Pose3,
    pub linear: Vec3,
    pub angular: Vec3,
}

pub fn odometry(r: &mut dyn WireReader<'_>) -> WireResult<OdometryMessage> {
    let header = r.header()?;
    let child_frame_id = r.string()?;
    let pose = r.pose()?;
    let _ = r.f64s(36)?;
    let linear = r.vector3()?;
    let angular = r.vector3()?;
    let _ = r.f64s(36)?;
    if !linear.iter().chain(angular.iter()).all(|x| x.is_finite()) {
        return Err(wire_error(format!("twist {linear:?} {angular:?} is not finite")));
    }
    Ok(OdometryMessage { header, child_frame_id, pose, linear, angular })
}

/// One `geometry_msgs/TransformStamped`: `parent_from_child` maps points of
/// `child_frame_id` into `header.frame_id`.
#[derive(Debug, Clone, PartialEq)]
pub struct Transform {
    pub header: Header,
    pub child_frame_id: String,
    pub parent_from_child: Pose3,
}

/// `tf2_msgs/TFMessage`.
pub fn tf_message(r: &mut dyn WireReader<'_>) -> WireResult<Vec<Transform>> {
    // A TransformStamped takes at least 8 bytes of header, 8 of strings and 56 of doubles.
    let n = r.sequence_len(72)?;
    (0..n)
        .map(|_| {
            let header = r.header()?;
            let child_frame_id = r.string()?;
            let parent_from_child = r.pose()?;
            Ok(Transform { header, child_frame_id, parent_from_child })
        })
        .collect()
}

/// A stamped pose: `geometry_msgs/PoseStamped`,
/// `geometry_msgs/PoseWithCovarianceStamped` or the pose of a `nav_msgs/Odometry`.
#[derive(Debug, Clone, PartialEq)]
pub struct StampedPose {
    pub header: Header,
    pub pose: Pose3,
}

pub fn pose_stamped(r: &mut dyn WireReader<'_>) -> WireResult<StampedPose> {
    Ok(StampedPose { header: r.header()?, pose: r.pose()? })
}

pub fn pose_with_covariance_stamped(r: &mut dyn WireReader<'_>) -> WireResult<StampedPose> {
    let header = r.header()?;
    let pose = r.pose()?;
    let _ = r.f64s(36)?;
    Ok(StampedPose { header, pose })
}
