//! A recorded sequence on disk (the layout `datagen` writes and DESIGN.md
//! documents): `cloud/<t>.pcd|ply|bin`, `rgb/<t>.png|jpg`, `odom.csv`,
//! `imu.csv`, `calib.json` and, when known, `groundtruth.txt` (TUM).

use std::path::{Path, PathBuf};

use datasets::formats::{
    Calibration, ImuSample, OdometrySample, Trajectory, read_calibration, read_imu, read_odometry, read_tum,
};

use crate::error::{LocalizeError, Result};

/// One frame's files; the image may be missing (the frame then falls back
/// to the reference pose).
#[derive(Debug, Clone)]
pub struct FrameFiles {
    pub stamp: f64,
    pub cloud: PathBuf,
    pub image: Option<PathBuf>,
}

pub struct RecordedSequence {
    pub dir: PathBuf,
    pub frames: Vec<FrameFiles>,
    pub calibration: Calibration,
    pub odometry: Vec<OdometrySample>,
    pub imu: Vec<ImuSample>,
    pub ground_truth: Option<Trajectory>,
}

const CLOUD_EXTENSIONS: [&str; 3] = ["pcd", "ply", "bin"];
const IMAGE_EXTENSIONS: [&str; 3] = ["png", "jpg", "jpeg"];

fn error(path: &Path, message: impl Into<String>) -> LocalizeError {
    LocalizeError::Sequence { path: path.to_path_buf(), message: message.into() }
}

impl RecordedSequence {
    pub fn open(dir: &Path) -> Result<Self> {
        if !dir.is_dir() {
            return Err(error(dir, "not a folder"));
        }
        let calibration = read_calibration(&dir.join("calib.json"))?;
        let odometry = read_odometry(&dir.join("odom.csv"))?;
        let imu = read_imu(&dir.join("imu.csv"))?;
        let truth_path = dir.join("groundtruth.txt");
        let ground_truth = if truth_path.is_file() { Some(read_tum(&truth_path)?) } else { None };
        if let Some(t) = &ground_truth {
            t.check_increasing(&truth_path)?;
        }
        let cloud_dir = dir.join("cloud");
        let entries = std::fs::read_dir(&cloud_dir).map_err(|e| error(&cloud_dir, e.to_string()))?;
        let mut frames = Vec::new();
        for entry in entries {
            let path = entry.map_err(|e| error(&cloud_dir, e.to_string()))?.path();
            let Some(ext) = path.extension().and_then(|e| e.to_str()) else { continue };
            if !CLOUD_EXTENSIONS.contains(&ext.to_ascii_lowercase().as_str()) {
                continue;
            }
            let stem = path.file_stem().and_then(|s| s.to_str()).unwrap_or_default().to_string();
            let stamp: f64 = stem
                .parse()
                .ok()
                .filter(|t: &f64| t.is_finite())
                .ok_or_else(|| error(&path, "file name is not a timestamp in seconds"))?;
            let image =
                IMAGE_EXTENSIONS.iter().map(|e| dir.join("rgb").join(format!("{stem}.{e}"))).find(|p| p.is_file());
            frames.push(FrameFiles { stamp, cloud: path, image });
        }
        if frames.is_empty() {
            return Err(error(&cloud_dir, "no point clouds (.pcd, .ply, .bin)"));
        }
        frames.sort_by(|a, b| a.stamp.total_cmp(&b.stamp));
        for w in frames.windows(2) {
            if w[1].stamp == w[0].stamp {
                return Err(error(
                    &w[1].cloud,
                    format!("duplicate timestamp {} (also {})", w[1].stamp, w[0].cloud.display()),
                ));
            }
        }
        Ok(Self { dir: dir.to_path_buf(), frames, calibration, odometry, imu, ground_truth })
    }
}
