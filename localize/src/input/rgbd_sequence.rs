//! RGB-D recordings as sensor sequences: each depth image is a scan (its
//! pixels through the depth camera's intrinsics) and its colour image the
//! detector's input. Two folder layouts are read as they are published:
//!
//! - TUM RGB-D: `rgb.txt` and `depth.txt` ("timestamp filename" lines),
//!   optional `groundtruth.txt` (TUM trajectory of the colour camera);
//!   depth registered to colour, 5000 units a metre. Intrinsics from a
//!   `calib.json` (this project's), else an ORB-SLAM style `*.yaml`
//!   (`Camera.fx` ..., `DepthMapFactor`), else the freiburg1/2/3 camera the
//!   folder's name says.
//! - 7-Scenes: `frame-NNNNNN.depth.png` (millimetres), `.color.png|jpg` and
//!   `.pose.txt` (4 x 4 camera-to-world), in the folder or its `frames/`;
//!   intrinsics from `camera-intrinsics.txt` (3 x 3 K), else 7-Scenes' own.
//!   There are no stamps: frame N was taken at N / 30 s.
//!
//! The robot frame is the depth camera's body frame (x forward, y left, z
//! up), the "LIDAR" is the depth camera there, and the ground truth is put
//! in that frame, so that a run's trajectory and the truth compare as they are.

use std::path::{Path, PathBuf};

use datasets::camera::PinholeCamera;
use datasets::io::formats::{
    Calibration, DepthImage, ImuSample, OdometrySample, PointCloud, Trajectory, read_depth_png, read_tum,
};
use datasets::math::{Pose3, Rot3};
use nalgebra::{Matrix3, Point3};
use serde::{Deserialize, Serialize};

use crate::error::{LocalizeError, Result};
use crate::input::frame_fault::FrameFault;
use crate::input::sequence::RangeSensor;
use crate::input::sequence::{FrameImage, FrameInput, SensorSequence, nearest_within};
use crate::scan::image_edges::{EdgeOptions, edge_points};

/// How a depth image becomes a scan.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DepthOptions {
    /// Every `stride`-th pixel of every `stride`-th row becomes a point.
    pub stride: usize,
    /// Readings nearer or farther than these (metres) are left out: a
    /// Kinect's depth error grows with the square of the range.
    pub near_m: f32,
    pub far_m: f32,
    /// The colour image's edges lifted through the depth, where the two are
    /// registered (TUM's layout).
    pub edges: EdgeOptions,
}

impl Default for DepthOptions {
    fn default() -> Self {
        Self { stride: 4, near_m: 0.2, far_m: 4.0, edges: EdgeOptions::default() }
    }
}

impl DepthOptions {
    pub fn validate(&self) -> std::result::Result<(), datasets::InvalidSetting> {
        datasets::InvalidSetting::count("stride", self.stride, 1, 64)?;
        if !(self.near_m >= 0.0 && self.far_m > self.near_m && self.far_m <= 100.0) {
            return Err(datasets::InvalidSetting::between(format!(
                "depth range {} to {} m: need 0 <= near < far <= 100",
                self.near_m, self.far_m
            )));
        }
        self.edges.validate().map_err(|e| e.within("edges"))?;
        Ok(())
    }
}

/// Which published layout a folder has.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RgbdLayout {
    Tum,
    SevenScenes,
}

struct RgbdFrame {
    stamp: f64,
    depth: PathBuf,
    image: Option<(f64, PathBuf)>,
}

pub struct RgbdSequence {
    pub dir: PathBuf,
    pub layout: RgbdLayout,
    frames: Vec<RgbdFrame>,
    calibration: Calibration,
    /// The depth camera's intrinsics (the colour camera's in `calibration`).
    depth_camera: PinholeCamera,
    units_per_metre: f64,
    options: DepthOptions,
    ground_truth: Option<Trajectory>,
    image_tolerance_s: f64,
}

fn error(path: &Path, message: impl Into<String>) -> LocalizeError {
    LocalizeError::Sequence { path: path.to_path_buf(), message: message.into() }
}

/// The depth camera's optical frame (x right, y down, z forward) from its
/// body frame (x forward, y left, z up).
pub fn optical_from_body() -> Pose3 {
    let r = Matrix3::new(0.0, -1.0, 0.0, 0.0, 0.0, -1.0, 1.0, 0.0, 0.0);
    Pose3::from_parts(nalgebra::Translation3::identity(), Rot3::from_matrix(&r))
}

/// Seven-Scenes' Kinect depth camera, when a folder does not say.
const SEVEN_SCENES_CAMERA: PinholeCamera =
    PinholeCamera { width: 640, height: 480, fx: 585.0, fy: 585.0, cx: 320.0, cy: 240.0 };
