//! The files of other tools, read and written: point clouds (PCD, PLY, KITTI
//! bin), trajectories (TUM, KITTI), COCO, calibration and sensor logs in
//! [`formats`]; ROS 1 bags, rosbag2 folders and MCAP files in [`recording`].
//! Depends on the shared layer only.

pub mod formats;
pub mod recording;
