//! Canny edges: Gaussian blur (sigma 1.4), Sobel gradients, non-maximum
//! suppression along the gradient, and hysteresis that follows weak edges
//! from strong ones through all eight neighbours (as OpenCV does).
//!
//! Blur and Sobel come from imageproc. Its own `edges::canny` (0.27) is not
//! used: its hysteresis visits only six of the eight neighbours (never the
//! pixel above or above-right), so an edge that continues upward from its
//! first strong pixel is dropped. On the rendered rooms that lost 40% of the
//! labelled corners' lines at the same thresholds.

use image::{GrayImage, Luma};
use imageproc::filter::gaussian_blur_f32;
use imageproc::gradients::{horizontal_sobel, vertical_sobel};

/// Edge map (255 on edges, 0 elsewhere) with hysteresis thresholds `low` and
/// `high` on the Sobel gradient magnitude of the blurred 0..255 image.
pub fn canny(image: &GrayImage, low: f32, high: f32) -> GrayImage {
    edges(&Gradients::of(image), low, high)
}

/// Edge map with thresholds taken from the image's own gradients: `high`
/// is the `high_quantile` of the gradient magnitude over the pixels (as
/// MATLAB's `edge(I, 'canny')` takes its 0.7), `low` is `low_ratio` of it.
/// Returns the edges and the two thresholds used.
pub fn canny_adaptive(image: &GrayImage, high_quantile: f32, low_ratio: f32) -> (GrayImage, [f32; 2]) {
    let gradients = Gradients::of(image);
    let mut magnitudes = gradients.magnitude.clone();
    let high = if magnitudes.is_empty() {
        0.0
    } else {
        let index = ((high_quantile * magnitudes.len() as f32) as usize).min(magnitudes.len() - 1);
        *magnitudes.select_nth_unstable_by(index, f32::total_cmp).1
    };
    // A flat image has no gradient at all: a zero threshold would make
    // every pixel an edge.
    let high = high.max(f32::MIN_POSITIVE);
    let low = low_ratio * high;
    (edges(&gradients, low, high), [low, high])
}

/// The Sobel gradient magnitude of every pixel of the blurred image, row by
/// row: what the thresholds of `canny` and `canny_adaptive` compare.
pub fn gradient_magnitudes(image: &GrayImage) -> Vec<f32> {
    Gradients::of(image).magnitude
}

/// Sobel gradients of the image blurred with sigma 1.4, and their magnitude.
struct Gradients {
    width: usize,
    height: usize,
    gx: Vec<i16>,
    gy: Vec<i16>,
    magnitude: Vec<f32>,
}

impl Gradients {
    fn of(image: &GrayImage) -> Self {
        let blurred = gaussian_blur_f32(image, 1.4);
        let gx = horizontal_sobel(&blurred).into_raw();
        let gy = vertical_sobel(&blurred).into_raw();
        let magnitude = gx.iter().zip(&gy).map(|(&x, &y)| f32::from(x).hypot(f32::from(y))).collect();
        Self { width: image.width() as usize, height: image.height() as usize, gx, gy, magnitude }
    }
}

