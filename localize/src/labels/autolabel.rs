//! `localize autolabel`: corner labels for a recording's own images from its
//! own 3D sensor. The recording is localized without the detector while the
//! scans' 3D corners (three planes meeting) are followed in the world
//! (`corner_tracks`); those seen again and again at one place from along
//! the route are projected into every image at the camera's pose at that
//! image's time, and kept where they are in front, inside the image and not
//! hidden behind the mapped surfaces (`depth_buffer`). The images and
//! labels are written as a `train --data` folder (COCO, the box size of
//! `datagen`'s labels), with a report and pictures of the labels.

use std::collections::{BTreeMap, HashMap};
use std::path::Path;

use datasets::bbox::BBox;
use datasets::io::formats::{CocoAnnotation, CocoDataset, CocoImage, corner_categories};
use datasets::math::{Pose3, Vec3};
use datasets::simulator::world::labels::LabelConfig;
use image::DynamicImage;
use indicatif::{ProgressBar, ProgressStyle};
use serde::{Deserialize, Serialize};

use crate::error::Result;
use crate::estimation::point_map::MapPoint;
use crate::input::sequence::{SensorSequence, truth_at};
use crate::labels::corner_tracks::{CornerTrack, CornerTrackConfig};
use crate::labels::depth_buffer::DepthBuffer;
use crate::labels::map_corners::{MapCornerConfig, map_corners};
use crate::run::RunResult;

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct AutolabelConfig {
    /// Which scan corners count as the building's.
    pub tracks: CornerTrackConfig,
    /// Corners found in the run's point map besides them.
    pub map_corners: MapCornerConfig,
    /// Box size and farthest depth, as `datagen`'s labels.
    pub labels: LabelConfig,
    /// A corner is hidden when a mapped surface lies this much nearer on its
    /// ray (metres, plus `occlusion_fraction` of its depth): a corner's own
    /// surfaces lie at its depth, with the map's noise.
    pub occlusion_margin_m: f64,
    pub occlusion_fraction: f64,
    /// Image pixels per cell of the depth buffer, and the radius of the disc
    /// each map point covers (about the map's point spacing).
    pub depth_cell_px: u32,
    pub splat_m: f64,
    /// The last this fraction of the images (in time) goes to `test.json`.
    pub test_fraction: f64,
    /// A label within this many pixels of a true corner matches it (when the
    /// recording has true labels, as generated sequences do).
    pub match_radius_px: f64,
    /// Where a corner may be that the 3D sensor cannot confirm.
    pub unsure: UnsureConfig,
}

/// Places where the labels cannot say "no corner here", written as COCO
/// ignore regions (`iscrowd` 1): training neither teaches a corner nor
/// background there, and evaluation does not count detections there. Without
/// them every corner the 3D sensor misses would be taught as background.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct UnsureConfig {
    /// The teacher detector's detections at or above this score (when a
    /// teacher is given) that no label confirms.
    pub teacher_score: f32,
    /// The teacher's detections at or above this score that no label
    /// confirms become labels themselves (kind "teacher"): self-training,
    /// so that fine-tuning keeps what the teacher finds. None: never.
    pub teacher_label_score: Option<f32>,
    /// The point map's corners, when they are not labels themselves.
    pub map_corners: bool,
    /// Scan corners seen more than once that did not persist.
    pub passing_tracks: bool,
}

impl Default for UnsureConfig {
    fn default() -> Self {
        Self { teacher_score: 0.3, teacher_label_score: Some(0.7), map_corners: true, passing_tracks: true }
    }
}

impl Default for AutolabelConfig {
    fn default() -> Self {
        Self {
            tracks: CornerTrackConfig::default(),
            map_corners: MapCornerConfig::default(),
            labels: LabelConfig::default(),
            occlusion_margin_m: 0.3,
            occlusion_fraction: 0.05,
            depth_cell_px: 4,
            splat_m: 0.1,
            test_fraction: 0.2,
            match_radius_px: 10.0,
            unsure: UnsureConfig::default(),
        }
    }
}

impl AutolabelConfig {
    /// The defaults for a 3D sensor: a depth camera sees furniture-sized
    /// scenes, whose faces (a cabinet's) spread less than a building's walls.
    pub fn for_range(range: crate::input::sequence::RangeSensor) -> Self {
        let mut config = Self::default();
        if range == crate::input::sequence::RangeSensor::DepthCamera {
            config.tracks.min_plane_extent_m = 0.1;
        }
        config
    }

    /// `self` with a settings file's JSON over it, checked.
    pub fn overlaid(&self, file: &serde_json::Value) -> std::result::Result<Self, String> {
        let config = datasets::settings_file::overlay(self, file)?;
        config.validate().map_err(|e| e.to_string())?;
        Ok(config)
    }

