//! What localization reads, whatever the recording: the calibration, the
//! odometry and IMU logs, the ground truth, and the frames (a LIDAR scan
//! each, with the nearest camera image within a tolerance). Three sources
//! give it: a sequence folder (here), a ROS bag (`bag_sequence`) and an
//! RGB-D folder (`rgbd_sequence`).
//!
//! The folder layout (`datagen` writes it, DESIGN.md documents it):
//! `cloud/<t>.pcd|ply|bin`, `rgb/<t>.png|jpg`, `odom.csv` and `imu.csv` (each
//! optional), `calib.json` and, when known, `groundtruth.txt` (TUM). `<t>` is the time
//! in seconds (`datagen` pads it with zeros so that names sort in time
//! order, e.g. `0000000010.500000`) or, with 16 digits or more and no
//! point, in nanoseconds; the clouds and the images keep their own clocks.

use std::path::{Path, PathBuf};

use datasets::InvalidSetting;
use datasets::io::formats::{
    CLOUD_EXTENSIONS, Calibration, IMAGE_EXTENSIONS, ImuSample, NonFinite, OdometrySample, PointCloud, Trajectory,
    read_calibration, read_cloud, read_imu, read_odometry, read_tum, stamped_files,
};
use datasets::math::Pose3;
use image::DynamicImage;
use serde::{Deserialize, Serialize};

use crate::error::{LocalizeError, Result};
use crate::input::frame_fault::FrameFault;

/// How frames take their images and their points' times.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SyncConfig {
    /// A scan takes the image nearest in time within this many seconds;
    /// further away, the frame has no image.
    pub image_tolerance_s: f64,
    /// Undo the motion during a sweep when the cloud has per-point times.
    pub deskew: bool,
    /// Cast the detector's rays from the camera's pose at the image's own
    /// time (predicted by the filter); off, from its pose at the scan's time.
    pub camera_motion: bool,
    /// The detector runs on at most this many images a second (the first
    /// image at least 1/rate after the last one it ran on); the frames
    /// between go on with the LIDAR alone. 0: on every frame's image.
    pub detector_rate_hz: f64,
}

impl Default for SyncConfig {
    fn default() -> Self {
        Self { image_tolerance_s: 0.05, deskew: true, camera_motion: true, detector_rate_hz: 5.0 }
    }
}

impl SyncConfig {
    pub fn validate(&self) -> std::result::Result<(), InvalidSetting> {
        if !(0.0..=10.0).contains(&self.image_tolerance_s) {
            return Err(InvalidSetting::field(
                "image_tolerance_s",
                format!("{} s outside [0, 10]", self.image_tolerance_s),
            ));
        }
        if !(0.0..=1000.0).contains(&self.detector_rate_hz) {
            return Err(InvalidSetting::field(
                "detector_rate_hz",
                format!("{} Hz outside [0, 1000]", self.detector_rate_hz),
            ));
        }
        Ok(())
    }
}

/// The image a frame takes, at its own time.
pub struct FrameImage {
    pub stamp: f64,
    /// The key of the image for labels (`--corners-from-labels`): its file stem.
    pub name: String,
    pub image: std::result::Result<DynamicImage, FrameFault>,
}

impl FrameImage {
    /// The image file at `path`, taken at `stamp`, which must be of
    /// `camera`'s size: corners of an image of another size would land on
    /// the wrong rays.
    pub fn read(stamp: f64, path: &Path, camera: &datasets::camera::PinholeCamera) -> Self {
        let image =
            datasets::atomic::read_image(path).map_err(|e| FrameFault::Unreadable(e.to_string())).and_then(|im| {
                if (im.width(), im.height()) == (camera.width, camera.height) {
                    Ok(im)
                } else {
                    Err(FrameFault::WrongSize {
                        source: path.display().to_string(),
                        what: "image",
                        size: [im.width(), im.height()],
                        reference: "the calibration's camera is",
                        expected: [camera.width, camera.height],
                    })
                }
            });
        let name = path.file_stem().and_then(|s| s.to_str()).unwrap_or_default().to_string();
        Self { stamp, name, image }
    }
}

/// The recorded motion logs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MotionLog {
    Odometry,
    Imu,
}

impl std::fmt::Display for MotionLog {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            MotionLog::Odometry => "the odometry log",
            MotionLog::Imu => "the IMU log",
        })
    }
}

