//! Sensor failures played into any recording, to see how a run holds up
//! when the LIDAR goes dark for a while or the camera stops
//! (`localize run --lidar-gap 20:25 --camera-stop 30`). Times count from the
//! recording's first scan, so that the same options fit a bag's absolute
//! clock and a generated sequence's. `WithChanges` plays them in, and
//! replaces the ground truth with `--gt`'s.

use std::path::PathBuf;

use datasets::io::formats::{Calibration, ImuSample, OdometrySample, Trajectory};

use crate::error::Result;
use crate::input::frame_fault::FrameFault;
use crate::input::sequence::RangeSensor;
use crate::input::sequence::{FrameInput, SensorSequence};

/// The failures: scans lost in each gap (start and end, seconds after the
/// first scan, end excluded), no image from `camera_stop_s` on, and the IMU
/// or the wheels left out altogether (`--without-imu`, `--without-wheels`).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct SensorFaults {
    pub lidar_gaps: Vec<[f64; 2]>,
    pub camera_stop_s: Option<f64>,
    pub without_imu: bool,
    pub without_wheels: bool,
}

impl SensorFaults {
    pub fn is_empty(&self) -> bool {
        self.lidar_gaps.is_empty() && self.camera_stop_s.is_none() && !self.without_imu && !self.without_wheels
    }

    /// Whether the scan `since_start` seconds after the first one is lost.
    fn scan_lost(&self, since_start: f64) -> bool {
        self.lidar_gaps.iter().any(|[a, b]| (*a..*b).contains(&since_start))
    }
}

/// `START:END` in seconds after the first scan, START < END (`--lidar-gap`).
pub fn parse_gap(text: &str) -> std::result::Result<[f64; 2], String> {
    let (a, b) = text.split_once(':').ok_or_else(|| format!("expected START:END in seconds, got `{text}`"))?;
    let start = datasets::cli::non_negative(a).map_err(|m| format!("START {m}"))?;
    let end = datasets::cli::non_negative(b).map_err(|m| format!("END {m}"))?;
    if end <= start {
        return Err(format!("END ({end}) must come after START ({start})"));
    }
    Ok([start, end])
}

/// A recording as the user changed it: its ground truth replaced (`--gt`)
/// and `faults` played into it (`--lidar-gap`, `--camera-stop`).
pub struct WithChanges {
    pub inner: Box<dyn SensorSequence>,
    /// Replaces the recording's own ground truth when given.
    pub truth: Option<Trajectory>,
    pub faults: SensorFaults,
}

impl WithChanges {
    fn first_scan(&self) -> f64 {
        self.inner.frame_stamps().first().copied().unwrap_or(0.0)
    }
}

impl SensorSequence for WithChanges {
    fn calibration(&self) -> &Calibration {
        self.inner.calibration()
    }
    fn odometry(&self) -> &[OdometrySample] {
        if self.faults.without_wheels { &[] } else { self.inner.odometry() }
    }
    fn imu(&self) -> &[ImuSample] {
        if self.faults.without_imu { &[] } else { self.inner.imu() }
    }
    fn range_sensor(&self) -> RangeSensor {
        self.inner.range_sensor()
    }
    fn log_source(&self, log: crate::input::sequence::MotionLog) -> String {
        self.inner.log_source(log)
    }
    fn ground_truth(&self) -> Option<&Trajectory> {
        self.truth.as_ref().or_else(|| self.inner.ground_truth())
    }
    fn world_description(&self) -> Option<PathBuf> {
        self.inner.world_description()
    }
    fn frame_stamps(&self) -> Vec<f64> {
        let first = self.first_scan();
        self.inner.frame_stamps().into_iter().filter(|t| !self.faults.scan_lost(t - first)).collect()
    }
    fn for_each_frame(&self, visit: &mut dyn FnMut(FrameInput) -> Result<()>) -> Result<()> {
        let first = self.first_scan();
        self.inner.for_each_frame(&mut |mut frame: FrameInput| {
            if self.faults.scan_lost(frame.stamp - first) {
                return Ok(());
            }
            if let Some(stop) = self.faults.camera_stop_s
                && frame.image.as_ref().is_ok_and(|image| image.stamp - first >= stop)
            {
                frame.image = Err(FrameFault::CameraStopped { after_s: stop });
            }
            visit(frame)
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gaps_parse_and_bad_ones_are_named() {
        assert_eq!(parse_gap("20:25.5"), Ok([20.0, 25.5]));
        for (text, says) in [("20", "START:END"), ("25:20", "must come after"), ("a:3", "START"), ("1:nan", "END")] {
            let error = parse_gap(text).unwrap_err();
            assert!(error.contains(says), "{text}: {error}");
        }
    }

    #[test]
    fn a_gap_loses_the_scans_from_its_start_up_to_its_end() {
        let faults = SensorFaults { lidar_gaps: vec![[2.0, 3.0]], ..SensorFaults::default() };
        let lost: Vec<bool> = [1.9, 2.0, 2.5, 2.999, 3.0].iter().map(|&t| faults.scan_lost(t)).collect();
        assert_eq!(lost, [false, true, true, true, false]);
    }
}
