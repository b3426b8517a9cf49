//! `localize run`: a recorded sequence in, the fused trajectory, the
//! odometry/IMU reference, the per-frame log and (with ground truth) the
//! metrics out.

use std::fmt::Write as _;
use std::path::Path;
use std::time::Instant;

use datasets::io::formats::{Trajectory, write_tum};
use datasets::math::Pose3;
use indicatif::{ProgressBar, ProgressStyle};
use serde::Serialize;

use crate::config::LocalizeConfig;
use crate::error::Result;
use crate::estimation::ekf::Ekf;
use crate::estimation::motion::FrameMotion;
use crate::estimation::pipeline::{CameraCorners, FrameReport, FrameStatus, Localizer};
use crate::estimation::relocalize::{Placement, keyframes_along};
use crate::estimation::sensor_replay::SensorReplay;
use crate::evaluation::eval::{Alignment, ErrorSummary, compare};
use crate::evaluation::levels::{LevelMap, SegmentMetrics};
use crate::input::corner_source::CornerSource;
use crate::input::frame_fault::FrameFault;
use crate::input::sequence::{FrameInput, SensorSequence, relative_to, truth_at};
use crate::labels::corner_tracks::{CornerTrackConfig, CornerTracks, structural_corners};

pub struct RunResult {
    /// The fused trajectory (world from robot).
    pub trajectory: Trajectory,
    /// Odometry/IMU alone: the same filter without corner corrections.
    pub reference: Trajectory,
    pub frames: Vec<FrameReport>,
    /// The maps at the end of the run.
    pub corner_landmarks: Vec<crate::estimation::landmarks::Landmark>,
    pub plane_landmarks: Vec<crate::estimation::plane_landmarks::PlaneLandmark>,
    /// The building's axis the walls were squared with (radians).
    pub wall_axis: Option<f64>,
    /// The point map's surface points (empty without scan matching).
    pub point_map: Vec<crate::estimation::point_map::MapPoint>,
    /// Poses a later run is placed from: the given map's, then this run's.
    pub keyframes: Vec<Pose3>,
    /// The run's world in the ground truth's frame: the ground truth at the
    /// first scan, or the given map's origin (`None` when not known).
    pub truth_origin: Option<Pose3>,
    /// Where the first scan was placed in a given map.
    pub placement: Option<Placement>,
    /// The scans' 3D corners followed over the run (when asked for).
    pub corner_tracks: Option<CornerTracks>,
}

/// What a run does besides localizing.
#[derive(Default)]
pub struct RunOptions {
    /// A map to start in.
    pub map: Option<MapStart>,
    pub show_progress: bool,
    /// Follow the scans' 3D corners in the world (`corner_tracks`), for `autolabel`.
    pub track_corners: Option<CornerTrackConfig>,
    /// Keep the image's edges lifted through the depth (`image_edges`) when
    /// the corner source is off: the detector is left out, not the camera.
    pub keep_image_edges: bool,
}

/// A map to localize in, and optionally where in it the sequence starts
/// (searched near there); without a start, around all the map's keyframes.
pub struct MapStart {
    pub map: crate::map_output::SavedMap,
    pub start: Option<Pose3>,
}

pub fn run_sequence(
    sequence: &dyn SensorSequence,
    source: &mut CornerSource,
    config: &LocalizeConfig,
    show_progress: bool,
) -> Result<RunResult> {
    run_sequence_in_map(sequence, source, config, None, show_progress)
}

/// As `run_sequence`, starting from the maps of an earlier run of the same
/// building when `map` is given: the first scan is placed in that map
/// (`relocalize.rs`) and the trajectory is in the map's frame.
pub fn run_sequence_in_map(
    sequence: &dyn SensorSequence,
    source: &mut CornerSource,
    config: &LocalizeConfig,
    map: Option<MapStart>,
    show_progress: bool,
) -> Result<RunResult> {
    run_with(sequence, source, config, RunOptions { map, show_progress, ..RunOptions::default() })
}