fn edges(gradients: &Gradients, low: f32, high: f32) -> GrayImage {
    let Gradients { width: w, height: h, gx, gy, magnitude } = gradients;
    let (w, h) = (*w, *h);
    let at = |x: usize, y: usize| magnitude[y * w + x];

    // Non-maximum suppression: keep a pixel that is no weaker than both
    // neighbours across the edge (gradient direction quantised to 45 deg).
    let mut thin = vec![0.0f32; w * h];
    for y in 1..h.saturating_sub(1) {
        for x in 1..w.saturating_sub(1) {
            let m = at(x, y);
            if m < low {
                continue;
            }
            let (dx, dy) = (f32::from(gx[y * w + x]), f32::from(gy[y * w + x]));
            // Angle of the gradient in 0..180 deg, y pointing down.
            let mut angle = dy.atan2(dx).to_degrees();
            if angle < 0.0 {
                angle += 180.0;
            }
            let (a, b) = if !(22.5..157.5).contains(&angle) {
                (at(x - 1, y), at(x + 1, y))
            } else if angle < 67.5 {
                (at(x - 1, y - 1), at(x + 1, y + 1))
            } else if angle < 112.5 {
                (at(x, y - 1), at(x, y + 1))
            } else {
                (at(x + 1, y - 1), at(x - 1, y + 1))
            };
            if m >= a && m >= b {
                thin[y * w + x] = m;
            }
        }
    }

    // Hysteresis: every pixel >= high starts an edge, which grows through
    // 8-connected pixels >= low.
    let mut out = GrayImage::new(w as u32, h as u32);
    let mut stack = Vec::new();
    for start in 0..w * h {
        if thin[start] < high || out.as_raw()[start] != 0 {
            continue;
        }
        out.put_pixel((start % w) as u32, (start / w) as u32, Luma([255]));
        stack.push(start);
        while let Some(p) = stack.pop() {
            let (px, py) = ((p % w) as isize, (p / w) as isize);
            for (dx, dy) in [(-1, -1), (0, -1), (1, -1), (-1, 0), (1, 0), (-1, 1), (0, 1), (1, 1)] {
                let (nx, ny) = (px + dx, py + dy);
                if nx < 0 || ny < 0 || nx >= w as isize || ny >= h as isize {
                    continue;
                }
                let n = ny as usize * w + nx as usize;
                if thin[n] >= low && out.as_raw()[n] == 0 {
                    out.put_pixel(nx as u32, ny as u32, Luma([255]));
                    stack.push(n);
                }
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A step edge rising to the upper right: every row of the line must be
    /// found, also the rows above the first strong pixel, which imageproc's
    /// six-neighbour hysteresis loses.
    #[test]
    fn an_edge_running_upward_is_followed_from_its_strong_end() {
        let (w, h) = (60u32, 60u32);
        // Dark left of the line x = 20 + (59 - y) / 2, bright right; the
        // contrast fades toward the top so that only the bottom is strong.
        let image = GrayImage::from_fn(w, h, |x, y| {
            let edge = 20.0 + (59.0 - y as f32) / 2.0;
            let contrast = 20.0 + 60.0 * y as f32 / 59.0;
            Luma([if (x as f32) < edge { 100 } else { (100.0 + contrast) as u8 }])
        });
        let edges = canny(&image, 10.0, 150.0);
        let rows_with_edge = (5..55).filter(|&y| (0..w).any(|x| edges.get_pixel(x, y)[0] == 255)).count();
        assert_eq!(rows_with_edge, 50, "the weak upper part of the edge was dropped");
        let legacy = imageproc::edges::canny(&image, 10.0, 150.0);
        let legacy_rows = (5..55).filter(|&y| (0..w).any(|x| legacy.get_pixel(x, y)[0] == 255)).count();
        assert!(legacy_rows < 50, "imageproc now follows upward edges ({legacy_rows}): consider using it again");
    }

    #[test]
    fn adaptive_thresholds_follow_the_contrast() {
        // The same step at two contrasts: fixed thresholds find the strong
        // one only, thresholds from the image's own gradients find both,
        // in the same place, at thresholds that scale with the contrast.
        let step = |contrast: u8| GrayImage::from_fn(32, 32, |x, _| Luma([if x < 16 { 80 } else { 80 + contrast }]));
        let (strong, weak) = (step(80), step(10));
        assert!(canny(&weak, 15.0, 40.0).pixels().all(|p| p[0] == 0));
        let (edges_strong, [low_strong, high_strong]) = canny_adaptive(&strong, 0.91, 0.375);
        let (edges_weak, [low_weak, high_weak]) = canny_adaptive(&weak, 0.91, 0.375);
        for edges in [&edges_strong, &edges_weak] {
            for y in 2..30 {
                let on: Vec<u32> = (0..32).filter(|&x| edges.get_pixel(x, y)[0] == 255).collect();
                assert!(!on.is_empty() && on.iter().all(|x| (14..18).contains(x)), "row {y}: edge at {on:?}");
            }
        }
        // About the contrast ratio 8, up to the blur's rounding to whole grey levels.
        let ratio = high_strong / high_weak;
        assert!((5.0..11.0).contains(&ratio), "thresholds {high_strong} and {high_weak}");
        assert!((low_weak / high_weak - 0.375).abs() < 1e-6 && (low_strong / high_strong - 0.375).abs() < 1e-6);
        // The high threshold is the quantile: 91% of pixels lie below it.
        let below = Gradients::of(&strong).magnitude.iter().filter(|&&m| m < high_strong).count();
        assert!(below as f32 <= 0.91 * 1024.0 + 1.0, "{below} of 1024 below {high_strong}");
        // A flat image gives no edges, not every pixel.
        let flat = GrayImage::from_pixel(16, 16, Luma([120]));
        assert!(canny_adaptive(&flat, 0.91, 0.375).0.pixels().all(|p| p[0] == 0));
    }

    #[test]
    fn a_flat_image_has_no_edges_and_thresholds_bound_the_edges() {
        let flat = GrayImage::from_pixel(32, 32, Luma([120]));
        assert!(canny(&flat, 1.0, 2.0).pixels().all(|p| p[0] == 0));
        // A vertical step of 40 grey levels: Sobel gives 8 x 40 = 320 times
        // the blurred step's slope (0.28 of the step per pixel at sigma 1.4),
        // about 90; found at 30/60, absent at 300/400.
        let step = GrayImage::from_fn(32, 32, |x, _| Luma([if x < 16 { 80 } else { 120 }]));
        let found = canny(&step, 30.0, 60.0);
        assert!((2..30).all(|y| (14..18).any(|x| found.get_pixel(x, y)[0] == 255)));
        assert!(found.pixels().filter(|p| p[0] == 255).count() <= 2 * 32);
        assert!(canny(&step, 300.0, 400.0).pixels().all(|p| p[0] == 0));
    }
}
