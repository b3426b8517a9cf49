//! Preview pictures: sequence images with their labels drawn, and the
//! building from above with its route.

use std::path::{Path, PathBuf};

use image::{DynamicImage, Rgb, RgbImage};

use super::sequence::Sequence;
use crate::atomic;
use crate::error::Result;
use crate::io::formats::stamped_files::stamp_name;
use crate::simulator::world::World;
use crate::simulator::world::labels::CornerLabel;
use crate::simulator::world::layout::Layout;
use crate::simulator::world::rig::Rig;
use crate::simulator::world::route::Route;

const CORNER_COLOURS: [[u8; 3]; 5] = [[0, 220, 0], [0, 160, 255], [255, 200, 0], [255, 60, 60], [220, 0, 220]];

/// Draws labeled boxes (colour by corner type) and their corner points.
pub fn draw_labels(image: &mut RgbImage, labels: &[CornerLabel]) {
    for l in labels {
        let colour = Rgb(CORNER_COLOURS[l.kind as usize]);
        let b = l.bbox;
        let rect = imageproc::rect::Rect::at(b.x1 as i32, b.y1 as i32)
            .of_size(b.width().max(1.0) as u32, b.height().max(1.0) as u32);
        imageproc::drawing::draw_hollow_rect_mut(image, rect, colour);
        imageproc::drawing::draw_filled_circle_mut(image, (l.point[0] as i32, l.point[1] as i32), 2, colour);
    }
}

pub(super) fn write_previews(dir: &Path, world: &World, rig: &Rig, sequence: &Sequence) -> Result<()> {
    let n = sequence.shots.len();
    let picks: Vec<usize> = if n <= 4 { (0..n).collect() } else { (0..4).map(|i| i * (n - 1) / 3).collect() };
    let seq_dir: PathBuf = dir.parent().map(|p| p.join("sequence")).unwrap_or_default();
    for k in picks {
        let shot = &sequence.shots[k];
        let path = seq_dir.join("rgb").join(format!("{}.png", stamp_name(shot.stamp)));
        let mut image = atomic::read_image(&path)?.to_rgb8();
        draw_labels(&mut image, &shot.labels);
        atomic::write_image(&dir.join(format!("frame_{k:05}_labels.png")), &DynamicImage::ImageRgb8(image))?;
    }
    atomic::write_image(&dir.join("topdown.png"), &DynamicImage::ImageRgb8(top_down(world, rig, sequence)))
}