/// A run with everything `RunOptions` can ask for.
pub fn run_with(
    sequence: &dyn SensorSequence,
    source: &mut CornerSource,
    config: &LocalizeConfig,
    options: RunOptions,
) -> Result<RunResult> {
    let RunOptions { map, show_progress, track_corners, keep_image_edges } = options;
    config.validate()?;
    if let Some(c) = &track_corners {
        c.validate().map_err(|e| e.within("corner_tracks"))?;
    }
    let calibration = sequence.calibration().clone();
    let mut localizer = Localizer::new(config, calibration.clone())?;
    let stamps = sequence.frame_stamps();
    let Some(&start_time) = stamps.first() else {
        return Err(crate::error::LocalizeError::Recording("the recording has no LIDAR scans".into()));
    };
    let (keyframes, truth_origin, placing) = match map {
        Some(MapStart { map, start }) => {
            let kept = (map.keyframes.clone(), map.truth_origin, Some(start));
            localizer.start_from_map(map);
            kept
        }
        None => (Vec::new(), sequence.ground_truth().map(|t| truth_at(t, start_time)), None),
    };
    check_logs_cover(&stamps, sequence)?;
    let bar = if show_progress { ProgressBar::new(stamps.len() as u64) } else { ProgressBar::hidden() };
    bar.set_style(
        ProgressStyle::with_template("{prefix} [{elapsed_precise}] {bar:30} {pos}/{len} frames {msg}")
            .expect("static template"),
    );
    bar.set_prefix("localize");
    // The world frame is the robot's pose at the first frame; in a given
    // map, the map's, the first frame placing the filters there.
    let start = datasets::math::Pose3::identity();
    let mut run = RunState {
        config,
        calibration,
        localizer,
        fused: Ekf::new(config.ekf.clone(), &start, start_time),
        dead_reckoning: Ekf::new(config.ekf.clone(), &start, start_time),
        replay: SensorReplay::new(sequence.odometry(), sequence.imu(), start_time),
        replay_reference: SensorReplay::new(sequence.odometry(), sequence.imu(), start_time),
        detector_clock: DetectorClock { rate_hz: config.sync.detector_rate_hz, last: None },
        placing,
        keep_image_edges,
        unreadable: Vec::new(),
        result: RunResult {
            trajectory: Trajectory::default(),
            reference: Trajectory::default(),
            frames: Vec::new(),
            corner_landmarks: Vec::new(),
            plane_landmarks: Vec::new(),
            wall_axis: None,
            point_map: Vec::new(),
            keyframes: Vec::new(),
            truth_origin,
            placement: None,
            corner_tracks: track_corners.map(CornerTracks::new),
        },
    };
    sequence.for_each_frame(&mut |frame: FrameInput| {
        let status = run.frame(frame, source)?;
        bar.set_message(status);
        bar.inc(1);
        Ok(())
    })?;
    bar.finish();
    run.finish(keyframes)
}

/// A run between its frames: the filters and their log replays, the
/// detector's clock, the map placement still to do, what was made so far.
struct RunState<'a> {
    config: &'a LocalizeConfig,
    calibration: datasets::io::formats::Calibration,
    localizer: Localizer,
    fused: Ekf,
    /// Odometry/IMU alone: the reference trajectory.
    dead_reckoning: Ekf,
    replay: SensorReplay<'a>,
    replay_reference: SensorReplay<'a>,
    detector_clock: DetectorClock,
    /// In a given map: the rough start the first scan is placed near.
    placing: Option<Option<Pose3>>,
    keep_image_edges: bool,
    unreadable: Vec<FrameFault>,
    result: RunResult,
}

