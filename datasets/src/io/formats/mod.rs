//! On-disk formats: each file reads and writes one format and reports
//! problems with the file name and the line or byte offset.

pub mod calib;
pub mod cloud;
pub mod coco;
pub mod depth_image;
pub mod lzf;
pub mod pcd;
pub mod ply;
pub mod point_labels;
pub mod sensor_csv;
pub mod stamped_files;
pub mod trajectory;

pub use calib::{Calibration, read_calibration, write_calibration};
pub use cloud::{NonFinite, PointCloud, read_cloud};
pub use coco::{CocoAnnotation, CocoCategory, CocoDataset, CocoImage, corner_categories, read_coco, write_coco};
pub use depth_image::{DepthImage, read_depth_png};
pub use pcd::{PcdData, read_pcd, write_pcd};
pub use ply::{PlyFormat, read_ply, write_ply};
pub use point_labels::{CocoHalves, PointLabel, coco_halves, labelled_photos, read_point_labels, write_point_labels};
pub use sensor_csv::{ImuSample, OdometrySample, read_imu, read_odometry, write_imu, write_odometry};
pub use stamped_files::{CLOUD_EXTENSIONS, IMAGE_EXTENSIONS, stamped_files};
pub use trajectory::{Trajectory, TrajectoryFormat, read_trajectory, read_tum, write_tum};
