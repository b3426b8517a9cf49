//! The colour camera of an RGB-D sensor whose colour image is not
//! registered to its depth (7-Scenes' Kinect: two cameras, no calibration
//! given). The depth image's occluding contours (where the depth jumps
//! back) are outlines the colour camera sees as edges too: the colour
//! camera's focal length, principal point and sideways offset are those
//! that lay the contours, seen through it, onto the colour image's Canny
//! edges (a truncated chamfer distance over a few frames, searched coarse
//! to fine). On a registered sequence (TUM) the fit lands within a few
//! pixels of the published intrinsics: that is its error bound.

use datasets::camera::PinholeCamera;
use datasets::io::formats::DepthImage;
use datasets::math::Vec3;
use image::GrayImage;
use rayon::prelude::*;

/// A contour point farther than this from every colour edge counts this
/// much (pixels): a contour the colour image does not show must not pull.
const TRUNCATE_PX: f32 = 10.0;

/// One frame's evidence: contour points (the depth camera's optical frame)
/// and the distance from each colour pixel to the nearest colour edge.
pub struct ContourFrame {
    pub points: Vec<Vec3>,
    width: u32,
    height: u32,
    distance_px: Vec<f32>,
}

impl ContourFrame {
    /// The frame of `depth` (seen by `depth_camera`) and its colour image in gray.
    pub fn new(depth: &DepthImage, depth_camera: &PinholeCamera, colour: &GrayImage, jump: f32) -> Self {
        // Canny marks edges 255, the rest 0: the transform's distances are to the edges.
        let edges = imageproc::edges::canny(colour, 40.0, 120.0);
        let squared = imageproc::distance_transform::euclidean_squared_distance_transform(&edges);
        let distance_px = squared.pixels().map(|p| (p[0] as f32).sqrt()).collect();
        Self {
            points: contour_points(depth, depth_camera, jump),
            width: colour.width(),
            height: colour.height(),
            distance_px,
        }
    }

    /// Sum of truncated distances of the points seen by `camera` at
    /// `baseline_m` (the colour camera's offset along x), and their count.
    fn chamfer(&self, camera: &PinholeCamera, baseline_m: f64) -> (f64, usize) {
        let mut sum = 0.0;
        for p in &self.points {
            let (x, y) = (p.x + baseline_m, p.y);
            let u = (camera.fx * x / p.z + camera.cx + 0.5).floor();
            let v = (camera.fy * y / p.z + camera.cy + 0.5).floor();
            let inside = u >= 0.0 && v >= 0.0 && u < f64::from(self.width) && v < f64::from(self.height);
            sum += if inside {
                f64::from(self.distance_px[v as usize * self.width as usize + u as usize].min(TRUNCATE_PX))
            } else {
                f64::from(TRUNCATE_PX)
            };
        }
        (sum, self.points.len())
    }
}

/// The occluding contour of a depth image: pixels whose 4-neighbour lies
/// more than `jump` (a fraction of the depth) behind them, lifted to 3D in
/// the camera's optical frame.
pub fn contour_points(depth: &DepthImage, camera: &PinholeCamera, jump: f32) -> Vec<Vec3> {
    let (w, h) = (depth.width as usize, depth.height as usize);
    let at = |x: usize, y: usize| depth.metres[y * w + x];
    let mut out = Vec::new();
    for y in 1..h.saturating_sub(1) {
        for x in 1..w.saturating_sub(1) {
            let z = at(x, y);
            if !(z > 0.0 && z.is_finite()) {
                continue;
            }
            let behind = [at(x + 1, y), at(x - 1, y), at(x, y + 1), at(x, y - 1)]
                .iter()
                .any(|&n| n.is_finite() && n > z * (1.0 + jump));
            if behind {
                let ray = camera.ray(x as f64 + 0.5, y as f64 + 0.5);
                out.push(ray * f64::from(z));
            }
        }
    }
    out
}

/// The fitted colour camera, and how well each camera lines the contours up.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct ColourFit {
    pub camera: PinholeCamera,
    /// The colour camera's offset from the depth camera along x (metres).
    pub baseline_m: f64,
    /// Mean truncated distance (pixels) from a contour point to a colour edge.
    pub mean_distance_px: f64,
    /// The same with the depth camera's own intrinsics and no offset.
    pub unregistered_distance_px: f64,
    pub frames: usize,
    pub contour_points: usize,
}

/// Mean truncated chamfer distance of every frame's contours.
pub fn mean_distance(frames: &[ContourFrame], camera: &PinholeCamera, baseline_m: f64) -> f64 {
    let (sum, n) = frames.iter().map(|f| f.chamfer(camera, baseline_m)).fold((0.0, 0), |a, b| (a.0 + b.0, a.1 + b.1));
    if n > 0 { sum / n as f64 } else { f64::from(TRUNCATE_PX) }
}