impl RunState<'_> {
    /// One frame: the filters to its time, its cloud deskewed, geometry and
    /// detector side by side, the fusion; returns the frame's status line.
    fn frame(&mut self, frame: FrameInput, source: &mut CornerSource) -> Result<String> {
        let (config, calibration) = (self.config, &self.calibration);
        let FrameInput { stamp, mut cloud, image, edges } = frame;
        if let Err(why) = &cloud {
            self.unreadable.push(why.clone());
        }
        // A frame's time counts from here: filter, deskewing, geometry and detector.
        let started = Instant::now();
        let image_stamp = image.as_ref().ok().map(|i| i.stamp);
        // The filter moves to the scan's time, and says where the robot was
        // when the image was taken and while the sweep went round.
        let times = FrameMotion::times_for(stamp, image_stamp, cloud.as_ref().ok().filter(|_| config.sync.deskew));
        let motion = FrameMotion::sample(&mut self.fused, &mut self.replay, stamp, &times);
        self.replay_reference.advance(&mut self.dead_reckoning, stamp);
        // The sweep's rows and columns, while its points still lie on their beams.
        let sweep_image = cloud.as_ref().ok().filter(|c| c.times.is_some()).and_then(|c| self.localizer.sweep_image(c));
        if config.sync.deskew
            && let Ok(c) = &mut cloud
        {
            motion.deskew(c, &calibration.robot_from_lidar);
        }
        let lidar_from_camera = match image_stamp {
            Some(t) if t != stamp && config.sync.camera_motion => {
                calibration.robot_from_lidar.inverse() * motion.relative(t) * calibration.robot_from_camera()
            }
            _ => calibration.camera_from_lidar.inverse(),
        };
        let name =
            image.as_ref().map_or_else(|_| datasets::io::formats::stamped_files::stamp_name(stamp), |i| i.name.clone());
        let camera_off = matches!(source, CornerSource::Off);
        let image = image
            .and_then(|i| i.image)
            .and_then(|image| if camera_off { Err(FrameFault::CameraOff) } else { Ok(image) })
            .and_then(|image| self.detector_clock.take(stamp).map(|()| image));
        // The cloud's geometry and the detector are independent until fusion:
        // run them side by side, so each fills the cores the other leaves idle.
        let localizer = &self.localizer;
        let (geometry, (pixels, detect_ms)) = rayon::join(
            || localizer.frame_geometry(cloud, sweep_image),
            || match (&image, &mut *source) {
                (Err(why), _) => (Err(why.clone()), 0.0),
                (Ok(image), source) => source.corners(&name, Some(image)),
            },
        );
        // In a given map, the first scan says where the run starts.
        if let Some(start) = self.placing.take() {
            self.place(&geometry, start.as_ref(), stamp)?;
        }
        // The image's edges are the camera's too: left out with it.
        let edges = if camera_off && !self.keep_image_edges { Vec::new() } else { edges };
        let camera = CameraCorners { pixels, lidar_from_camera, detect_ms, edges };
        let scan_corners = match (&self.result.corner_tracks, &geometry) {
            (Some(t), Ok(g)) => structural_corners(g, &self.calibration.robot_from_lidar, t.config.min_plane_extent_m),
            _ => Vec::new(),
        };
        let report = self.localizer.process(stamp, &mut self.fused, geometry, camera, started);
        let result = &mut self.result;
        if let Some(tracks) = &mut result.corner_tracks {
            tracks.observe(stamp, &report.pose, &scan_corners);
        }
        // What the recording does not measure carries on from this motion.
        if let (Some(&from_stamp), Some(from)) = (result.trajectory.stamps.last(), result.trajectory.poses.last()) {
            self.replay.carry_on((from, from_stamp), (&report.pose, stamp));
        }
        let status = report.status.label();
        result.trajectory.push(stamp, report.pose);
        result.reference.push(stamp, self.dead_reckoning.pose());
        result.frames.push(report);
        Ok(status)
    }

    /// Places both filters where the first scan fits the given map.
    fn place(
        &mut self,
        geometry: &std::result::Result<crate::scan::geometry::Geometry, FrameFault>,
        start: Option<&Pose3>,
        stamp: f64,
    ) -> Result<()> {
        let placed = match geometry {
            Ok(g) => self.localizer.place_in_map(g, start),
            Err(why) => Err(format!("its cloud is unusable: {why}")),
        };
        let placement = placed.map_err(|why| crate::error::LocalizeError::Relocalize { stamp, why })?;
        self.fused.place(&placement.pose, &placement.covariance);
        self.dead_reckoning.place(&placement.pose, &placement.covariance);
        self.result.placement = Some(placement);
        Ok(())
    }

    /// The maps the run built, and its keyframes after `keyframes` (a given
    /// map's). Clouds that cannot be read are each a frame's fallback; all
    /// of them unreadable is a broken recording, not a run.
    fn finish(self, mut keyframes: Vec<Pose3>) -> Result<RunResult> {
        let Self { mut result, localizer, unreadable, config, .. } = self;
        if unreadable.len() == result.frames.len()
            && let Some(why) = unreadable.first()
        {
            return Err(crate::error::LocalizeError::Cloud(format!(
                "every one of the {} clouds is unreadable; the first: {why}",
                result.frames.len()
            )));
        }
        result.corner_landmarks = localizer.map.landmarks.clone();
        result.plane_landmarks = localizer.plane_map.landmarks.clone();
        result.wall_axis = localizer.plane_map.axis;
        result.point_map = localizer.point_map.points().copied().collect();
        keyframes.extend(keyframes_along(&result.trajectory.poses, &config.relocalize));
        result.keyframes = keyframes;
        Ok(result)
    }
}

