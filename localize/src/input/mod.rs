//! The recordings a run reads: sequence folders, ROS bags, RGB-D folders, the sensors they hold, simulated faults, and where the 2D corners come from.

pub mod bag_sequence;
pub mod colour_registration;
pub mod corner_source;
pub mod frame_fault;
pub mod rgbd_sequence;
pub mod sensor_faults;
pub mod sensor_set;
pub mod sequence;
