//! The classic corner detectors a learned one is measured against:
//! Shi-Tomasi (the smaller eigenvalue of the structure tensor) and Harris
//! (det - k trace^2), from Sobel gradients smoothed by a Gaussian window,
//! the strongest responses kept at least a given distance apart.

use image::{GrayImage, ImageBuffer, Luma};
use imageproc::filter::gaussian_blur_f32;
use imageproc::gradients::{horizontal_sobel, vertical_sobel};

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CornerResponse {
    ShiTomasi,
    /// With Harris's k = 0.04.
    Harris,
}

type FloatImage = ImageBuffer<Luma<f32>, Vec<f32>>;

/// Standard deviation of the window that sums the gradients' products.
const WINDOW_SIGMA: f32 = 1.5;
const HARRIS_K: f32 = 0.04;

/// The response at every pixel.
pub fn response_map(gray: &GrayImage, kind: CornerResponse) -> FloatImage {
    let (gx, gy) = (horizontal_sobel(gray), vertical_sobel(gray));
    let (w, h) = gray.dimensions();
    let product = |f: &dyn Fn(f32, f32) -> f32| -> FloatImage {
        let raw = FloatImage::from_fn(w, h, |x, y| {
            Luma([f(gx.get_pixel(x, y)[0] as f32 / 8.0, gy.get_pixel(x, y)[0] as f32 / 8.0)])
        });
        gaussian_blur_f32(&raw, WINDOW_SIGMA)
    };
    let (xx, yy, xy) = (product(&|a, _| a * a), product(&|_, b| b * b), product(&|a, b| a * b));
    FloatImage::from_fn(w, h, |x, y| {
        let (a, c, b) = (xx.get_pixel(x, y)[0], yy.get_pixel(x, y)[0], xy.get_pixel(x, y)[0]);
        Luma([match kind {
            CornerResponse::ShiTomasi => 0.5 * (a + c) - (0.25 * (a - c) * (a - c) + b * b).sqrt(),
            CornerResponse::Harris => a * c - b * b - HARRIS_K * (a + c) * (a + c),
        }])
    })
}

/// The `count` strongest local maxima of the response (pixel centres in
/// box coordinates, where pixel (i, j) spans [i, i + 1) x [j, j + 1)), each at least `min_distance` from every stronger one kept, and
/// none within `border` pixels of the image edge (where the gradients see
/// the edge of the image). Ties go to the earlier pixel in row order.
pub fn strongest_corners(
    gray: &GrayImage,
    kind: CornerResponse,
    count: usize,
    min_distance: f32,
    border: u32,
) -> Vec<[f32; 2]> {
    let response = response_map(gray, kind);
    let (w, h) = response.dimensions();
    let mut candidates: Vec<(f32, u32, u32)> = Vec::new();
    for y in border.max(1)..h.saturating_sub(border.max(1)) {
        for x in border.max(1)..w.saturating_sub(border.max(1)) {
            let v = response.get_pixel(x, y)[0];
            if v <= 0.0 {
                continue;
            }
            let is_max = (y - 1..=y + 1)
                .flat_map(|yy| (x - 1..=x + 1).map(move |xx| (xx, yy)))
                .all(|(xx, yy)| (xx, yy) == (x, y) || response.get_pixel(xx, yy)[0] <= v);
            if is_max {
                candidates.push((v, x, y));
            }
        }
    }
    candidates.sort_by(|a, b| b.0.total_cmp(&a.0).then((a.2, a.1).cmp(&(b.2, b.1))));
    let mut kept: Vec<[f32; 2]> = Vec::new();
    let d2 = min_distance * min_distance;
    for (_, x, y) in candidates {
        if kept.len() >= count {
            break;
        }
        let p = [x as f32 + 0.5, y as f32 + 0.5];
        if kept.iter().all(|q| (q[0] - p[0]).powi(2) + (q[1] - p[1]).powi(2) >= d2) {
            kept.push(p);
        }
    }
    kept
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_rectangles_four_corners_are_the_strongest_and_its_edges_are_not_corners() {
        // A bright rectangle over pixels (40, 30) to (119, 89) on a dark
        // image: its corners at (40, 30) ... (120, 90) in box coordinates.
        let image = GrayImage::from_fn(160, 120, |x, y| {
            Luma([if (40..120).contains(&x) && (30..90).contains(&y) { 200 } else { 20 }])
        });
        for kind in [CornerResponse::ShiTomasi, CornerResponse::Harris] {
            let found = strongest_corners(&image, kind, 4, 10.0, 3);
            assert_eq!(found.len(), 4, "{kind:?}");
            for corner in [[40.0, 30.0], [120.0, 30.0], [40.0, 90.0], [120.0, 90.0]] {
                let nearest = found
                    .iter()
                    .map(|p| ((p[0] - corner[0]).powi(2) + (p[1] - corner[1]).powi(2)).sqrt())
                    .fold(f32::INFINITY, f32::min);
                // The window's smoothing pulls a corner's peak about a pixel and a half inside it.
                assert!(nearest <= 2.5, "{kind:?}: no corner within 2.5 px of {corner:?} in {found:?}");
            }
            // The middle of an edge responds far less than a corner.
            let response = response_map(&image, kind);
            let (edge, corner) = (response.get_pixel(80, 30)[0], response.get_pixel(40, 30)[0]);
            assert!(edge < 0.1 * corner, "{kind:?}: edge {edge}, corner {corner}");
        }
        // A flat image has no corners at all.
        let flat = GrayImage::from_pixel(64, 64, Luma([90]));
        assert!(strongest_corners(&flat, CornerResponse::ShiTomasi, 10, 5.0, 3).is_empty());
    }
}
