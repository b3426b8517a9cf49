//! `localize benchmark`: generated buildings the detector and the settings
//! were never tuned on, driven at several speeds with a robot's sensor
//! timing, localized by the fused pipeline, by the same without the camera,
//! by the paper's estimator (no scan matching) and by odometry/IMU alone,
//! beside the LIDAR odometry peers whose trajectories a script left in the
//! folder. One table out, as Markdown, CSV and JSON.
//!
//! Layout of `--out`: `building-N/speed-S/` (`building-0-seed-K/speed-S/`
//! for the paper's building at another seed) holds the generated data
//! (`sequence/`, `detection/`, `preview/topdown.png`), `run/` the fused run's
//! outputs, `run-without-camera/` and `run-without-scan-match/` the two
//! ablations', `benchmark-run.json` their figures and what made them (so an
//! unchanged run is not redone; beside the run folders, which `localize run`
//! replaces whole), and `peers/NAME.txt` (TUM, robot frame) any
//! peer's trajectory.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use datasets::InvalidSetting;
use datasets::io::formats::read_trajectory;
use datasets::simulator::generate::{DatagenConfig, generate};
use indicatif::{ProgressBar, ProgressStyle};
use serde::{Deserialize, Serialize};

use crate::config::LocalizeConfig;
use crate::error::{LocalizeError, Result};
use crate::evaluation::eval::{Alignment, ErrorSummary, compare};
use crate::input::corner_source::CornerSource;
use crate::input::sensor_faults::{SensorFaults, WithChanges};
use crate::input::sensor_set::SensorSet;
use crate::input::sequence::RecordedSequence;
use crate::run::{RunMetrics, metrics_against, run_sequence, truth_in_run_frame, write_outputs};

/// The LIDAR odometry systems `scripts/lidar_peers.py` runs.
pub const PEERS: [&str; 2] = ["kiss-icp", "genz-icp"];

/// What the benchmark runs.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct BenchmarkPlan {
    pub buildings: Vec<u32>,
    pub speeds_mps: Vec<f64>,
    /// Scans per sequence at most (10 per second of driving).
    pub max_scans: usize,
    /// Labelled images per building for the detector's AP@0.5.
    pub detection_images: usize,
    pub seed: u64,
    /// More seeds for the paper's building (0): its appearance, lighting
    /// and sensor noise drawn again, the geometry the same.
    #[serde(default)]
    pub paper_seeds: Vec<u64>,
}

impl BenchmarkPlan {
    /// Five buildings at three speeds, a minute of driving each.
    pub fn standard() -> Self {
        Self {
            buildings: (1..=5).collect(),
            speeds_mps: vec![0.05, 0.5, 1.0],
            max_scans: 600,
            detection_images: 60,
            seed: 7,
            paper_seeds: Vec::new(),
        }
    }

    /// Two buildings at one speed, 15 s each: a few minutes in all.
    pub fn quick() -> Self {
        Self {
            buildings: vec![1, 2],
            speeds_mps: vec![1.0],
            max_scans: 150,
            detection_images: 16,
            seed: 7,
            paper_seeds: Vec::new(),
        }
    }

    pub fn validate(&self) -> std::result::Result<(), InvalidSetting> {
        if self.buildings.is_empty() {
            return Err(InvalidSetting::field("buildings", "needs at least one building"));
        }
        if self.speeds_mps.is_empty() {
            return Err(InvalidSetting::field("speeds_mps", "needs at least one speed"));
        }
        if let Some(b) = self.buildings.iter().find(|&&b| b > datasets::simulator::world::building::MAX_BUILDING) {
            let problem = format!(
                "building {b} is neither the paper's (0) nor a generated one (1..={})",
                datasets::simulator::world::building::MAX_BUILDING
            );
            return Err(InvalidSetting::field("buildings", problem));
        }
        if let Some(s) = self.speeds_mps.iter().find(|s| !(**s >= 0.05 && **s <= 1.5)) {
            return Err(InvalidSetting::field("speeds_mps", format!("{s} m/s outside [0.05, 1.5]")));
        }
        if !(10..=3000).contains(&self.max_scans) {
            return Err(InvalidSetting::field("max_scans", format!("{} outside 10..=3000", self.max_scans)));
        }
        if self.detection_images > 2000 {
            return Err(InvalidSetting::field(
                "detection_images",
                format!("{} is more than 2000", self.detection_images),
            ));
        }
        Ok(())
    }