/// The sequence's ground truth in the run's world (the frame of its
/// trajectory); `None` without ground truth or where the run's world is not
/// known in the ground truth's frame (a map written without ground truth).
pub fn truth_in_run_frame(sequence: &dyn SensorSequence, result: &RunResult) -> Option<Trajectory> {
    Some(relative_to(sequence.ground_truth()?, result.truth_origin.as_ref()?))
}

/// Holds the detector to `SyncConfig::detector_rate_hz`.
struct DetectorClock {
    rate_hz: f64,
    last: Option<f64>,
}

impl DetectorClock {
    /// Whether the detector runs on the frame at `stamp`; why not otherwise.
    fn take(&mut self, stamp: f64) -> std::result::Result<(), FrameFault> {
        // A tenth of the period of slack: a driver's scan stamps jitter.
        if self.rate_hz > 0.0 && self.last.is_some_and(|last| stamp - last < 0.9 / self.rate_hz) {
            return Err(FrameFault::DetectorSkipped { rate_hz: self.rate_hz });
        }
        self.last = Some(stamp);
        Ok(())
    }
}

/// Longest a scan may lie past either end of the odometry and IMU logs
/// (beyond, its pose would be extrapolated, not measured).
const MAX_OUTSIDE_LOGS_S: f64 = 1.0;

fn check_logs_cover(stamps: &[f64], sequence: &dyn SensorSequence) -> Result<()> {
    use crate::input::sequence::MotionLog;
    let odometry = sequence.odometry();
    let imu = sequence.imu();
    let spans = [
        (MotionLog::Odometry, odometry.first().map(|s| s.timestamp), odometry.last().map(|s| s.timestamp)),
        (MotionLog::Imu, imu.first().map(|s| s.timestamp), imu.last().map(|s| s.timestamp)),
    ];
    // A log the recording does not have is not checked: its role carries on
    // from the previous motion (`SensorReplay`).
    for (name, first, last) in spans {
        let (Some(first), Some(last)) = (first, last) else { continue };
        let outside: Vec<f64> = stamps
            .iter()
            .copied()
            .filter(|&t| t > last + MAX_OUTSIDE_LOGS_S || t < first - MAX_OUTSIDE_LOGS_S)
            .collect();
        if let Some(t) = outside.first() {
            return Err(crate::error::LocalizeError::Recording(format!(
                "{} scans lie more than {MAX_OUTSIDE_LOGS_S} s outside {name} ({}: {first:.6} to {last:.6} s), the first at {t:.6} s",
                outside.len(),
                sequence.log_source(name)
            )));
        }
    }
    Ok(())
}

/// The errors of one trajectory against the ground truth.
#[derive(Debug, Clone, Serialize)]
pub struct TrajectoryMetrics {
    pub overall: ErrorSummary,
    pub levels: Vec<SegmentMetrics>,
}

#[derive(Debug, Clone, Serialize)]
pub struct RunMetrics {
    pub fused: TrajectoryMetrics,
    /// The fused trajectory's errors after the rigid (SE3) alignment that
    /// fits it best to the truth, as RGB-D and visual odometry papers report
    /// (`None` where no alignment is defined: fewer than three poses, or all
    /// on a line).
    pub fused_se3_aligned: Option<ErrorSummary>,
    pub odometry_imu: TrajectoryMetrics,
    pub frames: usize,
    /// Frames corrected with the camera's corners in the solve.
    pub fused_frames: usize,
    /// Frames corrected by anything: corners, walls or the scan (`FrameStatus::corrected`).
    pub corrected_frames: usize,
    pub mean_total_ms: f64,
}

/// The run's errors against the sequence's ground truth (`None` without
/// one, or when it does not overlap the run).
pub fn metrics(sequence: &dyn SensorSequence, result: &RunResult) -> Result<Option<RunMetrics>> {
    metrics_against(sequence, result, truth_in_run_frame(sequence, result).as_ref())
}

