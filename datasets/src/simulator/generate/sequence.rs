//! The localization sequence: LIDAR sweeps along the route, camera images
//! on their own clock, odometry, IMU, ground truth, calibration and corner
//! labels, in the files `localize` reads.

use std::path::Path;

use image::DynamicImage;
use rayon::prelude::*;

use super::config::DatagenConfig;
use super::detection::coco_annotations;
use super::world_description::WorldDescription;
use super::{key, stream};
use crate::atomic;
use crate::cli::progress;
use crate::error::{DataError, Result};
use crate::io::formats::corner_categories;
use crate::io::formats::stamped_files::stamp_name;
use crate::io::formats::{self, CocoDataset, CocoImage, PcdData, Trajectory};
use crate::math::Pose3;
use crate::simulator::world::World;
use crate::simulator::world::labels::{CornerLabel, visible_corners};
use crate::simulator::world::lidar::{scan, sweep};
use crate::simulator::world::motion::{simulate_imu, simulate_odometry};
use crate::simulator::world::render::{Lighting, render};
use crate::simulator::world::rig::Rig;
use crate::simulator::world::route::{Route, pose_on_floor, samples_on_floor};

/// A LIDAR scan of the sequence.
pub struct Frame {
    /// The scan's stamp: the start of its sweep.
    pub stamp: f64,
    pub world_from_robot: Pose3,
    pub cloud: formats::PointCloud,
}

/// A camera image of the sequence.
pub struct Shot {
    pub stamp: f64,
    pub labels: Vec<CornerLabel>,
}

pub struct Sequence {
    pub frames: Vec<Frame>,
    pub shots: Vec<Shot>,
    pub route_length_m: f64,
    pub frames_after_route_end: usize,
}

pub(super) fn write_sequence(dir: &Path, world: &World, rig: &Rig, config: &DatagenConfig) -> Result<Sequence> {
    let s = &config.sequence;
    let route = Route::new(&world.layout.route, s.turn_radius_m);
    let length = route.length();
    let whole_route = ((length - s.start_m) / s.speed_mps * s.rate_hz).floor() as usize + 1;
    let count = s.frames.unwrap_or_else(|| whole_route.min(s.max_scans.unwrap_or(usize::MAX)));
    let frames_after_route_end = count.saturating_sub(whole_route);
    let layout = &world.layout;
    // The route is checked once, every 5 cm, so that poses never fail later.
    if let Err(xy) = samples_on_floor(layout, &route, 0.05) {
        return Err(DataError::invalid(
            dir,
            format!(
                "the route leaves the free space at ({:.2}, {:.2}) with a turn radius of {} m",
                xy[0], xy[1], s.turn_radius_m
            ),
        ));
    }
    let pose_at = |t: f64| -> Pose3 {
        let (xy, heading) = route.at(s.start_m + s.speed_mps * t.max(0.0));
        pose_on_floor(layout, xy, heading).expect("the route was checked to stay inside the free space")
    };
    let last_scan = (count - 1) as f64 / s.rate_hz;
    let image_stamps = image_stamps(config, count);

    let bar = progress(count + image_stamps.len(), "sequence");
    let frames: Vec<Result<Frame>> = (0..count)
        .into_par_iter()
        .map(|k| {
            let stamp = k as f64 / s.rate_hz;
            let world_from_robot = pose_at(stamp);
            let lidar_key = key(config.seed, stream::LIDAR, k as u64);
            let cloud = if config.lidar.sweep_period_s > 0.0 {
                let world_from_lidar = |t: f64| pose_at(t) * rig.robot_from_lidar;
                sweep(world, &config.lidar, &world_from_lidar, stamp, lidar_key)
            } else {
                scan(world, &config.lidar, &(world_from_robot * rig.robot_from_lidar), stamp, lidar_key)
            };
            formats::write_pcd(&dir.join("cloud").join(format!("{}.pcd", stamp_name(stamp))), &cloud, PcdData::Binary)?;
            bar.inc(1);
            Ok(Frame { stamp, world_from_robot, cloud })
        })
        .collect();
    let frames: Vec<Frame> = frames.into_iter().collect::<Result<_>>()?;
    let shots: Vec<Result<Shot>> = image_stamps
        .par_iter()
        .enumerate()
        .map(|(k, &image_stamp)| {
            let world_from_camera = pose_at(image_stamp) * rig.robot_from_camera;
            // Lighting drifts slowly along the route, noise changes every frame.
            let mut lighting = Lighting::varied(key(config.seed, stream::SEQUENCE_LIGHT, 0), layout.lights.len());
            lighting.gain *= 1.0 + 0.15 * ((image_stamp - s.camera_delay_s) as f32 * 0.01).sin();
            lighting.noise_seed = key(config.seed, stream::SEQUENCE_LIGHT, k as u64 + 1);
            let image = render(world, &rig.camera, &world_from_camera, &lighting, image_stamp);
            let labels = visible_corners(world, &rig.camera, &world_from_camera, &config.labels, image_stamp);
            let name = stamp_name(image_stamp);
            atomic::write_image(&dir.join("rgb").join(format!("{name}.png")), &DynamicImage::ImageRgb8(image))?;
            bar.inc(1);
            Ok(Shot { stamp: image_stamp, labels })
        })
        .collect();
    bar.finish_and_clear();
    let shots: Vec<Shot> = shots.into_iter().collect::<Result<_>>()?;

    // The logs run to the last image and the end of the last sweep.
    let last_image = image_stamps.last().copied().unwrap_or(0.0);
    let duration = (last_scan + config.lidar.sweep_period_s).max(last_image);
    write_logs(dir, &frames, &pose_at, duration, rig, config)?;
    write_labels(dir, &shots, rig)?;
    atomic::write_json(&dir.join("world.json"), &WorldDescription::of(world))?;
    Ok(Sequence { frames, shots, route_length_m: length, frames_after_route_end })
}