    pub fn validate(&self) -> std::result::Result<(), datasets::InvalidSetting> {
        use datasets::InvalidSetting;
        self.tracks.validate().map_err(|e| e.within("tracks"))?;
        self.map_corners.validate().map_err(|e| e.within("map_corners"))?;
        self.labels.validate().map_err(|e| e.within("labels"))?;
        InvalidSetting::non_negative("occlusion_margin_m", self.occlusion_margin_m, 5.0)?;
        InvalidSetting::non_negative("occlusion_fraction", self.occlusion_fraction, 0.5)?;
        InvalidSetting::count("depth_cell_px", self.depth_cell_px as usize, 1, 64)?;
        InvalidSetting::range("splat_m", self.splat_m, 0.001, 2.0, false)?;
        InvalidSetting::non_negative("test_fraction", self.test_fraction, 0.9)?;
        InvalidSetting::range("match_radius_px", self.match_radius_px, 0.5, 200.0, false)?;
        InvalidSetting::range("teacher_score", f64::from(self.unsure.teacher_score), 0.0, 1.0, true)
            .map_err(|e| e.within("unsure"))?;
        if let Some(score) = self.unsure.teacher_label_score {
            InvalidSetting::range("teacher_label_score", f64::from(score), 0.0, 1.0, true)
                .map_err(|e| e.within("unsure"))?;
        }
        Ok(())
    }
}

/// A 3D corner to label, and the standard error of its position.
#[derive(Debug, Clone, PartialEq)]
pub struct LabelCorner {
    pub position: Vec3,
    pub sigma_m: f64,
}

/// The 3D corners of a run, sure and unsure.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct RunCorners {
    /// To label: the scans' persistent corners, then (when enabled) the
    /// point map's corners farther than the tracks' gate from all of them.
    pub labels: Vec<LabelCorner>,
    /// How many of `labels` came from the point map.
    pub from_map: usize,
    /// Maybe corners (`UnsureConfig`), each farther than the gate from every label.
    pub unsure: Vec<LabelCorner>,
}

pub fn label_corners(run: &RunResult, config: &AutolabelConfig) -> RunCorners {
    let of_track =
        |t: &CornerTrack| LabelCorner { position: t.position, sigma_m: t.spread_m / (t.scans as f64).sqrt() };
    let tracks: Vec<CornerTrack> = run.corner_tracks.as_ref().map(|t| t.persistent()).unwrap_or_default();
    let mut out = RunCorners { labels: tracks.iter().map(of_track).collect(), ..Default::default() };
    let apart =
        |corners: &[LabelCorner], p: &Vec3| corners.iter().all(|k| (k.position - p).norm() > config.tracks.gate_m);
    let from_map = if config.map_corners.enabled || config.unsure.map_corners {
        map_corners(&run.point_map, &config.map_corners)
    } else {
        Vec::new()
    };
    for c in from_map {
        if !apart(&out.labels, &c.position) {
            continue;
        }
        let corner = LabelCorner { position: c.position, sigma_m: c.sigma_m };
        if config.map_corners.enabled {
            out.labels.push(corner);
            out.from_map += 1;
        } else {
            out.unsure.push(corner);
        }
    }
    if config.unsure.passing_tracks {
        let passing = run.corner_tracks.as_ref().map(|t| t.passing()).unwrap_or_default();
        for t in &passing {
            if apart(&out.labels, &t.position) {
                out.unsure.push(of_track(t));
            }
        }
    }
    out
}

/// One corner projected into one image.
#[derive(Debug, Clone, PartialEq)]
pub struct AutoLabel {
    /// Index into the corners labelled.
    pub corner: usize,
    pub point: [f64; 2],
    pub bbox: BBox,
    pub depth_m: f64,
    /// The standard error of the corner's position seen from here:
    /// focal length x sigma / depth.
    pub expected_error_px: f64,
}

/// What became of the persistent corners in one image.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ImageLabels {
    pub labels: Vec<AutoLabel>,
    /// In front, inside the image and in range, but behind a mapped surface.
    pub hidden: usize,
    /// Centres of ignore regions: unsure corners seen from here, and the
    /// teacher's detections that no label confirms.
    pub unsure: Vec<[f64; 2]>,
    /// The teacher's confident detections that no label confirms, taken as
    /// labels (`UnsureConfig::teacher_label_score`).
    pub teacher: Vec<[f64; 2]>,
}

/// The corners that `camera` sees at `world_from_camera`, and the boxes of
/// the unsure corners it sees farther than the match radius from every label.
pub fn label_image(
    corners: &RunCorners,
    depth: Option<&DepthBuffer>,
    camera: &datasets::camera::PinholeCamera,
    world_from_camera: &Pose3,
    config: &AutolabelConfig,
) -> ImageLabels {
    let camera_from_world = world_from_camera.inverse();
    let max_depth = config.labels.max_depth_m;
    let focal = 0.5 * (camera.fx + camera.fy);
    let mut out = ImageLabels::default();
    // Where a corner appears: `Err(true)` when a mapped surface hides it.
    let project = |t: &LabelCorner| -> std::result::Result<([f64; 2], f64), bool> {
        let p = camera_from_world * nalgebra::Point3::from(t.position);
        if p.z < 0.2 || p.z > max_depth {
            return Err(false);
        }
        let uv = camera.project(&p).filter(|&uv| camera.contains(uv)).ok_or(false)?;
        let margin = config.occlusion_margin_m + config.occlusion_fraction * p.z;
        if depth.is_some_and(|d| d.at(uv) < p.z - margin) {
            return Err(true);
        }
        Ok((uv, p.z))
    };
    for (corner, t) in corners.labels.iter().enumerate() {
        match project(t) {
            Ok((uv, depth_m)) => {
                let bbox = label_box(uv, camera, config);
                let expected_error_px = focal * t.sigma_m / depth_m;
                out.labels.push(AutoLabel { corner, point: uv, bbox, depth_m, expected_error_px });
            }
            Err(hidden) => out.hidden += usize::from(hidden),
        }
    }
    for t in &corners.unsure {
        if let Ok((uv, _)) = project(t) {
            out.add_unsure(uv, config);
        }
    }
    out
}