    /// The seeds building `building` runs at: the plan's, and for the
    /// paper's building the extra ones.
    pub fn seeds_of(&self, building: u32) -> Vec<u64> {
        let mut seeds = vec![self.seed];
        if building == 0 {
            for &seed in &self.paper_seeds {
                if !seeds.contains(&seed) {
                    seeds.push(seed);
                }
            }
        }
        seeds
    }

    /// The data settings of one sequence (building 0 keeps the paper's 1 Hz
    /// timing); the first speed of a building and seed also renders its
    /// labelled images.
    pub fn datagen(&self, building: u32, seed: u64, speed: f64, first_speed: bool) -> DatagenConfig {
        let mut config = DatagenConfig::for_building(building);
        config.seed = seed;
        config.sequence.speed_mps = speed;
        config.sequence.max_scans = Some(self.max_scans);
        let images = if first_speed { self.detection_images } else { 0 };
        config.detection.images = images;
        config.detection.train = 0;
        config
    }
}

/// One sequence's figures.
#[derive(Debug, Clone, Serialize)]
pub struct BenchmarkRow {
    pub building: u32,
    pub seed: u64,
    pub speed_mps: f64,
    pub levels: usize,
    pub scans: usize,
    pub distance_m: f64,
    pub fused: ErrorSummary,
    pub odometry_imu: ErrorSummary,
    /// The same estimator without the camera (LIDAR and odometry/IMU).
    pub without_camera: ErrorSummary,
    /// The paper's estimator: corners and walls, no scan-to-map registration.
    pub without_scan_match: ErrorSummary,
    /// The 3D sensor alone: no camera, no IMU, no wheels (as KISS-ICP runs).
    pub lidar_alone: ErrorSummary,
    /// Frames whose pose the corners, walls or scan corrected.
    pub corrected_frames: usize,
    pub ms_per_frame: f64,
    /// The detector's AP@0.5 on the building's own labelled images.
    pub ap50: Option<f64>,
    /// Each peer's errors, when its trajectory is in the folder.
    pub peers: Vec<(String, Option<ErrorSummary>)>,
}

/// `building-N/speed-S`, or `building-N-seed-K/speed-S` for a seed other than the plan's.
fn sequence_dir(out: &Path, plan: &BenchmarkPlan, building: u32, seed: u64, speed: f64) -> PathBuf {
    let name =
        if seed == plan.seed { format!("building-{building}") } else { format!("building-{building}-seed-{seed}") };
    out.join(name).join(format!("speed-{speed}"))
}