/// The TUM RGB-D cameras by sequence name (the benchmark's published intrinsics).
const TUM_CAMERAS: [(&str, [f64; 4]); 3] = [
    ("freiburg1", [517.3, 516.5, 318.6, 255.3]),
    ("freiburg2", [520.9, 521.0, 325.1, 249.7]),
    ("freiburg3", [535.4, 539.2, 320.1, 247.6]),
];
/// 7-Scenes' clock: frame N at N / 30 s.
const SEVEN_SCENES_RATE_HZ: f64 = 30.0;

impl RgbdSequence {
    /// The layout of `dir`, if it is an RGB-D folder.
    pub fn layout_of(dir: &Path) -> Option<RgbdLayout> {
        if dir.join("depth.txt").is_file() && dir.join("rgb.txt").is_file() {
            return Some(RgbdLayout::Tum);
        }
        let has_frames = |d: &Path| {
            std::fs::read_dir(d).is_ok_and(|mut entries| {
                entries.any(|e| e.is_ok_and(|e| e.file_name().to_string_lossy().ends_with(".depth.png")))
            })
        };
        (has_frames(dir) || has_frames(&dir.join("frames"))).then_some(RgbdLayout::SevenScenes)
    }

    pub fn open(dir: &Path, options: &DepthOptions, image_tolerance_s: f64) -> Result<Self> {
        options.validate().map_err(|e| error(dir, format!("depth options: {e}")))?;
        match Self::layout_of(dir) {
            Some(RgbdLayout::Tum) => Self::open_tum(dir, options, image_tolerance_s),
            Some(RgbdLayout::SevenScenes) => Self::open_seven_scenes(dir, options),
            None => {
                Err(error(dir, "not an RGB-D folder (TUM's rgb.txt and depth.txt, or 7-Scenes' frame-N.depth.png)"))
            }
        }
    }

    fn open_tum(dir: &Path, options: &DepthOptions, image_tolerance_s: f64) -> Result<Self> {
        let depth = read_file_list(&dir.join("depth.txt"), dir)?;
        let rgb = read_file_list(&dir.join("rgb.txt"), dir)?;
        if depth.is_empty() {
            return Err(error(&dir.join("depth.txt"), "lists no depth images"));
        }
        let (camera, units_per_metre) = tum_camera(dir)?;
        let images: Vec<f64> = rgb.iter().map(|r| r.0).collect();
        let stamps: Vec<f64> = depth.iter().map(|d| d.0).collect();
        let pairs = nearest_within(&stamps, &images, image_tolerance_s);
        let frames = depth
            .into_iter()
            .zip(pairs)
            .map(|((stamp, depth), image)| RgbdFrame { stamp, depth, image: image.map(|k| rgb[k].clone()) })
            .collect();
        let truth_path = dir.join("groundtruth.txt");
        let ground_truth = if truth_path.is_file() {
            let truth = read_tum(&truth_path)?;
            truth.check_increasing(&truth_path)?;
            Some(in_body_frame(&truth))
        } else {
            None
        };
        Ok(Self {
            dir: dir.to_path_buf(),
            layout: RgbdLayout::Tum,
            frames,
            calibration: calibration(&camera),
            depth_camera: camera,
            units_per_metre,
            options: options.clone(),
            ground_truth,
            image_tolerance_s,
        })
    }

