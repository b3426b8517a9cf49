//! Labels from the robot's own 3D sensor (`localize autolabel`): corner tracks, corners of the map, visibility, projection.

pub mod autolabel;
pub mod corner_tracks;
pub mod depth_buffer;
pub mod map_corners;
