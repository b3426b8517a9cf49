//! A pose topic as a trajectory, the way `evo_traj bag|bag2` reads one:
//! `geometry_msgs/PoseStamped`, `PoseWithCovarianceStamped` or
//! `nav_msgs/Odometry`, each pose at its header stamp, in file order.

use crate::error::{DataError, Result};
use crate::io::formats::Trajectory;
use crate::io::recording::messages::{MessageKind, geometry};
use crate::io::recording::wire::WireReader;
use crate::io::recording::{Recording, wire};

/// The types a trajectory topic may have.
pub const POSE_KINDS: [MessageKind; 3] =
    [MessageKind::PoseStamped, MessageKind::PoseWithCovarianceStamped, MessageKind::Odometry];

/// Decodes the stamped pose of one message of a pose topic.
pub fn stamped_pose(kind: MessageKind, r: &mut dyn WireReader<'_>) -> wire::WireResult<geometry::StampedPose> {
    match kind {
        MessageKind::PoseStamped => geometry::pose_stamped(r),
        MessageKind::PoseWithCovarianceStamped => geometry::pose_with_covariance_stamped(r),
        _ => geometry::odometry(r).map(|o| geometry::StampedPose { header: o.header, pose: o.pose }),
    }
}

pub fn read_pose_topic(recording: &Recording, topic: &str) -> Result<Trajectory> {
    let k = recording.topic(topic).ok_or_else(|| {
        let names: Vec<&str> = recording.topics.iter().map(|t| t.name.as_str()).collect();
        DataError::invalid(&recording.path, format!("no topic `{topic}` (topics: {})", names.join(", ")))
    })?;
    let info = &recording.topics[k];
    let kind = info.kind().filter(|kind| POSE_KINDS.contains(kind)).ok_or_else(|| {
        DataError::invalid(
            &recording.path,
            format!(
                "topic {topic} is {}, not a pose topic (geometry_msgs/msg/PoseStamped, PoseWithCovarianceStamped or nav_msgs/msg/Odometry)",
                info.type_name
            ),
        )
    })?;
    let mut trajectory = Trajectory::default();
    recording.read(&[k], &mut |m| {
        let pose = recording.decode(&m, |r| stamped_pose(kind, r))?;
        trajectory.push(pose.header.stamp_s(), pose.pose);
        Ok(())
    })?;
    Ok(trajectory)
}