/// Generates what is missing (a folder whose `benchmark-data.json` holds the
/// same settings is reused), runs every sequence and returns the rows.
pub fn run_benchmark(
    out: &Path,
    plan: &BenchmarkPlan,
    checkpoint: &Path,
    device: burn::prelude::Device,
    config: &LocalizeConfig,
    show_progress: bool,
) -> Result<Vec<BenchmarkRow>> {
    plan.validate()?;
    let cases: Vec<(u32, u64, f64, bool)> = plan
        .buildings
        .iter()
        .flat_map(|&b| plan.seeds_of(b).into_iter().map(move |seed| (b, seed)))
        .flat_map(|(b, seed)| plan.speeds_mps.iter().enumerate().map(move |(i, &s)| (b, seed, s, i == 0)))
        .collect();
    let bar = if show_progress { ProgressBar::new(cases.len() as u64 * 2) } else { ProgressBar::hidden() };
    bar.set_style(
        ProgressStyle::with_template("benchmark [{elapsed_precise}] {bar:30} {pos}/{len} steps ({eta}) {msg}")
            .expect("static template"),
    );
    let mut source = CornerSource::detector(checkpoint, device.clone(), config.fusion.min_score)?;
    let detector = infer::detector::Detector::load(checkpoint, device)?;
    // A sequence's run is redone when anything that made it changed.
    let made_by = serde_json::json!({
        "localize": config,
        "detector": [
            datasets::fingerprint::of_file(&checkpoint.join(infer::checkpoint::CONFIG_FILE))?,
            datasets::fingerprint::of_file(&checkpoint.join(infer::checkpoint::WEIGHTS_FILE))?,
        ],
        "program": datasets::fingerprint::of_program()?,
    });
    let mut rows = Vec::new();
    for (building, seed, speed, first) in cases {
        let dir = sequence_dir(out, plan, building, seed, speed);
        let data = plan.datagen(building, seed, speed, first);
        let case =
            if seed == plan.seed { format!("building {building}") } else { format!("building {building} seed {seed}") };
        bar.set_message(format!("{case} at {speed} m/s: data"));
        ensure_data(&dir, &data)?;
        bar.inc(1);
        let sequence = RecordedSequence::open_with(&dir.join("sequence"), &config.sync)?;
        let measures_ap = first && plan.detection_images > 0;
        let inputs = serde_json::json!({ "data": data, "made_by": made_by, "ap50": measures_ap });
        let record = match SequenceRecord::read(&dir, &inputs) {
            Some(record) => record,
            None => {
                let progress = |what: &str| bar.set_message(format!("{case} at {speed} m/s: {what}"));
                let record = measure_sequence(&dir, &sequence, &mut source, &detector, config, measures_ap, &progress)?;
                record.write(&dir, &inputs)?;
                record
            }
        };
        bar.inc(1);
        let (distance_m, peers) = route_and_peers(&dir, &sequence)?;
        let levels = datasets::simulator::world::World::new(&data.world, 0).layout.levels.len();
        rows.push(BenchmarkRow {
            building,
            seed,
            speed_mps: speed,
            levels,
            scans: record.scans,
            distance_m,
            fused: record.fused,
            odometry_imu: record.odometry_imu,
            without_camera: record.without_camera,
            without_scan_match: record.without_scan_match,
            lidar_alone: record.lidar_alone,
            corrected_frames: record.corrected_frames,
            ms_per_frame: record.ms_per_frame,
            ap50: record.ap50,
            peers,
        });
    }
    bar.finish_and_clear();
    fill_building_aps(&mut rows);
    Ok(rows)
}

/// A building's AP is measured once per seed, at its first speed: its other
/// speeds' rows repeat it.
fn fill_building_aps(rows: &mut [BenchmarkRow]) {
    let aps: Vec<((u32, u64), Option<f64>)> =
        rows.iter().filter(|r| r.ap50.is_some()).map(|r| ((r.building, r.seed), r.ap50)).collect();
    for row in rows {
        if row.ap50.is_none() {
            row.ap50 = aps.iter().find(|(key, _)| *key == (row.building, row.seed)).and_then(|(_, ap)| *ap);
        }
    }
}

/// A peer's name and its errors, when its trajectory is there.
type PeerErrors = (String, Option<ErrorSummary>);

/// The sequence's route length, and each peer's errors where its trajectory
/// is in `dir/peers/`.
fn route_and_peers(dir: &Path, sequence: &RecordedSequence) -> Result<(f64, Vec<PeerErrors>)> {
    // The peers' world, like a run's, is the robot at the first scan.
    let raw = sequence_truth(sequence).expect("a generated sequence has ground truth");
    let truth =
        &crate::input::sequence::relative_to(raw, &crate::input::sequence::truth_at(raw, sequence.frames[0].stamp));
    let distance_m = truth.poses.windows(2).map(|w| (w[1].translation.vector - w[0].translation.vector).norm()).sum();
    let peers = PEERS
        .iter()
        .map(|name| {
            let path = dir.join("peers").join(format!("{name}.txt"));
            let summary = path.is_file().then(|| peer_errors(&path, truth)).transpose()?;
            Ok((name.to_string(), summary))
        })
        .collect::<Result<Vec<_>>>()?;
    Ok((distance_m, peers))
}

