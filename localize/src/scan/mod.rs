//! One scan's geometry: down-sampling, the scan grid, normals, planes, 3D corners, and an RGB-D frame's image edges lifted to 3D.

pub mod corners;
pub mod geometry;
pub mod image_edges;
pub mod normals;
pub mod planes;
pub mod scan_grid;
pub mod voxel;
