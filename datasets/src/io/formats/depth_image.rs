//! Depth images (16-bit PNG, as Kinect-style RGB-D datasets store them: TUM
//! RGB-D in fifths of a millimetre, 7-Scenes in millimetres, 0 = no
//! reading) and their points through the depth camera's intrinsics.

use std::path::Path;

use nalgebra::Point3;

use crate::camera::PinholeCamera;
use crate::error::{DataError, Result};

/// A depth image in metres, row-major; NaN where the sensor gave nothing.
#[derive(Debug, Clone, PartialEq)]
pub struct DepthImage {
    pub width: u32,
    pub height: u32,
    pub metres: Vec<f32>,
}

/// Reads a 16-bit single-channel PNG whose values are `units_per_metre`
/// to the metre (5000 for TUM RGB-D, 1000 for millimetres).
pub fn read_depth_png(path: &Path, units_per_metre: f64) -> Result<DepthImage> {
    if !(units_per_metre.is_finite() && units_per_metre > 0.0) {
        return Err(DataError::invalid(path, format!("depth scale {units_per_metre} must be finite and positive")));
    }
    let image = crate::atomic::read_image(path)?;
    let image::DynamicImage::ImageLuma16(gray) = image else {
        return Err(DataError::invalid(
            path,
            format!("a depth image must be 16-bit single-channel; this one is {:?}", image.color()),
        ));
    };
    let scale = 1.0 / units_per_metre;
    let metres =
        gray.pixels().map(|p| if p.0[0] == 0 { f32::NAN } else { (f64::from(p.0[0]) * scale) as f32 }).collect();
    Ok(DepthImage { width: gray.width(), height: gray.height(), metres })
}

impl DepthImage {
    /// The valid readings within `[near, far]` metres as points in the
    /// camera's optical frame (x right, y down, z forward), every `stride`-th
    /// pixel of every `stride`-th row, in row order.
    pub fn points(&self, camera: &PinholeCamera, stride: usize, near: f32, far: f32) -> Vec<Point3<f32>> {
        let stride = stride.max(1);
        let mut out = Vec::with_capacity((self.width as usize / stride + 1) * (self.height as usize / stride + 1));
        for v in (0..self.height as usize).step_by(stride) {
            let y = ((v as f64 - camera.cy) / camera.fy) as f32;
            for u in (0..self.width as usize).step_by(stride) {
                let z = self.metres[v * self.width as usize + u];
                // NaN (no reading) fails both comparisons.
                if z >= near && z <= far {
                    let x = ((u as f64 - camera.cx) / camera.fx) as f32;
                    out.push(Point3::new(x * z, y * z, z));
                }
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_written_depth_png_reads_back_in_metres_and_projects_through_the_intrinsics() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("depth.png");
        // 4 x 3: a wall 2 m ahead, one pixel missing, one 5 m away.
        let mut gray = image::ImageBuffer::<image::Luma<u16>, Vec<u16>>::from_pixel(4, 3, image::Luma([10_000]));
        gray.put_pixel(1, 0, image::Luma([0]));
        gray.put_pixel(3, 2, image::Luma([25_000]));
        gray.save(&path).unwrap();
        let depth = read_depth_png(&path, 5000.0).unwrap();
        assert_eq!((depth.width, depth.height), (4, 3));
        assert_eq!(depth.metres[0], 2.0);
        assert!(depth.metres[1].is_nan());
        let camera = PinholeCamera { width: 4, height: 3, fx: 2.0, fy: 4.0, cx: 1.5, cy: 1.0 };
        let points = depth.points(&camera, 1, 0.2, 4.0);
        assert_eq!(points.len(), 10, "one missing, one beyond 4 m");
        // Pixel (0, 0): x = (0 - 1.5) / 2 * 2 m, y = (0 - 1) / 4 * 2 m.
        assert_eq!(points[0], Point3::new(-1.5, -0.5, 2.0));
        // Every point projects back onto its pixel.
        let strided = depth.points(&camera, 2, 0.2, 10.0);
        let pixels: Vec<[f32; 2]> = strided.iter().map(|p| [p.x / p.z * 2.0 + 1.5, p.y / p.z * 4.0 + 1.0]).collect();
        assert_eq!(pixels, [[0.0, 0.0], [2.0, 0.0], [0.0, 2.0], [2.0, 2.0]]);
    }

    #[test]
    fn a_colour_image_or_a_bad_scale_is_refused_naming_the_file() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("colour.png");
        image::RgbImage::new(2, 2).save(&path).unwrap();
        let error = read_depth_png(&path, 1000.0).unwrap_err().to_string();
        assert!(error.contains("colour.png") && error.contains("16-bit"), "{error}");
        let error = read_depth_png(&path, 0.0).unwrap_err().to_string();
        assert!(error.contains("depth scale"), "{error}");
    }
}