/// A sequence's runs: fused, without the camera, without scan matching
/// (the paper's estimator), the LIDAR alone, and (at a building's first
/// speed) the detector's AP@0.5 on its labelled images.
fn measure_sequence(
    dir: &Path,
    sequence: &RecordedSequence,
    source: &mut CornerSource,
    detector: &infer::detector::Detector,
    config: &LocalizeConfig,
    measures_ap: bool,
    progress: &dyn Fn(&str),
) -> Result<SequenceRecord> {
    progress("localizing");
    // Records were once kept inside `run/`, which a new run must replace whole.
    let _ = std::fs::remove_file(dir.join("run").join(RECORD_FILE));
    let measured = localize_into(dir, "run", sequence, source, config)?;
    progress("without the camera");
    let without_camera = localize_into(dir, "run-without-camera", sequence, &mut CornerSource::Off, config)?;
    progress("without scan matching");
    let mut paper = config.clone();
    paper.scan_match.enabled = false;
    let without_scan_match = localize_into(dir, "run-without-scan-match", sequence, source, &paper)?;
    progress("LIDAR alone");
    let lidar_alone = lidar_alone_into(dir, config)?;
    let ap50 = if measures_ap {
        let test = dir.join("detection").join("test.json");
        let set = infer::labeled::load_coco_set(&test, &detector.config.preprocess)?;
        Some(infer::eval::evaluate_set(detector, &set, 4).ap50)
    } else {
        None
    };
    Ok(SequenceRecord {
        fused: measured.fused.overall,
        odometry_imu: measured.odometry_imu.overall,
        without_camera: without_camera.fused.overall,
        without_scan_match: without_scan_match.fused.overall,
        lidar_alone: lidar_alone.fused.overall,
        scans: measured.frames,
        corrected_frames: measured.corrected_frames,
        ms_per_frame: measured.mean_total_ms,
        ap50,
    })
}

/// What a sequence's fused run measured, kept in `run/` with what made it
/// (the data's settings, the localization settings, the detector's files and
/// the program), so that a second benchmark (to add the peers' columns, or
/// after a crash) redoes only what changed.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SequenceRecord {
    pub fused: ErrorSummary,
    pub odometry_imu: ErrorSummary,
    pub without_camera: ErrorSummary,
    pub without_scan_match: ErrorSummary,
    pub lidar_alone: ErrorSummary,
    pub scans: usize,
    pub corrected_frames: usize,
    pub ms_per_frame: f64,
    pub ap50: Option<f64>,
}

/// The record's file inside a sequence folder.
const RECORD_FILE: &str = "benchmark-run.json";

impl SequenceRecord {
    /// The record of `dir` when it was made from `inputs`; `None` when there
    /// is none, it is unreadable or anything differs.
    pub fn read(dir: &Path, inputs: &serde_json::Value) -> Option<Self> {
        let text = std::fs::read_to_string(dir.join(RECORD_FILE)).ok()?;
        let file: serde_json::Value = serde_json::from_str(&text).ok()?;
        if file.get("inputs") != Some(inputs) {
            return None;
        }
        serde_json::from_value(file.get("record")?.clone()).ok()
    }

    pub fn write(&self, dir: &Path, inputs: &serde_json::Value) -> Result<()> {
        let file = serde_json::json!({ "inputs": inputs, "record": self });
        Ok(datasets::atomic::write_json(&dir.join(RECORD_FILE), &file)?)
    }
}

/// Localizes `sequence` with `source` and `config` into `dir/name` and
/// returns its metrics.
/// The sequence of `dir` run with its 3D sensor alone (no camera, IMU or
/// wheels), with the settings that follow from that over `config`.
fn lidar_alone_into(dir: &Path, config: &LocalizeConfig) -> Result<RunMetrics> {
    let inner = RecordedSequence::open_with(&dir.join("sequence"), &config.sync)?;
    let faults = SensorFaults { without_imu: true, without_wheels: true, ..SensorFaults::default() };
    let alone = WithChanges { inner: Box::new(inner), truth: None, faults };
    let mut config = config.clone();
    SensorSet::of(&alone, false).adapt(&mut config);
    localize_into(dir, "run-lidar-alone", &alone, &mut CornerSource::Off, &config)
}