/// A map of the area seen from above: floors shaded by height, walls, the
/// LIDAR points of every few frames coloured by height, the route, corners.
fn top_down(world: &World, rig: &Rig, sequence: &Sequence) -> RgbImage {
    let layout = &world.layout;
    let px_per_m = 40.0;
    let (mut x0, mut y0, mut x1, mut y1) = (f64::MAX, f64::MAX, f64::MIN, f64::MIN);
    for r in &layout.regions {
        x0 = x0.min(r.x[0]);
        y0 = y0.min(r.y[0]);
        x1 = x1.max(r.x[1]);
        y1 = y1.max(r.y[1]);
    }
    let pad = 1.0;
    let (w, h) = (((x1 - x0 + 2.0 * pad) * px_per_m) as u32, ((y1 - y0 + 2.0 * pad) * px_per_m) as u32);
    let to_px = |x: f64, y: f64| (((x - x0 + pad) * px_per_m) as f32, ((y1 + pad - y) * px_per_m) as f32);
    let mut image = RgbImage::from_pixel(w, h, Rgb([255, 255, 255]));
    let lo = layout.levels.first().copied().unwrap_or(0.0);
    let hi = layout.levels.last().copied().unwrap_or(0.0);
    let ceiling = layout.regions.iter().map(|r| layout.ceiling_of(r, r.x[0], r.y[0])).fold(f64::MIN, f64::max);
    for (px, py, pixel) in image.enumerate_pixels_mut() {
        let x = px as f64 / px_per_m + x0 - pad;
        let y = y1 + pad - py as f64 / px_per_m;
        if let Some(z) = layout.floor_height(x, y) {
            let shade = (235.0 - 60.0 * (z - lo) / (hi - lo).max(1e-9)) as u8;
            *pixel = Rgb([shade, shade, shade]);
        }
    }
    let colour_of = |z: f64| {
        let f = ((z - lo) / (ceiling - lo)).clamp(0.0, 1.0);
        Rgb([(255.0 * f) as u8, (80.0 + 100.0 * (1.0 - (2.0 * f - 1.0).abs())) as u8, (255.0 * (1.0 - f)) as u8])
    };
    let step = (sequence.frames.len() / 40).max(1);
    for frame in sequence.frames.iter().step_by(step) {
        let world_from_lidar = frame.world_from_robot * rig.robot_from_lidar;
        for p in frame.cloud.points.iter().step_by(3) {
            let q = world_from_lidar * nalgebra::Point3::new(p.x as f64, p.y as f64, p.z as f64);
            let (u, v) = to_px(q.x, q.y);
            if u >= 0.0 && v >= 0.0 && (u as u32) < w && (v as u32) < h {
                image.put_pixel(u as u32, v as u32, colour_of(q.z));
            }
        }
    }
    for s in layout.surfaces.iter().filter(|s| s.kind == crate::simulator::world::surface::SurfaceKind::Wall) {
        let (a, b) = (s.vertices[0], s.vertices[1]);
        imageproc::drawing::draw_line_segment_mut(&mut image, to_px(a.x, a.y), to_px(b.x, b.y), Rgb([0, 0, 0]));
    }
    draw_blocks(&mut image, layout, &to_px);
    draw_route(&mut image, layout, sequence, &to_px);
    for c in &layout.corners {
        let (u, v) = to_px(c.position[0], c.position[1]);
        imageproc::drawing::draw_hollow_circle_mut(
            &mut image,
            (u as i32, v as i32),
            3,
            Rgb(CORNER_COLOURS[c.kind as usize]),
        );
    }
    image
}

/// Furniture in brown, glass in cyan, crates in orange (pillars and
/// partitions are drawn as walls).
fn draw_blocks(image: &mut RgbImage, layout: &Layout, to_px: &dyn Fn(f64, f64) -> (f32, f32)) {
    for b in &layout.blocks {
        use crate::simulator::world::block::BlockKind;
        let colour = match b.kind {
            BlockKind::Glass => Rgb([0, 170, 200]),
            BlockKind::Crate => Rgb([230, 120, 0]),
            BlockKind::Table | BlockKind::Chair | BlockKind::Shelf => Rgb([120, 70, 30]),
            BlockKind::Pillar | BlockKind::Partition => continue,
        };
        let f = b.footprint();
        for i in 0..4 {
            let (p, q) = (f[i], f[(i + 1) % 4]);
            imageproc::drawing::draw_line_segment_mut(image, to_px(p[0], p[1]), to_px(q[0], q[1]), colour);
        }
    }
}

/// The whole planned route in pink under the driven part in red.
fn draw_route(image: &mut RgbImage, layout: &Layout, sequence: &Sequence, to_px: &dyn Fn(f64, f64) -> (f32, f32)) {
    let planned = Route::new(&layout.route, 1.2);
    let steps = (planned.length() / 0.1).ceil() as usize;
    for k in 0..steps {
        let ((a, _), (b, _)) = (planned.at(k as f64 * 0.1), planned.at((k + 1) as f64 * 0.1));
        imageproc::drawing::draw_line_segment_mut(image, to_px(a[0], a[1]), to_px(b[0], b[1]), Rgb([255, 160, 160]));
    }
    for pair in sequence.frames.windows(2) {
        let (a, b) = (pair[0].world_from_robot.translation.vector, pair[1].world_from_robot.translation.vector);
        imageproc::drawing::draw_line_segment_mut(image, to_px(a.x, a.y), to_px(b.x, b.y), Rgb([200, 0, 0]));
    }
}
