//! One scan's geometry: down-sampling, the scan grid, normals (exact, or on the range image), planes, 3D corners, and an RGB-D frame's image edges lifted to 3D.

pub mod corners;
pub mod geometry;
pub mod image_edges;
pub mod normals;
pub mod organised_normals;
pub mod planes;
pub mod range_image;
pub mod scan_grid;
pub mod voxel;