/// The map's surfaces seen from `world_from_camera` (None without a point map).
pub fn render_depth(
    points: &[MapPoint],
    camera: &datasets::camera::PinholeCamera,
    world_from_camera: &Pose3,
    config: &AutolabelConfig,
) -> Option<DepthBuffer> {
    let camera_from_world = world_from_camera.inverse();
    let max_depth = config.labels.max_depth_m;
    (!points.is_empty()).then(|| {
        DepthBuffer::render(points, camera, &camera_from_world, config.depth_cell_px, config.splat_m, max_depth)
    })
}

/// A label's box: `datagen`'s size around the point, clipped to the image.
fn label_box(uv: [f64; 2], camera: &datasets::camera::PinholeCamera, config: &AutolabelConfig) -> BBox {
    let size = config.labels.box_size_px;
    BBox::around(uv[0] as f32, uv[1] as f32, size).clip(camera.width as f32, camera.height as f32)
}

impl ImageLabels {
    fn labelled_near(&self, uv: [f64; 2], radius: f64) -> bool {
        let near = |p: &[f64; 2]| (p[0] - uv[0]).hypot(p[1] - uv[1]) <= radius;
        self.labels.iter().any(|l| near(&l.point)) || self.teacher.iter().any(near)
    }

    /// Adds an ignore region at `uv` unless a label lies within the match radius.
    pub fn add_unsure(&mut self, uv: [f64; 2], config: &AutolabelConfig) {
        if !self.labelled_near(uv, config.match_radius_px) {
            self.unsure.push(uv);
        }
    }

    /// Adds a teacher's label at `uv` unless a label lies within the match
    /// radius; an ignore region there gives way to it.
    pub fn add_teacher(&mut self, uv: [f64; 2], config: &AutolabelConfig) {
        if !self.labelled_near(uv, config.match_radius_px) {
            self.unsure.retain(|p| (p[0] - uv[0]).hypot(p[1] - uv[1]) > config.match_radius_px);
            self.teacher.push(uv);
        }
    }
}

/// Labels against true labels, matched one to one within a pixel radius.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct LabelScore {
    pub images: usize,
    pub labels: usize,
    pub true_labels: usize,
    pub matched: usize,
    pub precision: f64,
    pub recall: f64,
    pub radius_px: f64,
    /// Median distance between a matched label and its true corner.
    pub median_error_px: f64,
}

/// Greedy one-to-one matching, nearest pairs first.
pub fn match_points(ours: &[[f64; 2]], truth: &[[f64; 2]], radius: f64) -> Vec<f64> {
    let mut pairs: Vec<(f64, usize, usize)> = Vec::new();
    for (i, a) in ours.iter().enumerate() {
        for (j, b) in truth.iter().enumerate() {
            let d = (a[0] - b[0]).hypot(a[1] - b[1]);
            if d <= radius {
                pairs.push((d, i, j));
            }
        }
    }
    pairs.sort_by(|a, b| a.0.total_cmp(&b.0));
    let (mut used_a, mut used_b) = (vec![false; ours.len()], vec![false; truth.len()]);
    let mut distances = Vec::new();
    for (d, i, j) in pairs {
        if !used_a[i] && !used_b[j] {
            used_a[i] = true;
            used_b[j] = true;
            distances.push(d);
        }
    }
    distances
}

/// Scores the labels of each image (by name) against the true labels of
/// the images of the same name in `truth`; images without true labels are
/// left out.
pub fn score_labels(labelled: &[(String, Vec<[f64; 2]>)], truth: &CocoDataset, radius: f64) -> LabelScore {
    let stem = |f: &str| Path::new(f).file_stem().and_then(|s| s.to_str()).unwrap_or_default().to_string();
    let ids: HashMap<String, u64> = truth.images.iter().map(|i| (stem(&i.file_name), i.id)).collect();
    let mut points: HashMap<u64, Vec<[f64; 2]>> = HashMap::new();
    for a in &truth.annotations {
        let p = a.point.map_or([a.bbox[0] + a.bbox[2] / 2.0, a.bbox[1] + a.bbox[3] / 2.0], |p| p);
        points.entry(a.image_id).or_default().push([f64::from(p[0]), f64::from(p[1])]);
    }
    let mut score = LabelScore { radius_px: radius, ..Default::default() };
    let mut distances = Vec::new();
    for (name, ours) in labelled {
        let Some(id) = ids.get(name) else { continue };
        let theirs = points.get(id).map_or(&[][..], Vec::as_slice);
        score.images += 1;
        score.labels += ours.len();
        score.true_labels += theirs.len();
        distances.extend(match_points(ours, theirs, radius));
    }
    score.matched = distances.len();
    score.precision = if score.labels > 0 { score.matched as f64 / score.labels as f64 } else { 0.0 };
    score.recall = if score.true_labels > 0 { score.matched as f64 / score.true_labels as f64 } else { 0.0 };
    distances.sort_by(f64::total_cmp);
    score.median_error_px = distances.get(distances.len() / 2).copied().unwrap_or(f64::NAN);
    score
}