    fn open_seven_scenes(dir: &Path, options: &DepthOptions) -> Result<Self> {
        let frames_dir = if dir.join("frames").is_dir() { dir.join("frames") } else { dir.to_path_buf() };
        let entries = std::fs::read_dir(&frames_dir).map_err(|e| error(&frames_dir, e.to_string()))?;
        let mut numbers: Vec<(u64, PathBuf)> = Vec::new();
        for entry in entries {
            let name = entry.map_err(|e| error(&frames_dir, e.to_string()))?.file_name();
            let name = name.to_string_lossy();
            if let Some(n) = name.strip_prefix("frame-").and_then(|r| r.strip_suffix(".depth.png")) {
                let number = n.parse().map_err(|_| error(&frames_dir.join(&*name), "frame number is not a number"))?;
                numbers.push((number, frames_dir.join(&*name)));
            }
        }
        numbers.sort();
        let intrinsics = dir.join("camera-intrinsics.txt");
        let camera = if intrinsics.is_file() { read_intrinsics(&intrinsics)? } else { SEVEN_SCENES_CAMERA };
        let mut frames = Vec::with_capacity(numbers.len());
        let mut truth = Trajectory::default();
        for (number, depth) in numbers {
            let stamp = number as f64 / SEVEN_SCENES_RATE_HZ;
            let stem = depth.to_string_lossy().trim_end_matches(".depth.png").to_string();
            let image = ["color.png", "color.jpg"]
                .iter()
                .map(|ext| PathBuf::from(format!("{stem}.{ext}")))
                .find(|p| p.is_file())
                .map(|p| (stamp, p));
            let pose_path = PathBuf::from(format!("{stem}.pose.txt"));
            if pose_path.is_file() {
                truth.push(stamp, read_pose_matrix(&pose_path)?);
            }
            frames.push(RgbdFrame { stamp, depth, image });
        }
        // Poses for some frames only would score a different route.
        let ground_truth = match truth.len() {
            0 => None,
            n if n == frames.len() => Some(in_body_frame(&truth)),
            n => return Err(error(&frames_dir, format!("{n} of {} frames have a pose.txt", frames.len()))),
        };
        Ok(Self {
            dir: dir.to_path_buf(),
            layout: RgbdLayout::SevenScenes,
            frames,
            calibration: calibration(&camera),
            depth_camera: camera,
            units_per_metre: 1000.0,
            options: options.clone(),
            ground_truth,
            image_tolerance_s: 0.0,
        })
    }

    /// The depth image at `path`, of the depth camera's size.
    fn depth(&self, path: &Path) -> std::result::Result<DepthImage, FrameFault> {
        let depth = read_depth_png(path, self.units_per_metre).map_err(|e| FrameFault::Unreadable(e.to_string()))?;
        let camera = &self.depth_camera;
        if (depth.width, depth.height) != (camera.width, camera.height) {
            return Err(FrameFault::WrongSize {
                source: path.display().to_string(),
                what: "depth image",
                size: [depth.width, depth.height],
                reference: "the depth camera's is",
                expected: [camera.width, camera.height],
            });
        }
        Ok(depth)
    }

    /// The edge points of a frame whose colour image is registered to its
    /// depth (TUM's layout), in the body frame; none otherwise.
    fn edges(&self, depth: &DepthImage, image: &FrameImage) -> Vec<Point3<f32>> {
        let options = &self.options;
        let (RgbdLayout::Tum, true, Ok(colour)) = (self.layout, options.edges.enabled, &image.image) else {
            return Vec::new();
        };
        let body_from_optical = optical_from_body().inverse();
        edge_points(&colour.to_luma8(), depth, &self.depth_camera, &options.edges, options.near_m, options.far_m)
            .unwrap_or_default()
            .into_iter()
            .map(|p| (body_from_optical * p.cast::<f64>()).cast::<f32>())
            .collect()
    }
}

/// The scan of a depth image: its points in the depth camera's body frame.
pub fn depth_scan(depth: &DepthImage, camera: &PinholeCamera, options: &DepthOptions) -> PointCloud {
    let body_from_optical = optical_from_body().inverse();
    let points = depth
        .points(camera, options.stride, options.near_m, options.far_m)
        .into_iter()
        .map(|p| (body_from_optical * p.cast::<f64>()).cast::<f32>())
        .collect::<Vec<Point3<f32>>>();
    PointCloud::new(points, None)
}

impl RgbdSequence {
    /// The colour camera fitted to the depth's contours (`colour_registration`)
    /// on `frames` frames spread over the sequence.
    pub fn fit_colour_camera(&self, frames: usize) -> Result<crate::input::colour_registration::ColourFit> {
        use crate::input::colour_registration::{ContourFrame, fit_colour_camera};
        let with_images: Vec<&RgbdFrame> = self.frames.iter().filter(|f| f.image.is_some()).collect();
        if with_images.is_empty() {
            return Err(error(&self.dir, "no frame has a colour image to fit the colour camera to"));
        }
        let step = with_images.len().div_ceil(frames.max(1));
        let mut samples = Vec::new();
        for frame in with_images.iter().step_by(step) {
            // Of the depth camera's size, as every frame of a run must be.
            let depth = self.depth(&frame.depth).map_err(|fault| error(&frame.depth, fault.to_string()))?;
            let Some((_, path)) = &frame.image else { continue };
            let colour = datasets::atomic::read_image(path)?.to_luma8();
            samples.push(ContourFrame::new(&depth, &self.depth_camera, &colour, 0.1));
        }
        Ok(fit_colour_camera(&samples, &self.depth_camera))
    }

