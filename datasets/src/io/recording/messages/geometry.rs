//! Motion and pose messages: `sensor_msgs/Imu`, `nav_msgs/Odometry`,
//! `tf2_msgs/TFMessage`, `geometry_msgs/PoseStamped` and
//! `geometry_msgs/PoseWithCovarianceStamped`.

use crate::io::recording::wire::{Header, WireReader, WireResult, wire_error};
use crate::math::{Pose3, Rot3, Vec3};

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

/// How far from 1 a transform quaternion's squared norm may be (tf2's
/// `QUATERNION_NORMALIZATION_TOLERANCE`).
const TF_QUATERNION_TOLERANCE: f64 = 0.01;

/// `tf2_msgs/TFMessage`.
pub fn tf_message(r: &mut dyn WireReader<'_>) -> WireResult<Vec<Transform>> {
    // A TransformStamped takes at least 8 bytes of header, 8 of strings and 56 of doubles.
    let n = r.sequence_len(72)?;
    (0..n)
        .map(|_| {
            let header = r.header()?;
            let child_frame_id = r.string()?;
            let t = r.vector3()?;
            let q = r.f64s(4)?;
            // tf2 ignores a transform whose quaternion is not of unit length
            // (|q|^2 more than 0.01 from 1): a calibration typo, not a rotation.
            let norm2: f64 = q.iter().map(|v| v * v).sum();
            if !((norm2 - 1.0).abs() <= TF_QUATERNION_TOLERANCE) {
                return Err(wire_error(format!(
                    "transform {} -> {child_frame_id}: quaternion ({}, {}, {}, {}) is not of unit length \
                     (squared norm {norm2}; tf2 refuses it too)",
                    header.frame_id, q[0], q[1], q[2], q[3]
                )));
            }
            if !t.iter().all(|v| v.is_finite()) {
                return Err(wire_error(format!(
                    "transform {} -> {child_frame_id}: translation {t:?} is not finite",
                    header.frame_id
                )));
            }
            let rotation = Rot3::from_quaternion(nalgebra::Quaternion::new(q[3], q[0], q[1], q[2]));
            Ok(Transform { header, child_frame_id, parent_from_child: Pose3::from_parts(t.into(), rotation) })
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::io::recording::messages::{Encoding, decode};
    use crate::io::recording::wire::CdrWriter;

    /// A TF message of one transform base -> lidar with the raw quaternion `q` (x, y, z, w).
    fn transform(q: [f64; 4]) -> Vec<u8> {
        let mut w = CdrWriter::new();
        w.u32(1);
        w.header(&Header { stamp_ns: 0, frame_id: "base".into() });
        w.string("lidar");
        w.f64s(&[0.1, 0.0, 0.5]);
        w.f64s(&q);
        w.finish()
    }

    #[test]
    fn a_transform_quaternion_off_unit_length_is_refused_as_tf2_refuses_it() {
        let half = std::f64::consts::FRAC_1_SQRT_2;
        let ok = decode(Encoding::Cdr, &transform([0.0, 0.0, half, half]), tf_message).unwrap();
        assert!((ok[0].parent_from_child.rotation.angle() - std::f64::consts::FRAC_PI_2).abs() < 1e-12);
        // Rounded by hand (|q|^2 = 0.9941): within tf2's tolerance.
        assert!(decode(Encoding::Cdr, &transform([0.0, 0.0, 0.70, 0.71]), tf_message).is_ok());
        for q in [[0.0, 0.0, 1.0, 1.0], [0.0, 0.0, 0.0, 0.9]] {
            let error = decode(Encoding::Cdr, &transform(q), tf_message).unwrap_err().to_string();
            assert!(error.contains("base -> lidar") && error.contains("not of unit length"), "{error}");
        }
    }
}