fn localize_into(
    dir: &Path,
    name: &str,
    sequence: &dyn crate::input::sequence::SensorSequence,
    source: &mut CornerSource,
    config: &LocalizeConfig,
) -> Result<RunMetrics> {
    let result = run_sequence(sequence, source, config, false)?;
    let no_overlap = || LocalizeError::Sequence {
        path: dir.to_path_buf(),
        message: "the ground truth does not overlap the run".into(),
    };
    let truth = truth_in_run_frame(sequence, &result).ok_or_else(no_overlap)?;
    let measured = metrics_against(sequence, &result, Some(&truth))?.ok_or_else(no_overlap)?;
    write_outputs(&dir.join(name), config, &result, Some(&truth), Some(&measured))?;
    Ok(measured)
}

fn sequence_truth(sequence: &RecordedSequence) -> Option<&datasets::io::formats::Trajectory> {
    crate::input::sequence::SensorSequence::ground_truth(sequence)
}

/// The errors of a peer's trajectory (robot frame, world at the first scan).
fn peer_errors(path: &Path, truth: &datasets::io::formats::Trajectory) -> Result<ErrorSummary> {
    let (estimate, _) = read_trajectory(path)?;
    estimate.check_increasing(path)?;
    let comparison = compare(truth, &estimate, Alignment::None, 0.01)
        .map_err(|source| LocalizeError::Compare { path: path.to_path_buf(), source })?;
    Ok(comparison.summary)
}

/// Generates `dir` unless it holds a finished generation with `config`.
fn ensure_data(dir: &Path, config: &DatagenConfig) -> Result<()> {
    let marker = dir.join("benchmark-data.json");
    if let Ok(text) = std::fs::read_to_string(&marker)
        && serde_json::from_str::<DatagenConfig>(&text).is_ok_and(|c| c == *config)
    {
        return Ok(());
    }
    // A changed or unfinished generation starts from an empty folder.
    let _ = std::fs::remove_file(&marker);
    let _ = std::fs::remove_file(dir.join(RECORD_FILE));
    for part in ["sequence", "detection", "preview", "run", "run-without-camera", "run-without-scan-match"] {
        let path = dir.join(part);
        if path.exists() {
            std::fs::remove_dir_all(&path).map_err(|e| datasets::DataError::io(&path, e))?;
        }
    }
    generate(dir, config)?;
    datasets::atomic::write_json(&marker, config)?;
    Ok(())
}

fn fmt_mm(v: f64) -> String {
    format!("{:.1}", v * 1000.0)
}

/// Parses a building list: `3`, `1-5`, `1,4,7` or `1-3,8`.
pub fn parse_buildings(text: &str) -> std::result::Result<Vec<u32>, String> {
    let mut out = Vec::new();
    for part in text.split(',').map(str::trim) {
        let number =
            |s: &str| s.trim().parse::<u32>().map_err(|_| format!("`{s}` in `{text}` is not a building number"));
        if part.starts_with('-') {
            return Err(format!("`{part}`: building numbers are whole numbers from 0 (0: the paper's building)"));
        }
        match part.split_once('-') {
            Some((a, b)) => {
                let (a, b) = (number(a)?, number(b)?);
                if a > b || b - a > 1000 {
                    return Err(format!("`{part}` is not a range of at most 1000 buildings"));
                }
                out.extend(a..=b);
            }
            None => out.push(number(part)?),
        }
    }
    Ok(out)
}

/// Parses a speed list: `0.05,0.5,1.0`.
pub fn parse_speeds(text: &str) -> std::result::Result<Vec<f64>, String> {
    text.split(',')
        .map(|s| s.trim().parse::<f64>().map_err(|_| format!("`{s}` in `{text}` is not a speed in m/s")))
        .collect()
}