/// One frame as the pipeline gets it.
pub struct FrameInput {
    /// The scan's time: the frame's time in the trajectory.
    pub stamp: f64,
    pub cloud: std::result::Result<PointCloud, FrameFault>,
    /// Why there is none when there is none.
    pub image: std::result::Result<FrameImage, FrameFault>,
    /// Edge points in the 3D sensor's frame (`image_edges`): only an RGB-D
    /// frame whose colour is registered to its depth has them.
    pub edges: Vec<nalgebra::Point3<f32>>,
}

/// What gives a recording's 3D points.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum RangeSensor {
    /// A spinning or solid-state LIDAR: tens of metres.
    Lidar,
    /// A depth image (RGB-D camera) turned into points: a few metres.
    DepthCamera,
}

/// A recording localization can run on.
pub trait SensorSequence {
    fn calibration(&self) -> &Calibration;
    fn odometry(&self) -> &[OdometrySample];
    fn imu(&self) -> &[ImuSample];
    /// World from robot in the ground truth's own frame (a generated
    /// building's, a motion-capture system's); `run::truth_in_run_frame`
    /// puts it in a run's world.
    fn ground_truth(&self) -> Option<&Trajectory>;
    /// The `world.json` of a generated sequence (levels for per-level metrics).
    fn world_description(&self) -> Option<PathBuf>;
    /// Scan times in order.
    fn frame_stamps(&self) -> Vec<f64>;
    /// What gives the 3D points: a LIDAR unless the recording says otherwise.
    fn range_sensor(&self) -> RangeSensor {
        RangeSensor::Lidar
    }
    /// Where the motion log `log` ([`MotionLog`]) comes from, for messages:
    /// its file or its topic.
    fn log_source(&self, log: MotionLog) -> String {
        log.to_string()
    }
    /// Hands each frame, in time order, to `visit`.
    fn for_each_frame(&self, visit: &mut dyn FnMut(FrameInput) -> Result<()>) -> Result<()>;
}

/// One frame's files; the image may be missing (the frame then falls back
/// to the reference pose).
#[derive(Debug, Clone)]
pub struct FrameFiles {
    pub stamp: f64,
    pub cloud: PathBuf,
    pub image: Option<ImageFile>,
}

#[derive(Debug, Clone, PartialEq)]
pub struct ImageFile {
    pub stamp: f64,
    pub path: PathBuf,
}

pub struct RecordedSequence {
    pub dir: PathBuf,
    pub frames: Vec<FrameFiles>,
    pub calibration: Calibration,
    pub odometry: Vec<OdometrySample>,
    pub imu: Vec<ImuSample>,
    pub ground_truth: Option<Trajectory>,
    pub image_tolerance_s: f64,
}

fn error(path: &Path, message: impl Into<String>) -> LocalizeError {
    LocalizeError::Sequence { path: path.to_path_buf(), message: message.into() }
}

pub use datasets::io::formats::stamped_files::parse_stamp_name as stamp_of_name;

/// For each of `scans` (sorted), the index of the nearest of `images`
/// (sorted) within `tolerance` seconds.
pub fn nearest_within(scans: &[f64], images: &[f64], tolerance: f64) -> Vec<Option<usize>> {
    scans
        .iter()
        .map(|&t| {
            let k = images.partition_point(|&s| s < t);
            [k.checked_sub(1), (k < images.len()).then_some(k)]
                .into_iter()
                .flatten()
                .min_by(|&a, &b| (images[a] - t).abs().total_cmp(&(images[b] - t).abs()))
                .filter(|&j| (images[j] - t).abs() <= tolerance)
        })
        .collect()
}

impl RecordedSequence {
    /// Opens a folder with the default image tolerance.
    pub fn open(dir: &Path) -> Result<Self> {
        Self::open_with(dir, &SyncConfig::default())
    }