/// The camera's stamps: one per scan (after the camera's delay) without a
/// rate of its own, else on its own clock up to the end of the last sweep.
fn image_stamps(config: &DatagenConfig, count: usize) -> Vec<f64> {
    let s = &config.sequence;
    let last_scan = (count - 1) as f64 / s.rate_hz;
    match s.camera_rate_hz {
        None => (0..count).map(|k| k as f64 / s.rate_hz + s.camera_delay_s).collect(),
        Some(rate) => {
            let end = last_scan + config.lidar.sweep_period_s;
            (0..).map(|i| s.camera_delay_s + i as f64 / rate).take_while(|&t| t <= end).collect()
        }
    }
}

/// Odometry and IMU over `duration`, the ground truth at the scans and the calibration.
fn write_logs(
    dir: &Path,
    frames: &[Frame],
    pose_at: &dyn Fn(f64) -> Pose3,
    duration: f64,
    rig: &Rig,
    config: &DatagenConfig,
) -> Result<()> {
    let odometry = simulate_odometry(pose_at, duration, &config.motion, key(config.seed, stream::ODOMETRY, 0));
    let imu = simulate_imu(pose_at, duration, &config.motion, key(config.seed, stream::IMU, 0));
    formats::write_odometry(&dir.join("odom.csv"), &odometry)?;
    formats::write_imu(&dir.join("imu.csv"), &imu)?;
    let mut truth = Trajectory::default();
    frames.iter().for_each(|f| truth.push(f.stamp, f.world_from_robot));
    formats::write_tum(&dir.join("groundtruth.txt"), &truth)?;
    formats::write_calibration(&dir.join("calib.json"), &rig.calibration())
}

/// The images' corner labels as one COCO file.
fn write_labels(dir: &Path, shots: &[Shot], rig: &Rig) -> Result<()> {
    let mut labels = CocoDataset { categories: corner_categories(), ..Default::default() };
    let mut next_id = 0;
    for (k, shot) in shots.iter().enumerate() {
        let id = k as u64 + 1;
        labels.images.push(CocoImage {
            id,
            file_name: format!("rgb/{}.png", stamp_name(shot.stamp)),
            width: rig.camera.width,
            height: rig.camera.height,
        });
        labels.annotations.extend(coco_annotations(&shot.labels, id, &mut next_id));
    }
    formats::write_coco(&dir.join("labels.json"), &labels)
}
