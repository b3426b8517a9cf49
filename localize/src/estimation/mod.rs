//! The estimator: the odometry/IMU filter and its replay, the frame loop, corner and wall landmarks, the fused pose, the point and edge maps and scan-to-map registration, level floors, relocalization.

pub mod edge_map;
pub mod ekf;
pub mod euler;
pub mod fusion;
pub mod landmarks;
pub mod level_floor;
pub mod motion;
pub mod pipeline;
pub mod plane_landmarks;
pub mod point_map;
pub mod pose;
pub mod relocalize;
pub mod scan_match;
pub mod sensor_replay;