    pub fn open_with(dir: &Path, sync: &SyncConfig) -> Result<Self> {
        if !dir.is_dir() {
            return Err(error(dir, "not a folder"));
        }
        sync.validate().map_err(|e| e.within("sync"))?;
        let calibration = read_calibration(&dir.join("calib.json"))?;
        // Either log may be missing (a rig without wheels or IMU); a log
        // with a header and no rows is a broken recording, not such a rig.
        let (odom_path, imu_path) = (dir.join("odom.csv"), dir.join("imu.csv"));
        let odometry = if odom_path.exists() { read_odometry(&odom_path)? } else { Vec::new() };
        let imu = if imu_path.exists() { read_imu(&imu_path)? } else { Vec::new() };
        for (path, empty) in [(&odom_path, odometry.is_empty()), (&imu_path, imu.is_empty())] {
            if empty && path.exists() {
                return Err(error(path, "a header and no rows: delete the file if the rig has no such sensor"));
            }
        }
        let truth_path = dir.join("groundtruth.txt");
        let ground_truth = if truth_path.is_file() { Some(read_tum(&truth_path)?) } else { None };
        if let Some(t) = &ground_truth {
            t.check_increasing(&truth_path)?;
        }
        let cloud_dir = dir.join("cloud");
        let clouds = stamped_files(&cloud_dir, &CLOUD_EXTENSIONS, "cloud")?;
        if clouds.is_empty() {
            return Err(error(&cloud_dir, "no point clouds (.pcd, .ply, .bin)"));
        }
        let rgb = dir.join("rgb");
        let images = if rgb.is_dir() { stamped_files(&rgb, &IMAGE_EXTENSIONS, "image")? } else { Vec::new() };
        let scan_times: Vec<f64> = clouds.iter().map(|c| c.0).collect();
        let image_times: Vec<f64> = images.iter().map(|c| c.0).collect();
        let pairs = nearest_within(&scan_times, &image_times, sync.image_tolerance_s);
        let frames = clouds
            .into_iter()
            .zip(pairs)
            .map(|((stamp, cloud), image)| FrameFiles {
                stamp,
                cloud,
                image: image.map(|j| ImageFile { stamp: images[j].0, path: images[j].1.clone() }),
            })
            .collect();
        Ok(Self {
            dir: dir.to_path_buf(),
            frames,
            calibration,
            odometry,
            imu,
            ground_truth,
            image_tolerance_s: sync.image_tolerance_s,
        })
    }
}

impl SensorSequence for RecordedSequence {
    fn calibration(&self) -> &Calibration {
        &self.calibration
    }
    fn log_source(&self, log: MotionLog) -> String {
        let file = match log {
            MotionLog::Odometry => "odom.csv",
            MotionLog::Imu => "imu.csv",
        };
        self.dir.join(file).display().to_string()
    }
    fn odometry(&self) -> &[OdometrySample] {
        &self.odometry
    }
    fn imu(&self) -> &[ImuSample] {
        &self.imu
    }
    fn ground_truth(&self) -> Option<&Trajectory> {
        self.ground_truth.as_ref()
    }
    fn world_description(&self) -> Option<PathBuf> {
        let world = self.dir.join("world.json");
        world.is_file().then_some(world)
    }
    fn frame_stamps(&self) -> Vec<f64> {
        self.frames.iter().map(|f| f.stamp).collect()
    }
    fn for_each_frame(&self, visit: &mut dyn FnMut(FrameInput) -> Result<()>) -> Result<()> {
        for frame in &self.frames {
            let cloud = read_cloud(&frame.cloud, NonFinite::Drop).map_err(|e| FrameFault::Unreadable(e.to_string()));
            let image = match &frame.image {
                Some(file) => Ok(FrameImage::read(file.stamp, &file.path, &self.calibration.camera)),
                None => Err(FrameFault::no_image_near(self.image_tolerance_s, frame.stamp)),
            };
            visit(FrameInput { stamp: frame.stamp, cloud, image, edges: Vec::new() })?;
        }
        Ok(())
    }
}

/// The ground truth's pose at `time`, interpolated between its samples
/// (the nearest end outside them).
pub fn truth_at(truth: &Trajectory, time: f64) -> Pose3 {
    let k = truth.stamps.partition_point(|&t| t < time);
    match (k.checked_sub(1), truth.stamps.get(k)) {
        (Some(a), Some(&tb)) if tb > time => {
            let ta = truth.stamps[a];
            let s = (time - ta) / (tb - ta);
            let (pa, pb) = (&truth.poses[a], &truth.poses[k]);
            Pose3::from_parts(
                pa.translation.vector.lerp(&pb.translation.vector, s).into(),
                pa.rotation.slerp(&pb.rotation, s),
            )
        }
        _ => truth.poses[k.min(truth.len() - 1)],
    }
}

/// `truth` in the frame whose pose in the truth's frame is `origin`.
pub fn relative_to(truth: &Trajectory, origin: &Pose3) -> Trajectory {
    let inverse = origin.inverse();
    Trajectory { stamps: truth.stamps.clone(), poses: truth.poses.iter().map(|p| inverse * p).collect() }
}