/// Summary numbers: mean, median, smallest and largest.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct Spread {
    pub mean: f64,
    pub median: f64,
    pub p90: f64,
    pub min: f64,
    pub max: f64,
}

impl Spread {
    pub fn of(values: &[f64]) -> Self {
        if values.is_empty() {
            return Self::default();
        }
        let mut v = values.to_vec();
        v.sort_by(f64::total_cmp);
        let at = |q: f64| v[((v.len() - 1) as f64 * q).round() as usize];
        Self { mean: v.iter().sum::<f64>() / v.len() as f64, median: at(0.5), p90: at(0.9), min: v[0], max: at(1.0) }
    }
}

/// `autolabel.json`.
#[derive(Debug, Clone, Serialize)]
pub struct AutolabelReport {
    pub images: usize,
    pub train_images: usize,
    pub test_images: usize,
    pub labels: usize,
    pub labels_per_image: Spread,
    /// Corners of the scans followed over the run, those kept, and the
    /// corners of the point map added to them.
    pub tracks: usize,
    pub persistent_corners: usize,
    pub map_corners: usize,
    /// 3D corners that may be corners (`UnsureConfig`), and the ignore
    /// regions written (theirs and the teacher's unconfirmed detections).
    pub unsure_corners: usize,
    pub ignore_regions: usize,
    /// The teacher's detections taken as labels (`teacher_label_score`).
    pub teacher_labels: usize,
    /// Whether a teacher detector marked ignore regions.
    pub teacher: bool,
    /// Labels left out because a mapped surface hid them.
    pub hidden: usize,
    /// Whether hidden corners could be found (the run kept a point map).
    pub occlusion_checked: bool,
    /// Focal length x the standard error of the corner's position over the
    /// scans / its depth, per label.
    pub expected_error_px: Spread,
    /// Against the recording's true labels, when it has them: within
    /// `match_radius_px`, and within twice that (a label a few pixels
    /// farther still frames the corner in its 96 px box).
    pub against_truth: Vec<LabelScore>,
    pub config: AutolabelConfig,
}

impl AutolabelReport {
    /// What `localize autolabel` prints: labels, corners, ignore regions,
    /// expected error, and the scores against true labels when there are some.
    pub fn summary(&self) -> String {
        use std::fmt::Write as _;
        let report = self;
        let mut out = String::new();
        let _ = writeln!(
            out,
            "{} images ({} train, {} test), {} labels: {:.1} per image (median {}, {} to {}); {} persistent corners of {} \
             followed over the scans and {} more in the map, {} labels hidden by the map{}",
            report.images,
            report.train_images,
            report.test_images,
            report.labels,
            report.labels_per_image.mean,
            report.labels_per_image.median,
            report.labels_per_image.min,
            report.labels_per_image.max,
            report.persistent_corners,
            report.tracks,
            report.map_corners,
            report.hidden,
            if report.occlusion_checked { "" } else { " (no point map: occlusion not checked)" }
        );
        let _ = writeln!(
            out,
            "{} ignore regions where the 3D sensor cannot tell ({} unsure 3D corners{}), {} teacher labels",
            report.ignore_regions,
            report.unsure_corners,
            if report.teacher { " and the teacher's unconfirmed detections" } else { "; no teacher" },
            report.teacher_labels
        );
        let _ = writeln!(
            out,
            "expected pixel error (standard error of each corner's position, projected): median {:.2} px, 90% below {:.2} px",
            report.expected_error_px.median, report.expected_error_px.p90
        );
        for s in &report.against_truth {
            let _ = writeln!(
                out,
                "against the true labels ({} images, within {} px): precision {:.3}, recall {:.3} ({} of {} labels, {} true; \
                 median error {:.2} px)",
                s.images, s.radius_px, s.precision, s.recall, s.matched, s.labels, s.true_labels, s.median_error_px
            );
        }

        out
    }
}

/// One labelled image.
pub struct LabelledImage {
    pub name: String,
    pub stamp: f64,
    pub image: DynamicImage,
    pub labels: ImageLabels,
}

