//! Undistorting camera images with the distortion of a `CameraInfo`
//! (`plumb_bob`: k1 k2 p1 p2 k3; `rational_polynomial`: k1 k2 p1 p2 k3 k4 k5
//! k6), as OpenCV's `undistort` with the same K: each output pixel samples
//! the raw image where the distortion moves it.

use image::{DynamicImage, Rgb, RgbImage};

use crate::camera::PinholeCamera;

/// A precomputed remap from the undistorted image to the raw one.
#[derive(Debug, Clone)]
pub struct Undistorter {
    camera: PinholeCamera,
    /// For each output pixel, the raw image position (OpenCV pixel convention).
    map: Vec<[f32; 2]>,
}

/// The models this handles, with the number of coefficients each takes.
pub const MODELS: [(&str, usize); 2] = [("plumb_bob", 5), ("rational_polynomial", 8)];

/// Where the distortion `d` moves the normalised point (x, y).
pub fn distort(d: &[f64], x: f64, y: f64) -> (f64, f64) {
    let k = |i: usize| d.get(i).copied().unwrap_or(0.0);
    let (k1, k2, p1, p2, k3, k4, k5, k6) = (k(0), k(1), k(2), k(3), k(4), k(5), k(6), k(7));
    let r2 = x * x + y * y;
    let radial = (1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))) / (1.0 + r2 * (k4 + r2 * (k5 + r2 * k6)));
    (x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x), y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y)
}

impl Undistorter {
    /// `camera` from K, `model` and `d` from the CameraInfo; an unknown
    /// model or a wrong number of coefficients is an error.
    pub fn new(camera: &PinholeCamera, model: &str, d: &[f64]) -> Result<Self, String> {
        let Some(&(_, n)) = MODELS.iter().find(|(m, _)| *m == model) else {
            return Err(format!(
                "distortion model `{model}` is not supported (plumb_bob, rational_polynomial); rectify the images first or pass an image_rect topic"
            ));
        };
        if d.len() < n.min(5) || d.len() > n.max(8) || !d.iter().all(|v| v.is_finite()) {
            return Err(format!("distortion model `{model}` takes {n} finite coefficients, got {d:?}"));
        }
        let (w, h) = (camera.width as usize, camera.height as usize);
        let mut map = Vec::with_capacity(w * h);
        for v in 0..h {
            for u in 0..w {
                let (x, y) = ((u as f64 - camera.cx) / camera.fx, (v as f64 - camera.cy) / camera.fy);
                let (xd, yd) = distort(d, x, y);
                map.push([(camera.fx * xd + camera.cx) as f32, (camera.fy * yd + camera.cy) as f32]);
            }
        }
        Ok(Self { camera: camera.clone(), map })
    }

    /// The undistorted image (RGB; pixels that map outside the raw image are black).
    pub fn apply(&self, raw: &DynamicImage) -> Result<DynamicImage, String> {
        let (w, h) = (self.camera.width, self.camera.height);
        if raw.width() != w || raw.height() != h {
            return Err(format!("image is {}x{}, its camera_info says {w}x{h}", raw.width(), raw.height()));
        }
        let rgb = raw.to_rgb8();
        let sample = |x: f32, y: f32| -> Rgb<u8> {
            if !(x >= 0.0 && y >= 0.0 && x <= (w - 1) as f32 && y <= (h - 1) as f32) {
                return Rgb([0, 0, 0]);
            }
            let (x0, y0) = (x.floor() as u32, y.floor() as u32);
            let (x1, y1) = ((x0 + 1).min(w - 1), (y0 + 1).min(h - 1));
            let (ax, ay) = (x - x0 as f32, y - y0 as f32);
            let mut out = [0u8; 3];
            for (c, o) in out.iter_mut().enumerate() {
                let p = |xx: u32, yy: u32| rgb.get_pixel(xx, yy)[c] as f32;
                let top = p(x0, y0) * (1.0 - ax) + p(x1, y0) * ax;
                let bottom = p(x0, y1) * (1.0 - ax) + p(x1, y1) * ax;
                *o = (top * (1.0 - ay) + bottom * ay).round().clamp(0.0, 255.0) as u8;
            }
            Rgb(out)
        };
        let out = RgbImage::from_fn(w, h, |u, v| {
            let [x, y] = self.map[(v * w + u) as usize];
            sample(x, y)
        });
        Ok(DynamicImage::ImageRgb8(out))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_point_seen_through_the_lens_lands_where_the_pinhole_puts_it() {
        let camera = PinholeCamera { width: 160, height: 120, fx: 100.0, fy: 100.0, cx: 79.5, cy: 59.5 };
        let d = [-0.3, 0.1, 0.001, -0.002, 0.0];
        // A ray at normalised (0.6, -0.35): the pinhole pixel and where the lens moves it.
        let (x, y) = (0.6, -0.35);
        let (xd, yd) = distort(&d, x, y);
        let raw_at = (camera.fx * xd + camera.cx, camera.fy * yd + camera.cy);
        let pinhole_at = (camera.fx * x + camera.cx, camera.fy * y + camera.cy);
        assert!((raw_at.0 - pinhole_at.0).abs() > 5.0, "the lens moves it visibly");
        let raw = RgbImage::from_fn(160, 120, |u, v| {
            let r2 = (u as f64 - raw_at.0).powi(2) + (v as f64 - raw_at.1).powi(2);
            if r2 < 2.0 { Rgb([255, 255, 255]) } else { Rgb([0, 0, 0]) }
        });
        let u = Undistorter::new(&camera, "plumb_bob", &d).unwrap();
        let out = u.apply(&DynamicImage::ImageRgb8(raw)).unwrap().to_rgb8();
        let (mut sx, mut sy, mut n) = (0.0, 0.0, 0.0);
        for (px, py, p) in out.enumerate_pixels() {
            let w = p[0] as f64;
            sx += w * px as f64;
            sy += w * py as f64;
            n += w;
        }
        let centroid = (sx / n, sy / n);
        assert!(
            (centroid.0 - pinhole_at.0).abs() < 0.5 && (centroid.1 - pinhole_at.1).abs() < 0.5,
            "{centroid:?} vs {pinhole_at:?}"
        );
        assert!(Undistorter::new(&camera, "equidistant", &[0.0; 4]).unwrap_err().contains("not supported"));
        assert!(u.apply(&DynamicImage::new_rgb8(10, 10)).unwrap_err().contains("10x10"));
    }
}
