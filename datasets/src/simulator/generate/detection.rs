//! The detection data set: random views of the world rendered with their
//! Canny images and corner labels, written as COCO train/test splits.

use std::path::Path;

use image::DynamicImage;
use indicatif::ProgressBar;
use rand::rngs::ChaCha8Rng;
use rand::{RngExt, SeedableRng};
use rayon::prelude::*;

use super::config::DatagenConfig;
use super::{key, stream};
use crate::atomic;
use crate::cli::progress;
use crate::error::Result;
use crate::io::formats::{self, CocoAnnotation, CocoDataset, CocoImage, corner_categories};
use crate::math::Pose3;
use crate::preprocess::preprocess;
use crate::simulator::world::World;
use crate::simulator::world::labels::{CornerLabel, visible_corners};
use crate::simulator::world::layout::Floor;
use crate::simulator::world::render::{Lighting, render};
use crate::simulator::world::rig::Rig;
use crate::simulator::world::route::pose_on_floor;

pub(super) fn coco_annotations(labels: &[CornerLabel], image_id: u64, next_id: &mut u64) -> Vec<CocoAnnotation> {
    labels
        .iter()
        .map(|l| {
            *next_id += 1;
            CocoAnnotation::corner(*next_id, image_id, &l.bbox, l.point, Some(l.kind.name()))
        })
        .collect()
}

/// A random robot pose in the free space, away from walls and boxes, whose
/// camera does not stare at a surface closer than 1.5 m.
fn random_view(world: &World, rig: &Rig, rng: &mut ChaCha8Rng) -> Pose3 {
    loop {
        let world_from_camera = random_robot_pose(world, rng) * rig.robot_from_camera;
        let eye = nalgebra::Point3::from(world_from_camera.translation.vector);
        let axis = world_from_camera.rotation * nalgebra::Vector3::z();
        if world.cast(&eye, &axis, 1e-4, 1.5).is_none() {
            return world_from_camera;
        }
    }
}

/// A random robot pose in the free space, away from walls and boxes.
fn random_robot_pose(world: &World, rng: &mut ChaCha8Rng) -> Pose3 {
    let layout = &world.layout;
    let margin = 0.35;
    // Doorways are too narrow to stand in away from their walls.
    let areas: Vec<f64> = layout
        .regions
        .iter()
        .map(|r| {
            let (w, h) = (r.x[1] - r.x[0], r.y[1] - r.y[0]);
            if w > 2.0 * margin && h > 2.0 * margin { w * h } else { 0.0 }
        })
        .collect();
    let total: f64 = areas.iter().sum();
    loop {
        let mut pick = rng.random_range(0.0..total);
        let region = areas.iter().position(|a| {
            pick -= a;
            pick < 0.0
        });
        let r = &layout.regions[region.unwrap_or(0)];
        let x = rng.random_range(r.x[0] + margin..r.x[1] - margin);
        let y = rng.random_range(r.y[0] + margin..r.y[1] - margin);
        let blocked = layout
            .obstacles
            .iter()
            .any(|b| x > b.x[0] - margin && x < b.x[1] + margin && y > b.y[0] - margin && y < b.y[1] + margin)
            || layout.blocks.iter().any(|b| b.distance([x, y]) < margin);
        if blocked {
            continue;
        }
        // Half the views look along the region's long axis (down corridors and ramps).
        let heading = if rng.random_bool(0.5) {
            let along = if let Floor::Ramp { axis, .. } = r.floor {
                axis == crate::simulator::world::layout::Axis::X
            } else {
                r.x[1] - r.x[0] >= r.y[1] - r.y[0]
            };
            let base = if along { 0.0 } else { std::f64::consts::FRAC_PI_2 };
            let flip = if rng.random_bool(0.5) { std::f64::consts::PI } else { 0.0 };
            base + flip + rng.random_range(-0.5..0.5)
        } else {
            rng.random_range(-std::f64::consts::PI..std::f64::consts::PI)
        };
        if let Some(pose) = pose_on_floor(layout, [x, y], heading) {
            return pose;
        }
    }
}