/// Labels every image of `sequence` whose time the run's trajectory covers
/// (reading the recording a second time: the run left the images alone).
pub fn label_sequence(
    sequence: &dyn SensorSequence,
    run: &RunResult,
    corners: &RunCorners,
    teacher: Option<&infer::detector::Detector>,
    config: &AutolabelConfig,
    show_progress: bool,
    mut keep: impl FnMut(LabelledImage) -> Result<()>,
) -> Result<()> {
    let calibration = sequence.calibration();
    let robot_from_camera = calibration.robot_from_camera();
    let trajectory = &run.trajectory;
    let (Some(&first), Some(&last)) = (trajectory.stamps.first(), trajectory.stamps.last()) else {
        return Ok(());
    };
    let bar = if show_progress { ProgressBar::new(trajectory.len() as u64) } else { ProgressBar::hidden() };
    bar.set_style(
        ProgressStyle::with_template("{prefix} [{elapsed_precise}] {bar:30} {pos}/{len} frames").expect("static"),
    );
    bar.set_prefix("autolabel");
    let mut seen = std::collections::HashSet::new();
    // Images within half a scan period of the trajectory's ends still take its end poses.
    let slack = if trajectory.len() > 1 { (last - first) / (trajectory.len() - 1) as f64 / 2.0 } else { 0.0 };
    sequence.for_each_frame(&mut |frame| {
        bar.inc(1);
        let Ok(image) = frame.image else { return Ok(()) };
        let Ok(pixels) = image.image else { return Ok(()) };
        if image.stamp < first - slack || image.stamp > last + slack || !seen.insert(image.name.clone()) {
            return Ok(());
        }
        let world_from_camera = truth_at(trajectory, image.stamp) * robot_from_camera;
        let camera = &calibration.camera;
        let depth = render_depth(&run.point_map, camera, &world_from_camera, config);
        let mut labels = label_image(corners, depth.as_ref(), camera, &world_from_camera, config);
        for d in teacher.map(|t| t.detect(&pixels)).unwrap_or_default() {
            let [x, y] = d.bbox.centre();
            let uv = [f64::from(x), f64::from(y)];
            if config.unsure.teacher_label_score.is_some_and(|s| d.score >= s) {
                labels.add_teacher(uv, config);
            } else if d.score >= config.unsure.teacher_score {
                labels.add_unsure(uv, config);
            }
        }
        keep(LabelledImage { name: image.name, stamp: image.stamp, image: pixels, labels })
    })?;
    bar.finish_and_clear();
    Ok(())
}

/// COCO annotations of one image's labels, then its ignore regions.
pub fn annotations(labels: &ImageLabels, image: &CocoImage, box_size: f32, next_id: &mut u64) -> Vec<CocoAnnotation> {
    let (image_id, width, height) = (image.id, image.width as f32, image.height as f32);
    let mut out = Vec::new();
    for l in &labels.labels {
        *next_id += 1;
        out.push(CocoAnnotation::corner(*next_id, image_id, &l.bbox, l.point, None));
    }
    let around = |p: &[f64; 2]| BBox::around(p[0] as f32, p[1] as f32, box_size).clip(width, height);
    for p in &labels.teacher {
        *next_id += 1;
        out.push(CocoAnnotation::corner(*next_id, image_id, &around(p), *p, Some("teacher")));
    }
    for p in &labels.unsure {
        *next_id += 1;
        out.push(CocoAnnotation::ignore_region(*next_id, image_id, &around(p)));
    }
    out
}

/// The train and test splits of the labelled images, in time order: the
/// last `test_fraction` of them is the test split.
pub fn splits(entries: &[(CocoImage, ImageLabels)], test_fraction: f64, box_size: f32) -> (CocoDataset, CocoDataset) {
    let n = entries.len();
    let test = ((n as f64 * test_fraction).round() as usize).min(n.saturating_sub(1));
    let mut sets = [
        CocoDataset { categories: corner_categories(), ..Default::default() },
        CocoDataset { categories: corner_categories(), ..Default::default() },
    ];
    let mut next_id = 0;
    for (k, (image, labels)) in entries.iter().enumerate() {
        let set = &mut sets[usize::from(k >= n - test)];
        set.annotations.extend(annotations(labels, image, box_size, &mut next_id));
        set.images.push(image.clone());
    }
    let [train, test] = sets;
    (train, test)
}

/// The labels drawn on the image: boxes and centres in green (the
/// teacher's in blue), ignore regions in orange.
pub fn draw(image: &DynamicImage, labels: &ImageLabels, box_size: f32) -> image::RgbImage {
    let mut out = image.to_rgb8();
    let rect = |b: &BBox| {
        imageproc::rect::Rect::at(b.x1 as i32, b.y1 as i32)
            .of_size(b.width().max(1.0) as u32, b.height().max(1.0) as u32)
    };
    for p in &labels.unsure {
        let b = BBox::around(p[0] as f32, p[1] as f32, box_size);
        imageproc::drawing::draw_hollow_rect_mut(&mut out, rect(&b), image::Rgb([250, 150, 30]));
    }
    let colour = image::Rgb([40, 220, 60]);
    for l in &labels.labels {
        imageproc::drawing::draw_hollow_rect_mut(&mut out, rect(&l.bbox), colour);
        imageproc::drawing::draw_filled_circle_mut(&mut out, (l.point[0] as i32, l.point[1] as i32), 3, colour);
    }
    for p in &labels.teacher {
        let b = BBox::around(p[0] as f32, p[1] as f32, box_size);
        imageproc::drawing::draw_hollow_rect_mut(&mut out, rect(&b), image::Rgb([40, 120, 250]));
        imageproc::drawing::draw_filled_circle_mut(&mut out, (p[0] as i32, p[1] as i32), 3, image::Rgb([40, 120, 250]));
    }
    out
}