    /// The calibration of a fit: the colour camera offset along the depth
    /// camera's x by the fitted baseline.
    pub fn calibration_of(fit: &crate::input::colour_registration::ColourFit) -> Calibration {
        let offset = Pose3::from_parts(nalgebra::Translation3::new(fit.baseline_m, 0.0, 0.0), Rot3::identity());
        Calibration {
            camera: fit.camera.clone(),
            camera_from_lidar: offset * optical_from_body(),
            robot_from_lidar: Pose3::identity(),
        }
    }

    /// The sequence with its colour camera as `calibration` says (`--calib`:
    /// a colour camera that is not registered to the depth); the depth
    /// camera, and so the 3D points, stay as they were.
    pub fn with_colour_calibration(mut self, calibration: Calibration, path: &Path) -> Result<Self> {
        let (old, new) = (&self.calibration.camera, &calibration.camera);
        if (old.width, old.height) != (new.width, new.height) {
            return Err(error(
                path,
                format!(
                    "its camera is {}x{}, the colour images are {}x{}",
                    new.width, new.height, old.width, old.height
                ),
            ));
        }
        if calibration.robot_from_lidar != Pose3::identity() {
            return Err(error(
                path,
                "robot_from_lidar must be the identity for an RGB-D folder (the depth camera is the body)",
            ));
        }
        self.calibration = calibration;
        Ok(self)
    }
}

/// The calibration of an RGB-D camera whose colour image is registered to
/// its depth (the robot and "LIDAR" frames are the depth camera's body).
fn calibration(camera: &PinholeCamera) -> Calibration {
    Calibration { camera: camera.clone(), camera_from_lidar: optical_from_body(), robot_from_lidar: Pose3::identity() }
}

/// A trajectory of the camera's optical frame as one of its body frame.
fn in_body_frame(truth: &Trajectory) -> Trajectory {
    let optical = optical_from_body();
    Trajectory { stamps: truth.stamps.clone(), poses: truth.poses.iter().map(|p| p * optical).collect() }
}

/// "timestamp filename" lines (TUM's `rgb.txt`, `depth.txt`), `#` comments.
fn read_file_list(path: &Path, dir: &Path) -> Result<Vec<(f64, PathBuf)>> {
    let text = datasets::atomic::read_text(path)?;
    let mut out: Vec<(f64, PathBuf)> = Vec::new();
    for (k, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let at = |m: String| error(path, format!("line {}: {m}", k + 1));
        let mut fields = line.split_whitespace();
        let (Some(stamp), Some(file)) = (fields.next(), fields.next()) else {
            return Err(at("expected `timestamp filename`".into()));
        };
        let stamp: f64 =
            stamp.parse().ok().filter(|t: &f64| t.is_finite()).ok_or_else(|| at(format!("bad time `{stamp}`")))?;
        if out.last().is_some_and(|(last, _)| *last >= stamp) {
            return Err(at(format!("time {stamp} does not come after the line before")));
        }
        out.push((stamp, dir.join(file)));
    }
    Ok(out)
}

/// The TUM folder's intrinsics and depth scale.
fn tum_camera(dir: &Path) -> Result<(PinholeCamera, f64)> {
    let own = dir.join("calib.json");
    if own.is_file() {
        return Ok((datasets::io::formats::read_calibration(&own)?.camera, 5000.0));
    }
    let yaml = std::fs::read_dir(dir)
        .map_err(|e| error(dir, e.to_string()))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x == "yaml"))
        .min();
    if let Some(yaml) = yaml {
        return read_orb_slam_yaml(&yaml);
    }
    let name = dir.canonicalize().unwrap_or_else(|_| dir.to_path_buf()).to_string_lossy().to_string();
    TUM_CAMERAS
        .iter()
        .find(|(camera, _)| name.contains(camera))
        .map(|(_, [fx, fy, cx, cy])| {
            (PinholeCamera { width: 640, height: 480, fx: *fx, fy: *fy, cx: *cx, cy: *cy }, 5000.0)
        })
        .ok_or_else(|| {
            error(
                dir,
                "no intrinsics: add a calib.json or an ORB-SLAM style .yaml, or keep TUM's folder name (freiburg1/2/3)",
            )
        })
}