/// The table as Markdown: errors in millimetres.
pub fn markdown(rows: &[BenchmarkRow]) -> String {
    let mut out = String::from(
        "| building | seed | levels | speed m/s | scans | distance m | fused x | fused y | fused z | fused ATE | \
         without camera ATE | without scan matching ATE | LIDAR alone ATE | odom/IMU ATE |",
    );
    for p in PEERS {
        let _ = write!(out, " {p} x | {p} y | {p} ATE |");
    }
    out.push_str(" corrected | ms/frame | AP@0.5 |\n|");
    for _ in 0..(14 + 3 * PEERS.len() + 3) {
        out.push_str("---:|");
    }
    out.push('\n');
    for r in rows {
        let _ = write!(
            out,
            "| {} | {} | {} | {} | {} | {:.1} | {} | {} | {} | {} | {} | {} | {} | {} |",
            r.building,
            r.seed,
            r.levels,
            r.speed_mps,
            r.scans,
            r.distance_m,
            fmt_mm(r.fused.rmse_x),
            fmt_mm(r.fused.rmse_y),
            fmt_mm(r.fused.rmse_z),
            fmt_mm(r.fused.ate_rmse),
            fmt_mm(r.without_camera.ate_rmse),
            fmt_mm(r.without_scan_match.ate_rmse),
            fmt_mm(r.lidar_alone.ate_rmse),
            fmt_mm(r.odometry_imu.ate_rmse)
        );
        for (_, peer) in &r.peers {
            match peer {
                Some(s) => {
                    let _ = write!(out, " {} | {} | {} |", fmt_mm(s.rmse_x), fmt_mm(s.rmse_y), fmt_mm(s.ate_rmse));
                }
                None => out.push_str(" - | - | - |"),
            }
        }
        let ap = r.ap50.map_or("-".to_string(), |a| format!("{a:.3}"));
        let _ = writeln!(out, " {}/{} | {:.1} | {ap} |", r.corrected_frames, r.scans, r.ms_per_frame);
    }
    out
}

/// The table as CSV: errors in metres.
pub fn csv(rows: &[BenchmarkRow]) -> String {
    let mut out = String::from(
        "building,seed,levels,speed_mps,scans,distance_m,fused_rmse_x,fused_rmse_y,fused_rmse_z,fused_ate,\
         without_camera_ate,without_scan_match_ate,lidar_alone_ate,odometry_imu_ate",
    );
    for p in PEERS {
        let p = p.replace('-', "_");
        let _ = write!(out, ",{p}_rmse_x,{p}_rmse_y,{p}_ate");
    }
    out.push_str(",corrected_frames,ms_per_frame,ap50\n");
    for r in rows {
        let _ = write!(
            out,
            "{},{},{},{},{},{:.3},{:.6},{:.6},{:.6},{:.6},{:.6},{:.6},{:.6},{:.6}",
            r.building,
            r.seed,
            r.levels,
            r.speed_mps,
            r.scans,
            r.distance_m,
            r.fused.rmse_x,
            r.fused.rmse_y,
            r.fused.rmse_z,
            r.fused.ate_rmse,
            r.without_camera.ate_rmse,
            r.without_scan_match.ate_rmse,
            r.lidar_alone.ate_rmse,
            r.odometry_imu.ate_rmse
        );
        for (_, peer) in &r.peers {
            match peer {
                Some(s) => {
                    let _ = write!(out, ",{:.6},{:.6},{:.6}", s.rmse_x, s.rmse_y, s.ate_rmse);
                }
                None => out.push_str(",,,"),
            }
        }
        let ap = r.ap50.map_or(String::new(), |a| format!("{a:.4}"));
        let _ = writeln!(out, ",{},{:.2},{ap}", r.corrected_frames, r.ms_per_frame);
    }
    out
}

/// Writes `benchmark.md`, `benchmark.csv` and `benchmark.json` into `out`.
pub fn write_tables(out: &Path, plan: &BenchmarkPlan, rows: &[BenchmarkRow]) -> Result<()> {
    datasets::atomic::write_bytes(&out.join("benchmark.md"), markdown(rows).as_bytes())?;
    datasets::atomic::write_bytes(&out.join("benchmark.csv"), csv(rows).as_bytes())?;
    datasets::atomic::write_json(&out.join("benchmark.json"), &serde_json::json!({ "plan": plan, "rows": rows }))?;
    Ok(())
}