/// Writes the `train --data` folder `out`: `images/`, `train.json`,
/// `test.json`, `points/` (each image's 3D labels as a point CSV, for
/// `infer eval-points`), `autolabel.json`, `preview/` (a few images with
/// their labels drawn) and `corners.ply` (the persistent corners); returns
/// the report.
pub fn write_autolabels(
    out: &Path,
    sequence: &dyn SensorSequence,
    run: &RunResult,
    teacher: Option<&infer::detector::Detector>,
    config: &AutolabelConfig,
    truth: Option<&CocoDataset>,
    show_progress: bool,
) -> Result<AutolabelReport> {
    config.validate().map_err(|e| e.within("autolabel"))?;
    let corners = label_corners(run, config);
    let camera = &sequence.calibration().camera;
    let mut report = None;
    datasets::atomic::write_dir(out, |dir| -> Result<()> {
        let mut entries: Vec<(CocoImage, ImageLabels)> = Vec::new();
        let mut hidden = 0;
        let mut previews: BTreeMap<usize, (String, DynamicImage)> = BTreeMap::new();
        label_sequence(sequence, run, &corners, teacher, config, show_progress, |l| {
            let file_name = format!("images/{}.png", l.name);
            datasets::atomic::write_image(&dir.join(&file_name), &l.image)?;
            let points: Vec<[f64; 2]> = l.labels.labels.iter().map(|a| a.point).collect();
            datasets::io::formats::write_point_labels(&dir.join(format!("points/{}.csv", l.name)), &points)?;
            hidden += l.labels.hidden;
            let id = entries.len() as u64 + 1;
            // Every 25th image is kept for the pictures (at most 8 of them, spread over the run below).
            if entries.len().is_multiple_of(25) {
                previews.insert(
                    entries.len(),
                    (l.name.clone(), DynamicImage::ImageRgb8(draw(&l.image, &l.labels, config.labels.box_size_px))),
                );
            }
            entries.push((CocoImage { id, file_name, width: camera.width, height: camera.height }, l.labels));
            Ok(())
        })?;
        if entries.is_empty() {
            return Err(crate::error::LocalizeError::Recording(
                "no image of the recording falls within the localized scans' times: nothing to label".into(),
            ));
        }
        let (train, test) = splits(&entries, config.test_fraction, config.labels.box_size_px);
        datasets::io::formats::write_coco(&dir.join("train.json"), &train)?;
        datasets::io::formats::write_coco(&dir.join("test.json"), &test)?;
        let step = previews.len().div_ceil(8).max(1);
        for (name, picture) in previews.values().step_by(step) {
            datasets::atomic::write_image(&dir.join("preview").join(format!("{name}.png")), picture)?;
        }
        datasets::atomic::write_bytes(&dir.join("corners.ply"), &corners_ply(&corners.labels))?;
        let counts: Vec<f64> = entries.iter().map(|(_, l)| l.labels.len() as f64).collect();
        let errors: Vec<f64> = entries.iter().flat_map(|(_, l)| l.labels.iter().map(|a| a.expected_error_px)).collect();
        let against_truth = truth.map_or_else(Vec::new, |truth| scores_at_two_radii(&entries, truth, config));
        let r = AutolabelReport {
            images: entries.len(),
            train_images: train.images.len(),
            test_images: test.images.len(),
            labels: errors.len(),
            labels_per_image: Spread::of(&counts),
            tracks: run.corner_tracks.as_ref().map_or(0, |t| t.tracks.len()),
            persistent_corners: corners.labels.len() - corners.from_map,
            map_corners: corners.from_map,
            unsure_corners: corners.unsure.len(),
            ignore_regions: entries.iter().map(|(_, l)| l.unsure.len()).sum(),
            teacher_labels: entries.iter().map(|(_, l)| l.teacher.len()).sum(),
            teacher: teacher.is_some(),
            hidden,
            occlusion_checked: !run.point_map.is_empty(),
            expected_error_px: Spread::of(&errors),
            against_truth,
            config: config.clone(),
        };
        datasets::atomic::write_json(&dir.join("autolabel.json"), &r)?;
        report = Some(r);
        Ok(())
    })?;
    Ok(report.expect("written"))
}

/// The 3D labels scored against true labels within the match radius and
/// twice it (a label a few pixels farther still frames its corner).
fn scores_at_two_radii(
    entries: &[(CocoImage, ImageLabels)],
    truth: &CocoDataset,
    config: &AutolabelConfig,
) -> Vec<LabelScore> {
    let labelled: Vec<(String, Vec<[f64; 2]>)> = entries
        .iter()
        .map(|(image, labels)| {
            let name = Path::new(&image.file_name).file_stem().and_then(|s| s.to_str()).unwrap_or_default();
            (name.to_string(), labels.labels.iter().map(|l| l.point).collect())
        })
        .collect();
    [1.0, 2.0].map(|k| score_labels(&labelled, truth, k * config.match_radius_px)).to_vec()
}

/// Refuses an output folder that holds anything but an earlier
/// `autolabel`'s output (which is replaced whole), before the work.
pub fn check_output_folder(out: &Path) -> Result<()> {
    let Some(mut entries) = crate::run::writable_output_folder(out)? else { return Ok(()) };
    if entries.next().is_some() && !out.join("autolabel.json").is_file() {
        return Err(datasets::DataError::invalid(
            out,
            "holds files that are not an earlier autolabel's output: give an empty or new folder",
        )
        .into());
    }
    Ok(())
}