/// `Camera.fx: 535.4` style settings (ORB-SLAM's camera files).
fn read_orb_slam_yaml(path: &Path) -> Result<(PinholeCamera, f64)> {
    let text = datasets::atomic::read_text(path)?;
    let value = |key: &str| -> Option<f64> {
        text.lines().find_map(|line| {
            let (k, v) = line.split_once(':')?;
            (k.trim() == key).then(|| v.trim().parse().ok()).flatten()
        })
    };
    let need = |key: &str| value(key).ok_or_else(|| error(path, format!("no number for `{key}`")));
    let width = value("Camera.width").unwrap_or(640.0) as u32;
    let height = value("Camera.height").unwrap_or(480.0) as u32;
    let camera = PinholeCamera {
        width,
        height,
        fx: need("Camera.fx")?,
        fy: need("Camera.fy")?,
        cx: need("Camera.cx")?,
        cy: need("Camera.cy")?,
    };
    camera.validate().map_err(|e| error(path, e.to_string()))?;
    let distortion = ["Camera.k1", "Camera.k2", "Camera.p1", "Camera.p2"].map(|k| value(k).unwrap_or(0.0));
    if distortion.iter().any(|d| *d != 0.0) {
        return Err(error(path, "the camera has distortion; RGB-D input takes undistorted images"));
    }
    let factor = value("DepthMapFactor").unwrap_or(5000.0);
    if !(factor.is_finite() && factor > 0.0) {
        return Err(error(path, format!("DepthMapFactor {factor} must be finite and positive")));
    }
    Ok((camera, factor))
}

/// Whitespace-separated numbers of a small text matrix file.
fn read_numbers(path: &Path, count: usize) -> Result<Vec<f64>> {
    let text = datasets::atomic::read_text(path)?;
    let numbers: Vec<f64> = text
        .split_whitespace()
        .map(|t| t.parse::<f64>().ok().filter(|v| v.is_finite()))
        .collect::<Option<_>>()
        .ok_or_else(|| error(path, "not a matrix of finite numbers"))?;
    if numbers.len() != count {
        return Err(error(path, format!("{} numbers, expected {count}", numbers.len())));
    }
    Ok(numbers)
}

/// A 3 x 3 camera matrix K (7-Scenes' `camera-intrinsics.txt`), 640 x 480.
fn read_intrinsics(path: &Path) -> Result<PinholeCamera> {
    let k = read_numbers(path, 9)?;
    let camera = PinholeCamera { width: 640, height: 480, fx: k[0], fy: k[4], cx: k[2], cy: k[5] };
    camera.validate().map_err(|e| error(path, e.to_string()))?;
    Ok(camera)
}

/// A 4 x 4 rigid transform, row by row (7-Scenes' `pose.txt`). Its rotation
/// is re-orthonormalised: KinectFusion wrote it in single precision.
fn read_pose_matrix(path: &Path) -> Result<Pose3> {
    let m = read_numbers(path, 16)?;
    let r = Matrix3::new(m[0], m[1], m[2], m[4], m[5], m[6], m[8], m[9], m[10]);
    let off = (r.transpose() * r - Matrix3::identity()).abs().max();
    if off > 1e-3 || (r.determinant() - 1.0).abs() > 1e-3 || m[12..15].iter().any(|v| *v != 0.0) || m[15] != 1.0 {
        return Err(error(path, "not a rigid transform (orthonormal rotation, last row 0 0 0 1)"));
    }
    let rotation = Rot3::from_matrix(&r);
    Ok(Pose3::from_parts(nalgebra::Translation3::new(m[3], m[7], m[11]), rotation))
}

impl SensorSequence for RgbdSequence {
    fn calibration(&self) -> &Calibration {
        &self.calibration
    }
    fn odometry(&self) -> &[OdometrySample] {
        &[]
    }
    fn imu(&self) -> &[ImuSample] {
        &[]
    }
    fn ground_truth(&self) -> Option<&Trajectory> {
        self.ground_truth.as_ref()
    }
    fn world_description(&self) -> Option<PathBuf> {
        None
    }
    fn frame_stamps(&self) -> Vec<f64> {
        self.frames.iter().map(|f| f.stamp).collect()
    }
    fn range_sensor(&self) -> RangeSensor {
        RangeSensor::DepthCamera
    }
    fn for_each_frame(&self, visit: &mut dyn FnMut(FrameInput) -> Result<()>) -> Result<()> {
        for frame in &self.frames {
            let image = match &frame.image {
                Some((stamp, path)) => Ok(FrameImage::read(*stamp, path, &self.calibration.camera)),
                None => Err(FrameFault::NoImageNear {
                    image: "colour image",
                    tolerance_s: self.image_tolerance_s,
                    scan: "depth image",
                    stamp: frame.stamp,
                }),
            };
            let depth = self.depth(&frame.depth);
            let edges = match (&depth, &image) {
                (Ok(depth), Ok(image)) => self.edges(depth, image),
                _ => Vec::new(),
            };
            let cloud = depth.map(|d| depth_scan(&d, &self.depth_camera, &self.options));
            visit(FrameInput { stamp: frame.stamp, cloud, image, edges })?;
        }
        Ok(())
    }
}
