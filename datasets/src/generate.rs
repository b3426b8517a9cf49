//! Writes the default data of the project from the synthetic world: a
//! detection data set (images, Canny images, COCO train/test splits) and a
//! localization sequence (images, LIDAR clouds, odometry, IMU, ground truth,
//! calibration, corner labels), plus preview pictures.

use std::path::{Path, PathBuf};

use image::{DynamicImage, Rgb, RgbImage};
use indicatif::{ProgressBar, ProgressStyle};
use rand::rngs::ChaCha8Rng;
use rand::{RngExt, SeedableRng};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::atomic;
use crate::error::{DataError, Result};
use crate::formats::{self, CocoAnnotation, CocoCategory, CocoDataset, CocoImage, PcdData, Trajectory};
use crate::math::Pose3;
use crate::preprocess::{PreprocessConfig, preprocess};
use crate::world::labels::{CornerLabel, LabelConfig, visible_corners};
use crate::world::layout::{Floor, mix};
use crate::world::lidar::{LidarConfig, scan, sweep};
use crate::world::motion::{MotionConfig, simulate_imu, simulate_odometry};
use crate::world::render::{Lighting, render};
use crate::world::rig::Rig;
use crate::world::route::{Route, pose_on_floor, samples_on_floor};
use crate::world::{World, WorldConfig};

/// Everything `datagen` needs; written next to the results as `datagen.json`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DatagenConfig {
    pub seed: u64,
    pub world: WorldConfig,
    pub detection: DetectionConfig,
    pub sequence: SequenceConfig,
    pub labels: LabelConfig,
    pub lidar: LidarConfig,
    pub motion: MotionConfig,
    pub preprocess: PreprocessConfig,
}