/// As `metrics`, with the ground truth already in the run's world
/// (`truth_in_run_frame`), for callers that also draw it.
pub fn metrics_against(
    sequence: &dyn SensorSequence,
    result: &RunResult,
    truth: Option<&Trajectory>,
) -> Result<Option<RunMetrics>> {
    let Some(truth) = truth else { return Ok(None) };
    // Levels are looked up where the ground truth's frame (world.json's) puts the robot.
    let in_world_json = sequence.ground_truth().unwrap_or(truth);
    let levels = match sequence.world_description() {
        Some(world) => Some(LevelMap::read(&world)?),
        None => None,
    };
    let measure = |estimate: &Trajectory| -> Option<TrajectoryMetrics> {
        let comparison = compare(truth, estimate, Alignment::None, 0.01).ok()?;
        let per_level = levels.as_ref().map(|l| l.per_segment(&comparison, in_world_json)).unwrap_or_default();
        Some(TrajectoryMetrics { overall: comparison.summary, levels: per_level })
    };
    let (Some(fused), Some(odometry_imu)) = (measure(&result.trajectory), measure(&result.reference)) else {
        return Ok(None);
    };
    let aligned = compare(truth, &result.trajectory, Alignment::Se3, 0.01).ok().map(|c| c.summary);
    Ok(Some(RunMetrics {
        fused,
        fused_se3_aligned: aligned,
        odometry_imu,
        frames: result.frames.len(),
        fused_frames: result.fused_frames(),
        corrected_frames: result.frames.iter().filter(|f| f.status.corrected()).count(),
        mean_total_ms: result.mean_total_ms(),
    }))
}

impl RunResult {
    /// Frames corrected with the camera's corners in the solve.
    pub fn fused_frames(&self) -> usize {
        self.frames
            .iter()
            .filter(|f| matches!(f.status, crate::estimation::pipeline::FrameStatus::Fused { .. }))
            .count()
    }

    /// A frame's mean time, all stages.
    pub fn mean_total_ms(&self) -> f64 {
        self.frames.iter().map(|f| f.total_ms).sum::<f64>() / self.frames.len().max(1) as f64
    }
}

/// The longest time between two scans and the scan that ended it, when it
/// is more than three times the typical (median) time: a LIDAR gap.
pub fn longest_scan_gap(frames: &[FrameReport]) -> Option<(f64, f64)> {
    let mut gaps: Vec<f64> = frames.iter().skip(1).map(|f| f.scan_gap_s).collect();
    gaps.sort_by(f64::total_cmp);
    let typical = *gaps.get(gaps.len() / 2)?;
    let longest = frames.iter().skip(1).max_by(|a, b| a.scan_gap_s.total_cmp(&b.scan_gap_s))?;
    (longest.scan_gap_s > 3.0 * typical).then_some((longest.scan_gap_s, longest.stamp))
}

/// The longest hole in the odometry and in the IMU log, each where it is
/// more than ten times the log's typical (median) interval and over
/// `MIN_LOG_GAP_S`: across it the motion is interpolated, not measured.
/// Returns (log, gap in seconds, the stamp that ended it).
pub fn log_gaps(sequence: &dyn SensorSequence) -> Vec<(crate::input::sequence::MotionLog, f64, f64)> {
    use crate::input::sequence::MotionLog;
    let odometry: Vec<f64> = sequence.odometry().iter().map(|s| s.timestamp).collect();
    let imu: Vec<f64> = sequence.imu().iter().map(|s| s.timestamp).collect();
    [(MotionLog::Odometry, odometry), (MotionLog::Imu, imu)]
        .into_iter()
        .filter_map(|(name, stamps)| {
            let mut gaps: Vec<f64> = stamps.windows(2).map(|w| w[1] - w[0]).collect();
            let (longest, k) = gaps.iter().enumerate().map(|(k, g)| (*g, k)).max_by(|a, b| a.0.total_cmp(&b.0))?;
            gaps.sort_by(f64::total_cmp);
            let typical = gaps[gaps.len() / 2];
            (longest > 10.0 * typical && longest > MIN_LOG_GAP_S).then_some((name, longest, stamps[k + 1]))
        })
        .collect()
}

