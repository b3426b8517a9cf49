//! Edge points of an RGB-D frame: the colour image's Canny edges lifted to
//! 3D through the depth registered to it. Where the planes of a scene are
//! few (a box on a floor: floor, top and one face in view), point-to-plane
//! registration slides along them; the box's outline and the marks on its
//! faces are lines in 3D that fix the slide (LOAM's edge points, taken from
//! the image instead of the scan lines).

use datasets::camera::PinholeCamera;
use datasets::io::formats::DepthImage;
use image::GrayImage;
use nalgebra::Point3;
use serde::{Deserialize, Serialize};

/// How edge points are found.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct EdgeOptions {
    /// Off: depth frames register by their surfaces alone.
    pub enabled: bool,
    /// Canny's hysteresis thresholds (gradient magnitude of the 0-255 image).
    pub canny_low: f32,
    pub canny_high: f32,
    /// An edge pixel takes the nearest reading within this many pixels: an
    /// outline lies between the object and what is behind it, and the edge
    /// belongs to the object.
    pub window_px: usize,
    /// Edge points are thinned to one per cube of this edge (metres).
    pub voxel_m: f64,
}

impl Default for EdgeOptions {
    fn default() -> Self {
        Self { enabled: true, canny_low: 15.0, canny_high: 50.0, window_px: 2, voxel_m: 0.01 }
    }
}

impl EdgeOptions {
    pub fn validate(&self) -> Result<(), datasets::InvalidSetting> {
        let positive = datasets::InvalidSetting::positive;
        positive("canny_high", f64::from(self.canny_high), 10_000.0)?;
        positive("voxel_m", self.voxel_m, 1.0)?;
        if !(self.canny_low >= 0.0 && self.canny_low <= self.canny_high) {
            return Err(datasets::InvalidSetting::field(
                "canny_low",
                format!("{} outside [0, canny_high = {}]", self.canny_low, self.canny_high),
            ));
        }
        datasets::InvalidSetting::count("window_px", self.window_px, 0, 16)
    }
}

/// The Canny edges of `gray` at which the registered `depth` has a reading
/// within `[near, far]` metres, as points in the camera's optical frame (x
/// right, y down, z forward), one per `voxel_m` cube (the first in row
/// order). `None` when the two images differ in size (not registered).
pub fn edge_points(
    gray: &GrayImage,
    depth: &DepthImage,
    camera: &PinholeCamera,
    options: &EdgeOptions,
    near: f32,
    far: f32,
) -> Option<Vec<Point3<f32>>> {
    if (gray.width(), gray.height()) != (depth.width, depth.height) {
        return None;
    }
    let edges = imageproc::edges::canny(gray, options.canny_low, options.canny_high);
    let (width, height) = (depth.width as usize, depth.height as usize);
    let reach = options.window_px;
    let mut kept = rustc_hash::FxHashSet::default();
    let mut out = Vec::new();
    for (u, v, pixel) in edges.enumerate_pixels() {
        if pixel.0[0] == 0 {
            continue;
        }
        let (u, v) = (u as usize, v as usize);
        let mut nearest = f32::INFINITY;
        for row in v.saturating_sub(reach)..(v + reach + 1).min(height) {
            for col in u.saturating_sub(reach)..(u + reach + 1).min(width) {
                let z = depth.metres[row * width + col];
                // NaN (no reading) fails the comparisons.
                if z >= near && z <= far && z < nearest {
                    nearest = z;
                }
            }
        }
        if !nearest.is_finite() {
            continue;
        }
        let x = ((u as f64 - camera.cx) / camera.fx) as f32 * nearest;
        let y = ((v as f64 - camera.cy) / camera.fy) as f32 * nearest;
        let point = Point3::new(x, y, nearest);
        let cube = point.coords.map(|c| (f64::from(c) / options.voxel_m).floor() as i64);
        if kept.insert([cube.x, cube.y, cube.z]) {
            out.push(point);
        }
    }
    Some(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A dark square on a bright wall 2 m away, the square's pixels 1.5 m
    /// away: its outline's points lie on the square (1.5 m), not the wall.
    #[test]
    fn an_outline_lifts_to_the_nearer_surface_on_its_own_rays() {
        let camera = PinholeCamera { width: 80, height: 60, fx: 60.0, fy: 60.0, cx: 40.0, cy: 30.0 };
        let inside = |u: u32, v: u32| (30..50).contains(&u) && (20..40).contains(&v);
        let gray = GrayImage::from_fn(80, 60, |u, v| image::Luma([if inside(u, v) { 30 } else { 220 }]));
        let metres = (0..60u32).flat_map(|v| (0..80u32).map(move |u| if inside(u, v) { 1.5 } else { 2.0 })).collect();
        let depth = DepthImage { width: 80, height: 60, metres };
        let options = EdgeOptions { voxel_m: 0.001, ..EdgeOptions::default() };
        let points = edge_points(&gray, &depth, &camera, &options, 0.2, 4.0).unwrap();
        assert!(points.len() > 40, "the square's outline: {} points", points.len());
        for p in &points {
            assert_eq!(p.z, 1.5, "an outline point off the square: {p:?}");
            // On the square's border: 10 pixels from its centre at 1.5 m / 60 px.
            let (u, v) = (p.x / p.z * 60.0 + 40.0, p.y / p.z * 60.0 + 30.0);
            let ring = (u - 39.5).abs().max((v - 29.5).abs());
            assert!((8.0..=12.0).contains(&ring), "({u}, {v}) is not on the outline");
        }
        let other = DepthImage { width: 40, height: 60, metres: vec![1.0; 2400] };
        assert!(edge_points(&gray, &other, &camera, &options, 0.2, 4.0).is_none(), "not registered");
    }

    #[test]
    fn thinning_keeps_one_point_a_cube() {
        let camera = PinholeCamera { width: 80, height: 60, fx: 60.0, fy: 60.0, cx: 40.0, cy: 30.0 };
        let gray = GrayImage::from_fn(80, 60, |u, _| image::Luma([if u < 40 { 30 } else { 220 }]));
        let depth = DepthImage { width: 80, height: 60, metres: vec![2.0; 4800] };
        let fine = edge_points(&gray, &depth, &camera, &EdgeOptions { voxel_m: 0.001, ..Default::default() }, 0.2, 4.0);
        let coarse = edge_points(&gray, &depth, &camera, &EdgeOptions { voxel_m: 0.5, ..Default::default() }, 0.2, 4.0);
        let (fine, coarse) = (fine.unwrap(), coarse.unwrap());
        // A vertical line 2 m away spanning 2 m of height: every row of it finely, and
        // at half a metre one point for each cube the fine points fall in.
        assert!(fine.len() >= 60, "{}", fine.len());
        let cube = |p: &Point3<f32>| p.coords.map(|c| (f64::from(c) / 0.5).floor() as i64);
        let cubes: rustc_hash::FxHashSet<_> = fine.iter().map(cube).collect();
        let kept: rustc_hash::FxHashSet<_> = coarse.iter().map(cube).collect();
        assert_eq!(kept.len(), coarse.len(), "two kept points share a cube");
        assert_eq!(kept, cubes);
        assert!((4..=8).contains(&coarse.len()), "{}", coarse.len());
    }
}