pub(super) fn write_detection_set(
    dir: &Path,
    world: &World,
    rig: &Rig,
    config: &DatagenConfig,
) -> Result<(usize, usize)> {
    let n = config.detection.images;
    let bar = progress(n, "detection");
    let views = render_views(dir, world, rig, config, config.seed, 0..n, &bar)?;
    bar.finish_and_clear();
    let train: Vec<bool> = (0..n).map(|i| i < config.detection.train).collect();
    let labels = write_coco_splits(dir, views, &train)?;
    Ok((n, labels))
}

/// Renders random views `indices` of `world` into `dir/images` and
/// `dir/canny` (files `{i:06}.png`, COCO ids `i + 1`), with their
/// visible corners. `seed` picks the views and the lighting.
pub(crate) fn render_views(
    dir: &Path,
    world: &World,
    rig: &Rig,
    config: &DatagenConfig,
    seed: u64,
    indices: std::ops::Range<usize>,
    bar: &ProgressBar,
) -> Result<Vec<(CocoImage, Vec<CornerLabel>)>> {
    indices
        .into_par_iter()
        .map(|i| {
            let k = key(seed, stream::DETECTION, i as u64);
            let mut rng = ChaCha8Rng::seed_from_u64(k);
            let world_from_camera = random_view(world, rig, &mut rng);
            let lighting = Lighting::varied(k, world.layout.lights.len());
            // People stand where they are at a random moment.
            let time = rng.random_range(0.0..600.0);
            let image = render(world, &rig.camera, &world_from_camera, &lighting, time);
            let labels = visible_corners(world, &rig.camera, &world_from_camera, &config.labels, time);
            let name = format!("{i:06}.png");
            let image = DynamicImage::ImageRgb8(image);
            atomic::write_image(
                &dir.join("canny").join(&name),
                &DynamicImage::ImageLuma8(preprocess(&image, &config.preprocess)),
            )?;
            atomic::write_image(&dir.join("images").join(&name), &image)?;
            bar.inc(1);
            let entry = CocoImage {
                id: i as u64 + 1,
                file_name: format!("images/{name}"),
                width: rig.camera.width,
                height: rig.camera.height,
            };
            Ok((entry, labels))
        })
        .collect()
}

/// Writes `dir/train.json` (views whose `train` flag is set) and
/// `dir/test.json` (the others); returns the number of labels.
pub(crate) fn write_coco_splits(
    dir: &Path,
    views: Vec<(CocoImage, Vec<CornerLabel>)>,
    train: &[bool],
) -> Result<usize> {
    let mut splits = [
        CocoDataset { categories: corner_categories(), ..Default::default() },
        CocoDataset { categories: corner_categories(), ..Default::default() },
    ];
    let mut next_id = 0;
    let mut label_count = 0;
    for ((entry, labels), &is_train) in views.into_iter().zip(train) {
        let split = &mut splits[usize::from(!is_train)];
        label_count += labels.len();
        split.annotations.extend(coco_annotations(&labels, entry.id, &mut next_id));
        split.images.push(entry);
    }
    formats::write_coco(&dir.join("train.json"), &splits[0])?;
    formats::write_coco(&dir.join("test.json"), &splits[1])?;
    Ok(label_count)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::simulator::world::WorldConfig;

    #[test]
    fn random_views_stand_on_the_floor_clear_of_clutter_in_every_building() {
        // Doorways (1 x 0.3 m) are regions too narrow to stand in: they must
        // never be picked (they once made the sampling range empty).
        for building in 0..=5 {
            let world = World::new(&WorldConfig { building, ..WorldConfig::default() }, 1);
            let mut rng = ChaCha8Rng::seed_from_u64(9);
            for _ in 0..3000 {
                let pose = random_robot_pose(&world, &mut rng);
                let p = pose.translation.vector;
                let floor = world.layout.floor_height(p.x, p.y).expect("on the floor");
                assert!((p.z - floor).abs() < 0.05, "building {building}: {p:?} above a floor at {floor}");
                assert!(world.layout.blocks.iter().all(|b| b.distance([p.x, p.y]) >= 0.35));
            }
        }
    }
}