impl Default for DatagenConfig {
    fn default() -> Self {
        Self {
            seed: 7,
            world: WorldConfig::default(),
            detection: DetectionConfig::default(),
            sequence: SequenceConfig::default(),
            labels: LabelConfig::default(),
            lidar: LidarConfig::default(),
            motion: MotionConfig::default(),
            preprocess: PreprocessConfig::default(),
        }
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DetectionConfig {
    /// Images in all; the first `train` form the training split, the rest the test split.
    pub images: usize,
    pub train: usize,
}

impl Default for DetectionConfig {
    fn default() -> Self {
        Self { images: 300, train: 200 }
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SequenceConfig {
    /// Robot speed along the route (the paper: 0.05 m/s).
    pub speed_mps: f64,
    /// LIDAR scan rate, and the camera's when it has none of its own (the
    /// paper: both at 1 Hz).
    pub rate_hz: f64,
    /// Frames (scans) to record; `None` drives the whole route once, up to `max_scans`.
    pub frames: Option<usize>,
    /// The most scans a whole-route sequence records: at slow speeds the
    /// sequence covers the start of the route.
    pub max_scans: Option<usize>,
    /// The camera's own frame rate; `None` takes one image per scan.
    pub camera_rate_hz: Option<f64>,
    /// Radius of the route's turns.
    pub turn_radius_m: f64,
    /// How long after each scan its image is taken, or with a camera rate
    /// of its own, the time of its first image; each image is rendered from
    /// the pose at its own time and named by it. 0, the paper's, takes scan
    /// and image together.
    pub camera_delay_s: f64,
}

impl Default for SequenceConfig {
    fn default() -> Self {
        Self {
            speed_mps: 0.05,
            rate_hz: 1.0,
            frames: None,
            max_scans: None,
            camera_rate_hz: None,
            turn_radius_m: 1.2,
            camera_delay_s: 0.0,
        }
    }
}

impl DatagenConfig {
    /// The settings for building `number`: the paper's for 0; for a
    /// generated building, a robot's sensors on their own clocks: a spinning
    /// LIDAR at 10 Hz sweeping over 0.1 s, the camera at 15 Hz, odometry at
    /// 50 Hz with slip on ramps, the IMU at 200 Hz, 1 m/s, at most 3000 scans.
    pub fn for_building(number: u32) -> Self {
        let mut config = Self::default();
        config.world.building = number;
        if number == 0 {
            return config;
        }
        config.sequence = SequenceConfig {
            speed_mps: 1.0,
            rate_hz: 10.0,
            max_scans: Some(3000),
            camera_rate_hz: Some(15.0),
            camera_delay_s: 0.021,
            ..SequenceConfig::default()
        };
        config.lidar.sweep_period_s = 0.1;
        config.motion.odometry_rate_hz = 50.0;
        config.motion.imu_rate_hz = 200.0;
        config.motion.ramp_slip = 0.03;
        config
    }
}

impl DatagenConfig {
    /// Checks every section; the message names the offending field.
    pub fn validate(&self) -> Result<(), String> {
        self.world.validate().map_err(|m| format!("world: {m}"))?;
        self.labels.validate().map_err(|m| format!("labels: {m}"))?;
        self.lidar.validate().map_err(|m| format!("lidar: {m}"))?;
        self.motion.validate().map_err(|m| format!("motion: {m}"))?;
        self.preprocess.validate().map_err(|m| format!("preprocess: {m}"))?;
        let d = &self.detection;
        if d.train > d.images {
            return Err(format!("detection: train split {} is larger than the {} images", d.train, d.images));
        }
        let s = &self.sequence;
        if !(s.speed_mps.is_finite() && s.speed_mps > 0.0 && s.speed_mps <= 5.0) {
            return Err(format!("sequence: speed {} m/s outside (0, 5]", s.speed_mps));
        }
        if !(s.rate_hz.is_finite() && s.rate_hz > 0.0 && s.rate_hz <= 100.0) {
            return Err(format!("sequence: rate {} Hz outside (0, 100]", s.rate_hz));
        }
        if s.frames == Some(0) {
            return Err("sequence: frames must be at least 1".into());
        }
        if s.max_scans == Some(0) {
            return Err("sequence: max scans must be at least 1".into());
        }
        if let Some(rate) = s.camera_rate_hz
            && !(rate.is_finite() && rate > 0.0 && rate <= 100.0)
        {
            return Err(format!("sequence: camera rate {rate} Hz outside (0, 100]"));
        }
        if self.lidar.sweep_period_s > 1.0 / s.rate_hz + 1e-9 {
            return Err(format!(
                "lidar: a sweep of {} s is longer than the {} s between scans",
                self.lidar.sweep_period_s,
                1.0 / s.rate_hz
            ));
        }
        if !(s.camera_delay_s.abs() <= 1.0) {
            return Err(format!("sequence: camera delay {} s outside [-1, 1]", s.camera_delay_s));
        }
        if !(s.turn_radius_m > 0.1 && s.turn_radius_m < 3.0) {
            return Err(format!("sequence: turn radius {} m outside (0.1, 3)", s.turn_radius_m));
        }
        Ok(())
    }
}

/// What a generation run produced, for the command's summary.
#[derive(Debug, Clone, PartialEq)]
pub struct Summary {
    pub detection_images: usize,
    pub detection_labels: usize,
    pub frames: usize,
    pub route_length_m: f64,
    /// Frames whose time runs past the end of the route (the robot waits there).
    pub frames_after_route_end: usize,
}

/// Streams of the one seed, so that each part draws its own numbers.
pub(crate) mod stream {
    pub const APPEARANCE: u64 = 1;
    pub const DETECTION: u64 = 2;
    pub const SEQUENCE_LIGHT: u64 = 3;
    pub const LIDAR: u64 = 4;
    pub const ODOMETRY: u64 = 5;
    pub const IMU: u64 = 6;
}

pub(crate) fn key(seed: u64, stream: u64, index: u64) -> u64 {
    mix(mix(seed ^ stream.wrapping_mul(0x9e37_79b9)) ^ index)
}

pub(crate) fn progress(len: usize, what: &str) -> ProgressBar {
    let bar = ProgressBar::new(len as u64);
    bar.set_style(
        ProgressStyle::with_template("{msg:>12} [{bar:40}] {pos}/{len} ({eta})")
            .expect("valid template")
            .progress_chars("=> "),
    );
    bar.set_message(what.to_string());
    bar
}

/// Generates the detection data set into `out/detection` and the sequence
/// into `out/sequence`, and previews into `out/preview`.
pub fn generate(out: &Path, config: &DatagenConfig) -> Result<Summary> {
    config.validate().map_err(|m| DataError::invalid(out, format!("invalid configuration: {m}")))?;
    let world = World::new(&config.world, key(config.seed, stream::APPEARANCE, 0));
    let rig = Rig::default();
    // The folder is one run: an earlier run's parts go first (a longer
    // sequence would leave its extra frames), and `datagen.json` comes last,
    // so that a killed run never looks finished.
    for part in ["datagen.json", "detection", "sequence", "preview"] {
        let path = out.join(part);
        let removed = if path.is_dir() { std::fs::remove_dir_all(&path) } else { std::fs::remove_file(&path) };
        match removed {
            Err(e) if e.kind() != std::io::ErrorKind::NotFound => return Err(DataError::io(&path, e)),
            _ => {}
        }
    }
    let (detection_images, detection_labels) = write_detection_set(&out.join("detection"), &world, &rig, config)?;
    let sequence = write_sequence(&out.join("sequence"), &world, &rig, config)?;
    write_previews(&out.join("preview"), &world, &rig, &sequence)?;
    atomic::write_json(&out.join("datagen.json"), config)?;
    Ok(Summary {
        detection_images,
        detection_labels,
        frames: sequence.frames.len(),
        route_length_m: sequence.route_length_m,
        frames_after_route_end: sequence.frames_after_route_end,
    })
}

fn coco_annotations(labels: &[CornerLabel], image_id: u64, next_id: &mut u64) -> Vec<CocoAnnotation> {
    labels
        .iter()
        .map(|l| {
            *next_id += 1;
            CocoAnnotation {
                id: *next_id,
                image_id,
                category_id: 1,
                bbox: l.bbox.to_xywh(),
                area: l.bbox.area(),
                iscrowd: 0,
                corner_type: Some(l.kind.name().to_string()),
                point: Some([l.point[0] as f32, l.point[1] as f32]),
            }
        })
        .collect()
}

fn categories() -> Vec<CocoCategory> {
    vec![CocoCategory { id: 1, name: "corner".into(), supercategory: Some("corner".into()) }]
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
                axis == crate::world::layout::Axis::X
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

fn write_detection_set(dir: &Path, world: &World, rig: &Rig, config: &DatagenConfig) -> Result<(usize, usize)> {
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
        CocoDataset { categories: categories(), ..Default::default() },
        CocoDataset { categories: categories(), ..Default::default() },
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

/// The file stem of a frame: its timestamp in seconds with six decimals,
/// zero-padded to ten integer digits so that names sort in time order
/// (tools that take files in name order, KISS-ICP among them, need that).
pub fn stamp_name(stamp: f64) -> String {
    format!("{stamp:017.6}")
}

/// The time a file stem gives: seconds (`10.5`, `0000000010.500000`), or
/// nanoseconds when it has 16 digits or more and no point.
pub fn parse_stamp_name(stem: &str) -> Option<f64> {
    if stem.len() >= 16 && stem.bytes().all(|b| b.is_ascii_digit()) {
        let ns: i64 = stem.parse().ok()?;
        return Some(crate::recording::wire::ns_to_s(ns));
    }
    stem.parse::<f64>().ok().filter(|t| t.is_finite())
}

fn write_sequence(dir: &Path, world: &World, rig: &Rig, config: &DatagenConfig) -> Result<Sequence> {
    let s = &config.sequence;
    let route = Route::new(&world.layout.route, s.turn_radius_m);
    let length = route.length();
    let whole_route = (length / s.speed_mps * s.rate_hz).floor() as usize + 1;
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
        let (xy, heading) = route.at(s.speed_mps * t.max(0.0));
        pose_on_floor(layout, xy, heading).expect("the route was checked to stay inside the free space")
    };
    let last_scan = (count - 1) as f64 / s.rate_hz;
    let image_stamps: Vec<f64> = match s.camera_rate_hz {
        None => (0..count).map(|k| k as f64 / s.rate_hz + s.camera_delay_s).collect(),
        Some(rate) => {
            let end = last_scan + config.lidar.sweep_period_s;
            (0..).map(|i| s.camera_delay_s + i as f64 / rate).take_while(|&t| t <= end).collect()
        }
    };

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
    let odometry = simulate_odometry(&pose_at, duration, &config.motion, key(config.seed, stream::ODOMETRY, 0));
    let imu = simulate_imu(&pose_at, duration, &config.motion, key(config.seed, stream::IMU, 0));
    formats::write_odometry(&dir.join("odom.csv"), &odometry)?;
    formats::write_imu(&dir.join("imu.csv"), &imu)?;
    let mut truth = Trajectory::default();
    frames.iter().for_each(|f| truth.push(f.stamp, f.world_from_robot));
    formats::write_tum(&dir.join("groundtruth.txt"), &truth)?;
    formats::write_calibration(&dir.join("calib.json"), &rig.calibration())?;

    let mut labels = CocoDataset { categories: categories(), ..Default::default() };
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
    formats::write_coco(&dir.join("labels.json"), &labels)?;
    atomic::write_json(&dir.join("world.json"), &WorldDescription::of(world))?;
    Ok(Sequence { frames, shots, route_length_m: length, frames_after_route_end })
}

/// `world.json`: what the ground truth knows about the area, for per-level
/// evaluation and for checking corners.
#[derive(Debug, Clone, Serialize)]
pub struct WorldDescription<'a> {
    pub config: &'a WorldConfig,
    pub levels: Vec<LevelDescription>,
    pub regions: &'a [crate::world::layout::Region],
    pub corners: &'a [crate::world::Corner],
}

#[derive(Debug, Clone, Serialize)]
pub struct LevelDescription {
    pub name: String,
    pub floor_height_m: f64,
}

impl<'a> WorldDescription<'a> {
    pub fn of(world: &'a World) -> Self {
        let layout = &world.layout;
        let levels = layout
            .levels
            .iter()
            .enumerate()
            .map(|(i, &h)| LevelDescription { name: format!("level {}", i + 1), floor_height_m: h })
            .collect();
        Self { config: &layout.config, levels, regions: &layout.regions, corners: &layout.corners }
    }
}

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

fn write_previews(dir: &Path, world: &World, rig: &Rig, sequence: &Sequence) -> Result<()> {
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
    for s in layout.surfaces.iter().filter(|s| s.kind == crate::world::surface::SurfaceKind::Wall) {
        let (a, b) = (s.vertices[0], s.vertices[1]);
        imageproc::drawing::draw_line_segment_mut(&mut image, to_px(a.x, a.y), to_px(b.x, b.y), Rgb([0, 0, 0]));
    }
    // Furniture in brown, glass in cyan, crates in orange (pillars and
    // partitions are walls).
    for b in &layout.blocks {
        use crate::world::block::BlockKind;
        let colour = match b.kind {
            BlockKind::Glass => Rgb([0, 170, 200]),
            BlockKind::Crate => Rgb([230, 120, 0]),
            BlockKind::Table | BlockKind::Chair | BlockKind::Shelf => Rgb([120, 70, 30]),
            BlockKind::Pillar | BlockKind::Partition => continue,
        };
        let f = b.footprint();
        for i in 0..4 {
            let (p, q) = (f[i], f[(i + 1) % 4]);
            imageproc::drawing::draw_line_segment_mut(&mut image, to_px(p[0], p[1]), to_px(q[0], q[1]), colour);
        }
    }
    // The whole planned route in pink under the driven part in red.
    let planned = Route::new(&layout.route, 1.2);
    let steps = (planned.length() / 0.1).ceil() as usize;
    for k in 0..steps {
        let ((a, _), (b, _)) = (planned.at(k as f64 * 0.1), planned.at((k + 1) as f64 * 0.1));
        imageproc::drawing::draw_line_segment_mut(
            &mut image,
            to_px(a[0], a[1]),
            to_px(b[0], b[1]),
            Rgb([255, 160, 160]),
        );
    }
    for pair in sequence.frames.windows(2) {
        let (a, b) = (pair[0].world_from_robot.translation.vector, pair[1].world_from_robot.translation.vector);
        imageproc::drawing::draw_line_segment_mut(&mut image, to_px(a.x, a.y), to_px(b.x, b.y), Rgb([200, 0, 0]));
    }
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

#[cfg(test)]
mod tests {
    use super::*;

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
