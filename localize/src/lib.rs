//! Localization: planes and 3D corners from LIDAR scans, 2D corners from the
//! detector cast into them, corner landmarks, the pose that aligns them with
//! an odometry/IMU prior, and trajectory metrics.

pub mod autolabel;
pub mod bag_sequence;
pub mod benchmark;
pub mod config;
pub mod corner_source;
pub mod corner_tracks;
pub mod corners;
pub mod depth_buffer;
pub mod edge_map;
pub mod ekf;
pub mod error;
pub mod euler;
pub mod eval;
pub mod fusion;
pub mod geometry;
pub mod image_edges;
pub mod landmarks;
pub mod level_floor;
pub mod levels;
pub mod map_corners;
pub mod map_output;
pub mod motion;
pub mod normals;
pub mod pipeline;
pub mod plane_landmarks;
pub mod planes;
pub mod plot;
pub mod point_map;
pub mod pose;
pub mod relocalize;
pub mod rgbd_sequence;
pub mod run;
pub mod scan_grid;
pub mod scan_match;
pub mod sensor_faults;
pub mod sensor_replay;
pub mod sensor_set;
pub mod sequence;
pub mod similarity;
pub mod voxel;