/// Localizes `sequence` without the detector, following its scans' corners,
/// and writes the labels of its images into `out` (`write_autolabels`); the
/// run itself goes to `out/run` (trajectory, map, and metrics with ground truth).
pub fn autolabel(
    out: &Path,
    sequence: &dyn SensorSequence,
    localize: &crate::config::LocalizeConfig,
    teacher: Option<&infer::detector::Detector>,
    config: &AutolabelConfig,
    truth: Option<&CocoDataset>,
    show_progress: bool,
) -> Result<(AutolabelReport, RunResult)> {
    config.validate().map_err(|e| e.within("autolabel"))?;
    check_output_folder(out)?;
    // The detector is left out; the image's edges lifted through a depth
    // image (RGB-D) still hold the registration, as in `localize run`.
    let options = crate::run::RunOptions {
        show_progress,
        track_corners: Some(config.tracks.clone()),
        keep_image_edges: true,
        map: None,
    };
    let run = crate::run::run_with(sequence, &mut crate::input::corner_source::CornerSource::Off, localize, options)?;
    let report = write_autolabels(out, sequence, &run, teacher, config, truth, show_progress)?;
    let truth_trajectory = crate::run::truth_in_run_frame(sequence, &run);
    let metrics = crate::run::metrics_against(sequence, &run, truth_trajectory.as_ref())?;
    crate::run::write_outputs(&out.join("run"), localize, &run, truth_trajectory.as_ref(), metrics.as_ref())?;
    Ok((report, run))
}