/// What a finished run should warn about: frames that lost their corners or
/// their cloud (how many, and the first one's fault: frames.csv has every
/// frame's), a LIDAR gap, holes in the motion logs, ground truth that gave
/// no metrics.
pub fn run_warnings(sequence: &dyn SensorSequence, result: &RunResult, metrics: Option<&RunMetrics>) -> Vec<String> {
    let mut out = Vec::new();
    if sequence.ground_truth().is_some() && result.truth_origin.is_none() {
        out.push(
            "the map was written by a run without ground truth, so this run's ground truth cannot be put in the \
             map's frame: no metrics.json"
                .to_string(),
        );
    } else if sequence.ground_truth().is_some() && metrics.is_none() {
        out.push("the ground truth does not overlap the run's times (within 0.01 s): no metrics.json".to_string());
    }
    let n = result.frames.len();
    let lost = |what: &str, fault: &dyn Fn(&FrameStatus) -> Option<&FrameFault>| {
        let faults: Vec<&FrameFault> = result.frames.iter().filter_map(|f| fault(&f.status)).collect();
        faults.first().map(|why| format!("{} of {n} frames had {what}, the first because: {why}", faults.len()))
    };
    out.extend(lost("no 2D corners", &|s| if let FrameStatus::NoImage { why, .. } = s { Some(why) } else { None }));
    out.extend(lost("no usable cloud", &|s| if let FrameStatus::BadCloud(why) = s { Some(why) } else { None }));
    if let Some((gap, stamp)) = longest_scan_gap(&result.frames) {
        out.push(format!("no scan for {gap:.2} s before the scan at {stamp:.3} (odometry/IMU carried the pose)"));
    }
    for (log, gap, stamp) in log_gaps(sequence) {
        let source = sequence.log_source(log);
        out.push(format!(
            "{log} ({source}) has no sample for {gap:.2} s before {stamp:.3} s (the motion across it is interpolated)"
        ));
    }
    out
}

/// The run's metrics as the terminal shows them: frames, then RMSE per axis
/// and ATE per level for the fused trajectory, the odometry/IMU reference
/// (`with_reference`: left out where the rig has neither) and the
/// SE3-aligned fused one.
pub fn metrics_table(m: &RunMetrics, with_reference: bool) -> String {
    let mut out = format!(
        "{} frames, {} corrected ({} with the camera's corners), {:.1} ms per frame\n",
        m.frames, m.corrected_frames, m.fused_frames, m.mean_total_ms
    );
    let row = |out: &mut String, name: &str, s: &ErrorSummary| {
        let _ = writeln!(out, "{:<22} {:>8.4} {:>8.4} {:>8.4} {:>8.4}", name, s.rmse_x, s.rmse_y, s.rmse_z, s.ate_rmse);
    };
    let _ = writeln!(out, "{:<22} {:>8} {:>8} {:>8} {:>8}", "", "rmse_x", "rmse_y", "rmse_z", "ate");
    let reference = with_reference.then_some(("odometry/IMU", &m.odometry_imu));
    for (name, t) in [("fused", &m.fused)].into_iter().chain(reference) {
        for (level, s) in t.levels.iter().map(|l| (l.name.as_str(), &l.errors)).chain([("all", &t.overall)]) {
            row(&mut out, &format!("{name} {level}"), s);
        }
    }
    if let Some(s) = &m.fused_se3_aligned {
        row(&mut out, "fused, SE3-aligned", s);
    }
    out
}

/// Shorter holes in a log are not reported (a 50 Hz log's jitter).
const MIN_LOG_GAP_S: f64 = 0.2;

pub const FRAME_COLUMNS: &str = "timestamp,scan_gap_s,x,y,z,status,detections,planes,corners,matches,correspondences,plane_correspondences,scan_correspondences,\
level_floor,landmarks,detect_ms,normals_ms,planes_ms,corners_ms,fusion_ms,scan_ms,pose_ms,total_ms";

pub fn frames_csv(frames: &[FrameReport]) -> String {
    let mut out = String::from(FRAME_COLUMNS);
    out.push('\n');
    for f in frames {
        let t = f.pose.translation.vector;
        let _ = writeln!(
            out,
            "{:.6},{:.3},{:.4},{:.4},{:.4},{},{},{},{},{},{},{},{},{},{},{:.1},{:.1},{:.1},{:.1},{:.1},{:.1},{:.1},{:.1}",
            f.stamp,
            f.scan_gap_s,
            t.x,
            t.y,
            t.z,
            f.status.label().replace(',', ";"),
            f.detections,
            f.planes,
            f.corners,
            f.matches,
            f.correspondences,
            f.plane_correspondences,
            f.scan_correspondences,
            u8::from(f.level_floor),
            f.landmarks,
            f.detect_ms,
            f.normals_ms,
            f.planes_ms,
            f.corners_ms,
            f.fusion_ms,
            f.scan_ms,
            f.pose_ms,
            f.total_ms
        );
    }
    out
}