/// Searches focal length (one for both axes), principal point and baseline
/// from `start` (the depth camera's intrinsics): a coarse grid, finer grids
/// around the best, then the principal point and baseline together (a
/// sideways offset and a shifted principal point differ only with depth).
pub fn fit_colour_camera(frames: &[ContourFrame], start: &PinholeCamera) -> ColourFit {
    let camera_of = |f: f64, cx: f64, cy: f64| PinholeCamera { fx: f, fy: f, cx, cy, ..start.clone() };
    let cost = |f: f64, cx: f64, cy: f64, b: f64| mean_distance(frames, &camera_of(f, cx, cy), b);
    let grid = |centre: f64, half: f64, step: f64| {
        let n = (half / step).round() as i64;
        (-n..=n).map(move |k| centre + k as f64 * step)
    };
    let best_of = |candidates: Vec<(f64, f64, f64, f64)>| {
        candidates
            .into_par_iter()
            .map(|(f, cx, cy, b)| (cost(f, cx, cy, b), f, cx, cy, b))
            .min_by(|a, b| a.0.total_cmp(&b.0))
            .expect("a grid has points")
    };
    let f0 = 0.5 * (start.fx + start.fy);
    let mut best = (cost(f0, start.cx, start.cy, 0.0), f0, start.cx, start.cy, 0.0);
    let unregistered = best.0;
    for (f_half, f_step, c_half, c_step) in [(0.2 * f0, 10.0, 32.0, 4.0), (12.0, 2.0, 6.0, 1.0), (3.0, 0.5, 1.5, 0.5)] {
        let (f, cx, cy, b) = (best.1, best.2, best.3, best.4);
        let candidates: Vec<_> = grid(f, f_half, f_step)
            .flat_map(|f| {
                grid(cx, c_half, c_step).flat_map(move |cx| grid(cy, c_half, c_step).map(move |cy| (f, cx, cy, b)))
            })
            .collect();
        let found = best_of(candidates);
        if found.0 < best.0 {
            best = found;
        }
    }
    let (f, cx, cy) = (best.1, best.2, best.3);
    let candidates: Vec<_> =
        grid(cx, 8.0, 0.5).flat_map(|cx| grid(0.0, 0.06, 0.005).map(move |b| (f, cx, cy, b))).collect();
    let found = best_of(candidates);
    if found.0 < best.0 {
        best = found;
    }
    ColourFit {
        camera: camera_of(best.1, best.2, best.3),
        baseline_m: best.4,
        mean_distance_px: best.0,
        unregistered_distance_px: unregistered,
        frames: frames.len(),
        contour_points: frames.iter().map(|f| f.points.len()).sum(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 640 x 480 depth image of a box 1.5 m away in front of a wall at 3 m.
    fn box_scene() -> DepthImage {
        let (w, h) = (640u32, 480u32);
        let metres = (0..h)
            .flat_map(|y| {
                (0..w).map(move |x| if (200..440).contains(&x) && (140..340).contains(&y) { 1.5 } else { 3.0 })
            })
            .collect();
        DepthImage { width: w, height: h, metres }
    }

    /// The colour image a camera would take of `depth`'s scene: the box dark
    /// on a bright wall, drawn where `colour` at `baseline` sees it.
    fn colour_image(
        depth: &DepthImage,
        depth_camera: &PinholeCamera,
        colour: &PinholeCamera,
        baseline: f64,
    ) -> GrayImage {
        let mut image = GrayImage::from_pixel(640, 480, image::Luma([200]));
        for y in 0..depth.height {
            for x in 0..depth.width {
                let z = depth.metres[(y * depth.width + x) as usize];
                if z > 2.0 {
                    continue;
                }
                let p = depth_camera.ray(f64::from(x) + 0.5, f64::from(y) + 0.5) * f64::from(z);
                let u = colour.fx * (p.x + baseline) / p.z + colour.cx + 0.5;
                let v = colour.fy * p.y / p.z + colour.cy + 0.5;
                // The depth pixel covers (585/525)^-1 of a colour pixel: fill around it.
                for (du, dv) in [(0.0, 0.0), (0.5, 0.0), (0.0, 0.5), (0.5, 0.5)] {
                    let (uu, vv) = ((u + du).floor(), (v + dv).floor());
                    if uu >= 0.0 && vv >= 0.0 && uu < 640.0 && vv < 480.0 {
                        image.put_pixel(uu as u32, vv as u32, image::Luma([40]));
                    }
                }
            }
        }
        image
    }

    #[test]
    fn the_contours_find_a_colour_camera_of_another_focal_length_and_offset() {
        let depth_camera = PinholeCamera { width: 640, height: 480, fx: 585.0, fy: 585.0, cx: 319.5, cy: 239.5 };
        let truth = PinholeCamera { fx: 525.0, fy: 525.0, cx: 311.5, cy: 245.5, ..depth_camera.clone() };
        let depth = box_scene();
        let colour = colour_image(&depth, &depth_camera, &truth, 0.025);
        let frames = [ContourFrame::new(&depth, &depth_camera, &colour, 0.1)];
        assert!(frames[0].points.len() > 800, "{} contour points", frames[0].points.len());
        let fit = fit_colour_camera(&frames, &depth_camera);
        assert!(fit.unregistered_distance_px > 5.0, "{fit:?}");
        assert!(fit.mean_distance_px < 1.5, "{fit:?}");
        // One box at one depth cannot tell a principal point from a baseline:
        // what is fixed is where the box's outline lands.
        assert!((fit.camera.fx - 525.0).abs() <= 5.0, "{fit:?}");
        let u_of = |c: &PinholeCamera, b: f64| c.fx * (0.1 + b) / 1.5 + c.cx;
        assert!((u_of(&fit.camera, fit.baseline_m) - u_of(&truth, 0.025)).abs() < 1.5, "{fit:?}");
        assert!((fit.camera.cy - 245.5).abs() <= 1.5, "{fit:?}");
    }
}