/// The persistent corners as a PLY point cloud (red), for a viewer beside the run's map.ply.
fn corners_ply(corners: &[LabelCorner]) -> Vec<u8> {
    let mut out = format!(
        "ply\nformat ascii 1.0\ncomment corner-fusion autolabel: persistent 3D corners\nelement vertex {}\n\
         property float x\nproperty float y\nproperty float z\nproperty uchar red\nproperty uchar green\n\
         property uchar blue\nend_header\n",
        corners.len()
    );
    for t in corners {
        out.push_str(&format!("{} {} {} 230 30 30\n", t.position.x as f32, t.position.y as f32, t.position.z as f32));
    }
    out.into_bytes()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::labels::corner_tracks::{CornerTrackConfig, CornerTracks};

    fn camera() -> datasets::camera::PinholeCamera {
        datasets::camera::PinholeCamera { width: 640, height: 480, fx: 500.0, fy: 500.0, cx: 319.5, cy: 239.5 }
    }

    /// Tracks of the given world points, each seen 6 times along 1 m of route.
    fn tracks_of(points: &[Vec3]) -> Vec<LabelCorner> {
        let mut tracks = CornerTracks::new(CornerTrackConfig::default());
        for k in 0..6 {
            let pose =
                Pose3::from_parts(Vec3::new(0.2 * k as f64, 0.0, 0.0).into(), nalgebra::UnitQuaternion::identity());
            let in_robot: Vec<Vec3> =
                points.iter().map(|p| (pose.inverse() * nalgebra::Point3::from(*p)).coords).collect();
            tracks.observe(k as f64, &pose, &in_robot);
        }
        tracks.persistent().iter().map(|t| LabelCorner { position: t.position, sigma_m: 0.0 }).collect()
    }

    #[test]
    fn corners_project_where_the_camera_sees_them_and_a_wall_hides_the_one_behind_it() {
        // Camera at the origin looking along +z. A corner 4 m ahead, 1 m right
        // and 0.5 m down; one straight ahead at 6 m behind a wall at 3 m; one
        // behind the camera; one outside the image.
        let points =
            [Vec3::new(1.0, 0.5, 4.0), Vec3::new(0.0, 0.0, 6.0), Vec3::new(0.0, 0.0, -3.0), Vec3::new(20.0, 0.0, 4.0)];
        let labels = tracks_of(&points);
        assert_eq!(labels.len(), 4);
        // Unsure corners: one on the wall 2 m left of the axis, one 1 cm from the
        // visible label (it is the label's), one behind the wall.
        let unsure = [Vec3::new(-1.0, 0.0, 2.99), Vec3::new(1.0, 0.51, 4.0), Vec3::new(0.5, 0.0, 6.0)]
            .map(|position| LabelCorner { position, sigma_m: 0.0 })
            .to_vec();
        let corners = RunCorners { labels, from_map: 0, unsure };
        let wall: Vec<MapPoint> = (-10..=10)
            .flat_map(|i| (-10..=10).map(move |j| (i, j)))
            .map(|(i, j)| MapPoint { position: Vec3::new(0.05 * i as f64, 0.05 * j as f64, 3.0), normal: -Vec3::z() })
            .collect();
        let config = AutolabelConfig::default();
        let depth = render_depth(&wall, &camera(), &Pose3::identity(), &config);
        let seen = label_image(&corners, depth.as_ref(), &camera(), &Pose3::identity(), &config);
        assert_eq!(seen.labels.len(), 1, "{seen:?}");
        assert_eq!(seen.hidden, 1);
        let l = &seen.labels[0];
        // f x / z = 125 px and f y / z = 62.5 px from the centre, in the camera's
        // pixel-corner convention (the centre of pixel 0 at 0.5).
        assert!((l.point[0] - 445.0).abs() < 1e-9 && (l.point[1] - 302.5).abs() < 1e-9, "{l:?}");
        assert!((l.depth_m - 4.0).abs() < 1e-12);
        assert_eq!(l.bbox.width(), 96.0);
        // The wall's corner at u = 320 - 500 / 2.99 px is the one ignore region.
        assert_eq!(seen.unsure.len(), 1, "{:?}", seen.unsure);
        assert!((seen.unsure[0][0] - (320.0 - 500.0 / 2.99)).abs() < 1e-9, "{:?}", seen.unsure);
        // Without a point map nothing is hidden.
        assert!(render_depth(&[], &camera(), &Pose3::identity(), &config).is_none());
        let unmapped = label_image(&corners, None, &camera(), &Pose3::identity(), &config);
        assert_eq!((unmapped.labels.len(), unmapped.hidden, unmapped.unsure.len()), (2, 0, 2));
    }

    #[test]
    fn ignore_regions_are_written_as_crowd_annotations_after_the_labels() {
        let mut labels = ImageLabels::default();
        let bbox = BBox::around(100.0, 100.0, 96.0);
        labels.labels.push(AutoLabel { corner: 0, point: [100.0, 100.0], bbox, depth_m: 3.0, expected_error_px: 1.0 });
        let config = AutolabelConfig::default();
        labels.add_unsure([105.0, 100.0], &config);
        labels.add_unsure([300.0, 200.0], &config);
        labels.add_unsure([600.0, 20.0], &config);
        assert_eq!(labels.unsure.len(), 2, "a teacher's detection 5 px from a label confirms it");
        // A teacher's label takes the place of an ignore region beside it.
        labels.add_teacher([603.0, 24.0], &config);
        assert_eq!((labels.unsure.len(), labels.teacher.len()), (1, 1));
        let mut next = 0;
        let image = CocoImage { id: 4, file_name: "images/a.png".into(), width: 640, height: 480 };
        let coco = annotations(&labels, &image, 96.0, &mut next);
        let kinds: Vec<_> = coco.iter().map(|a| (a.id, a.iscrowd, a.corner_type.as_deref())).collect();
        assert_eq!(kinds, [(1, 0, None), (2, 0, Some("teacher")), (3, 1, None)]);
        // The teacher's box is clipped at the image's right edge.
        assert_eq!(coco[1].bbox, [555.0, 0.0, 85.0, 72.0]);
        assert_eq!(coco[2].bbox, [252.0, 152.0, 96.0, 96.0]);
        assert_eq!(coco[2].point, None);
    }

    #[test]
    fn matching_is_one_to_one_nearest_first_within_the_radius() {
        let ours = [[100.0, 100.0], [104.0, 100.0], [300.0, 300.0]];
        let truth = [[103.0, 100.0], [200.0, 200.0]];
        // (104,100) is nearest to the one true corner; (100,100) then has none within 10 px.
        let d = match_points(&ours, &truth, 10.0);
        assert_eq!(d, vec![1.0]);
        let mut set = CocoDataset::default();
        set.images.push(CocoImage { id: 7, file_name: "rgb/a.png".into(), width: 640, height: 480 });
        for (k, p) in truth.iter().enumerate() {
            set.annotations.push(CocoAnnotation {
                id: k as u64 + 1,
                image_id: 7,
                category_id: 1,
                bbox: [0.0, 0.0, 1.0, 1.0],
                area: 1.0,
                iscrowd: 0,
                corner_type: None,
                point: Some([p[0] as f32, p[1] as f32]),
            });
        }
        let labelled = vec![("a".to_string(), ours.to_vec()), ("unknown".to_string(), vec![[1.0, 1.0]])];
        let s = score_labels(&labelled, &set, 10.0);
        assert_eq!((s.images, s.labels, s.true_labels, s.matched), (1, 3, 2, 1));
        assert!((s.precision - 1.0 / 3.0).abs() < 1e-12 && (s.recall - 0.5).abs() < 1e-12);
        assert_eq!(s.median_error_px, 1.0);
    }

    #[test]
    fn the_test_split_is_the_end_of_the_run() {
        let entries: Vec<(CocoImage, ImageLabels)> = (1..=10)
            .map(|id| {
                (CocoImage { id, file_name: format!("images/{id}.png"), width: 10, height: 10 }, ImageLabels::default())
            })
            .collect();
        let (train, test) = splits(&entries, 0.2, 96.0);
        assert_eq!(train.images.iter().map(|i| i.id).collect::<Vec<_>>(), (1..=8).collect::<Vec<_>>());
        assert_eq!(test.images.iter().map(|i| i.id).collect::<Vec<_>>(), vec![9, 10]);
        // One image stays in training whatever the fraction.
        let (train, test) = splits(&entries[..1], 0.9, 96.0);
        assert_eq!((train.images.len(), test.images.len()), (1, 0));
    }
}