/// The files `localize run` writes into its output folder, and nothing else.
pub const RUN_OUTPUTS: [&str; 9] = [
    "trajectory.txt",
    "reference.txt",
    "frames.csv",
    "config.json",
    "trajectory.png",
    "metrics.json",
    "map.ply",
    "map.json",
    "groundtruth.txt",
];

/// Writes the run's outputs as one unit: the folder is filled beside its
/// final name and then takes its place, so files of an earlier run never
/// stay beside the new ones and a killed run leaves the old folder whole.
/// A folder holding anything else than an earlier run's outputs is refused
/// rather than replaced (it may be the user's data).
pub fn write_outputs(
    out: &Path,
    config: &LocalizeConfig,
    result: &RunResult,
    truth: Option<&Trajectory>,
    metrics: Option<&RunMetrics>,
) -> Result<()> {
    check_output_folder(out)?;
    datasets::atomic::write_dir(out, |dir| -> Result<()> {
        write_tum(&dir.join("trajectory.txt"), &result.trajectory)?;
        write_tum(&dir.join("reference.txt"), &result.reference)?;
        datasets::atomic::write_bytes(&dir.join("frames.csv"), frames_csv(&result.frames).as_bytes())?;
        datasets::atomic::write_json(&dir.join("config.json"), config)?;
        crate::evaluation::plot::write_trajectory_png(
            &dir.join("trajectory.png"),
            &result.trajectory,
            &result.reference,
            truth,
        )?;
        let map = crate::map_output::SavedMap {
            corners: result.corner_landmarks.clone(),
            walls: result.plane_landmarks.clone(),
            wall_axis: result.wall_axis,
            points: result.point_map.clone(),
            keyframes: result.keyframes.clone(),
            truth_origin: result.truth_origin,
        };
        crate::map_output::write_map(dir, &map)?;
        if let Some(m) = metrics {
            datasets::atomic::write_json(&dir.join("metrics.json"), m)?;
        }
        // The truth in the run's world: other tools' trajectories started
        // there score against it (`localize eval`).
        if let Some(truth) = truth {
            write_tum(&dir.join("groundtruth.txt"), truth)?;
        }
        Ok(())
    })
}

/// Refuses an output folder that holds files `localize run` did not write
/// (temporary files a killed writer left are its own).
pub fn check_output_folder(out: &Path) -> Result<()> {
    let Some(entries) = writable_output_folder(out)? else { return Ok(()) };
    for entry in entries {
        let entry = entry.map_err(|e| datasets::DataError::io(out, e))?;
        let name = entry.file_name().to_string_lossy().into_owned();
        if !RUN_OUTPUTS.contains(&name.as_str()) && !name.starts_with(".tmp-") {
            return Err(datasets::DataError::invalid(
                out,
                format!(
                    "holds `{name}`, which is not an output of a localization run: give an empty or new folder \
                     (an earlier run's folder is replaced whole)"
                ),
            )
            .into());
        }
    }
    Ok(())
}

/// Refuses an output that is a file or cannot be written, before any work;
/// the entries of the folder when it exists, for the caller's rule on what
/// it may already hold.
pub fn writable_output_folder(out: &Path) -> Result<Option<std::fs::ReadDir>> {
    if out.exists() && !out.is_dir() {
        return Err(datasets::DataError::invalid(out, "the output is not a folder").into());
    }
    datasets::atomic::check_writable(out)?;
    Ok(std::fs::read_dir(out).ok())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_detector_clock_takes_every_other_scan_of_a_10_hz_lidar_at_5_hz() {
        let mut clock = DetectorClock { rate_hz: 5.0, last: None };
        // Scan stamps with a little jitter, as a driver writes them.
        let stamps = [0.0, 0.1, 0.2001, 0.2999, 0.3898, 0.5, 0.6, 0.75, 0.8];
        let taken: Vec<f64> = stamps.iter().copied().filter(|&t| clock.take(t).is_ok()).collect();
        assert_eq!(taken, [0.0, 0.2001, 0.3898, 0.6, 0.8]);
        let why = clock.take(0.85).unwrap_err();
        assert_eq!(why, FrameFault::DetectorSkipped { rate_hz: 5.0 });
        let mut every = DetectorClock { rate_hz: 0.0, last: None };
        assert!(stamps.iter().all(|&t| every.take(t).is_ok()));
    }
}
