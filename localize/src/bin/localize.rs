//! `localize`: run localization on a recorded sequence, extract the planes and
//! corners of one cloud, or evaluate a trajectory against ground truth.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use clap::{Parser, Subcommand};
use datasets::io::formats::read_trajectory;
use infer::detector_args::{BackendArg, DetectorArgs, SHIPPED_CHECKPOINT};
use localize::config::LocalizeConfig;
use localize::evaluation::eval::{Alignment, ErrorSummary, compare};
use localize::evaluation::levels::LevelMap;
use localize::input::bag_sequence::{BagOptions, BagSequence};
use localize::input::corner_source::CornerSource;
use localize::input::rgbd_sequence::RgbdSequence;
use localize::input::sensor_faults::{SensorFaults, WithChanges};
use localize::input::sensor_set::{RangeSensor, SensorSet};
use localize::input::sequence::{RecordedSequence, SensorSequence};
use localize::run::{MapStart, metrics_against, run_sequence_in_map, truth_in_run_frame, write_outputs};

#[derive(Parser)]
#[command(name = "localize", about = "Corner-fusion localization: camera corners + LIDAR planes")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Compares an estimated trajectory with ground truth (TUM, KITTI or EuRoC, detected from the content).
    Eval(EvalArgs),
    /// Localizes a recorded sequence (a folder or a ROS bag): trajectory, per-frame log and, with ground truth, metrics and a picture.
    Run(Box<RunArgs>),
    /// Corner labels for a recording's own images from its own 3D sensor: a `train --data` folder to fine-tune the detector on.
    Autolabel(Box<AutolabelArgs>),
    /// Prints what a recording holds (as `ros2 bag info` does) and which topic each role would take.
    Inspect(InspectArgs),
    /// Fits the colour camera of an RGB-D folder whose colour is not registered to its depth
    /// (7-Scenes): writes a calib.json for `--calib`.
    RegisterColour(RegisterColourArgs),
    /// Prints the planes and 3D corners of one point cloud (PCD, PLY or KITTI .bin).
    Planes(PlanesArgs),
    /// Milliseconds per frame of each stage on M8-like scans and on dense 100k-point scans.
    Bench(BenchArgs),
    /// Generated buildings at several speeds: fused, odometry/IMU and LIDAR-odometry peers side by side.
    Benchmark(BenchmarkArgs),
}

#[derive(clap::Args)]
#[command(allow_negative_numbers = true)]
struct BenchmarkArgs {
    /// Folder of the generated data, the runs and the tables (reused when run again).
    #[arg(long)]
    out: PathBuf,
    /// Buildings: `1-5`, `2,4` (default 1-5; with --quick 1,2).
    #[arg(long)]
    buildings: Option<String>,
    /// Speeds in m/s (default 0.05,0.5,1.0; with --quick 1.0).
    #[arg(long)]
    speeds: Option<String>,
    /// Scans per sequence at most, at 10 Hz (default 600; with --quick 150).
    #[arg(long, value_parser = datasets::cli::positive_count)]
    max_scans: Option<usize>,
    /// Labelled images per building for the detector's AP@0.5 (default 60; with --quick 16).
    #[arg(long, value_parser = datasets::cli::positive_count)]
    detection_images: Option<usize>,
    /// More seeds for the paper's building (0) when it is among --buildings:
    /// `8,9` (its appearance, lighting and sensor noise drawn again).
    #[arg(long, value_delimiter = ',')]
    paper_seeds: Vec<u64>,
    /// A few minutes instead of about an hour: two buildings, one speed, short sequences.
    #[arg(long)]
    quick: bool,
    #[command(flatten)]
    detector: DetectorArgs,
    /// Localization settings as JSON (see config.json of a run).
    #[arg(long)]
    config: Option<PathBuf>,
    /// Print the table as JSON instead of Markdown.
    #[arg(long)]
    json: bool,
}

#[derive(clap::Args)]
#[command(allow_negative_numbers = true)]
struct BenchArgs {
    /// Scans of each kind, taken along the built-in route.
    #[arg(long, default_value_t = 20, value_parser = datasets::cli::positive_count)]
    frames: usize,
    /// The detector timed (skipped when its checkpoint folder is missing).
    #[command(flatten)]
    detector: DetectorArgs,
    /// Also compare the organised and the exact normals on this cloud (PCD,
    /// PLY or KITTI .bin, seen from its viewpoint); repeat for more.
    #[arg(long = "cloud", value_name = "FILE")]
    clouds: Vec<PathBuf>,
    #[arg(long)]
    json: bool,
}

#[derive(clap::Args)]
#[command(allow_negative_numbers = true)]
struct InspectArgs {
    /// A rosbag2 folder, an .mcap, a .db3 or a ROS 1 .bag.
    path: PathBuf,
    #[command(flatten)]
    topics: TopicArgs,
}

/// Which topics of a recording play which role (found by type when not given).
#[derive(clap::Args, Clone, Default)]
struct TopicArgs {
    #[arg(long)]
    lidar_topic: Option<String>,
    #[arg(long)]
    image_topic: Option<String>,
    #[arg(long)]
    camera_info_topic: Option<String>,
    #[arg(long)]
    imu_topic: Option<String>,
    #[arg(long)]
    odom_topic: Option<String>,
    /// A PoseStamped, PoseWithCovarianceStamped or Odometry topic with the ground truth.
    #[arg(long)]
    gt_topic: Option<String>,
    /// A depth image topic (16UC1 in mm or 32FC1 in m) as the 3D sensor, instead of a LIDAR.
    #[arg(long)]
    depth_topic: Option<String>,
    /// The robot's TF frame.
    #[arg(long, default_value = "base_link")]
    base_frame: String,
}

impl TopicArgs {
    fn options(&self, calib: Option<PathBuf>) -> localize::input::bag_sequence::BagOptions {
        localize::input::bag_sequence::BagOptions {
            lidar_topic: self.lidar_topic.clone(),
            image_topic: self.image_topic.clone(),
            camera_info_topic: self.camera_info_topic.clone(),
            imu_topic: self.imu_topic.clone(),
            odom_topic: self.odom_topic.clone(),
            gt_topic: self.gt_topic.clone(),
            depth_topic: self.depth_topic.clone(),
            depth: Default::default(),
            base_frame: Some(self.base_frame.clone()),
            calib,
        }
    }
}

/// The recording to localize, as `run` and `autolabel` take it.
#[derive(clap::Args)]
#[group(id = "input", required = true, multiple = false, args = ["sequence", "bag"])]
struct InputArgs {
    /// The sequence folder (cloud/, rgb/, [odom.csv], [imu.csv], calib.json[, groundtruth.txt]),
    /// or an RGB-D folder as published (TUM RGB-D's rgb.txt and depth.txt; 7-Scenes' frame-N files).
    #[arg(long)]
    sequence: Option<PathBuf>,
    /// A ROS recording: a rosbag2 folder, an .mcap, a .db3 or a ROS 1 .bag.
    #[arg(long)]
    bag: Option<PathBuf>,
    #[command(flatten)]
    topics: TopicArgs,
    /// A calib.json that replaces a bag's /tf_static and camera_info, or an
    /// RGB-D folder's colour camera (`localize register-colour` fits one).
    #[arg(long)]
    calib: Option<PathBuf>,
    /// Ground truth (TUM, KITTI or EuRoC) instead of the recording's.
    #[arg(long)]
    gt: Option<PathBuf>,
    /// A scan takes the nearest image within this many seconds (default 0.05, or the config's).
    #[arg(long, value_parser = datasets::cli::non_negative)]
    image_tolerance: Option<f64>,
    /// Settings as JSON (any subset of the sections; see config.json of a run).
    #[arg(long)]
    config: Option<PathBuf>,
}

#[derive(clap::Args)]
#[command(allow_negative_numbers = true)]
struct RunArgs {
    #[command(flatten)]
    input: InputArgs,
    #[command(flatten)]
    detector: DetectorArgs,
    #[arg(long)]
    out: PathBuf,
    /// Instead of the detector, take the 2D corners from this COCO file's
    /// ground-truth points plus Gaussian noise (for testing the geometry apart
    /// from the detector; never the default).
    #[arg(long, conflicts_with = "without_camera")]
    corners_from_labels: Option<PathBuf>,
    /// Leave the camera out: LIDAR (walls and scan-to-map registration) and
    /// odometry/IMU alone.
    #[arg(long)]
    without_camera: bool,
    /// Localize in the map an earlier run of the same building wrote (its
    /// output folder, with map.json and map.ply): the first scan is placed
    /// in it, searched within 1 m of the mapping run's route at every
    /// heading, and the trajectory is in the map's frame.
    #[arg(long)]
    map: Option<PathBuf>,
    /// Where in the map the sequence starts, roughly (x, y, z in metres and
    /// heading in degrees, the map's frame): the search stays near it.
    #[arg(long, value_name = "X,Y,Z,YAW_DEG", requires = "map", value_parser = parse_start_pose, allow_hyphen_values = true)]
    start_pose: Option<datasets::math::Pose3>,
    /// Simulate a LIDAR blackout: drop the scans from START to END seconds
    /// after the first scan (repeatable), to see how the run holds up.
    #[arg(long, value_name = "START:END", value_parser = localize::input::sensor_faults::parse_gap)]
    lidar_gap: Vec<[f64; 2]>,
    /// Simulate a camera that stops: no image from this many seconds after the first scan on.
    #[arg(long, value_name = "SECONDS", value_parser = datasets::cli::non_negative)]
    camera_stop: Option<f64>,
    /// Leave the recording's IMU out (the rate carries on from the previous motion).
    #[arg(long)]
    without_imu: bool,
    /// Leave the recording's wheel odometry out (the velocity carries on from the previous motion).
    #[arg(long)]
    without_wheels: bool,
    #[arg(long, default_value_t = 2.0, value_parser = datasets::cli::non_negative)]
    label_noise_px: f64,
    #[arg(long, default_value_t = 1)]
    seed: u64,
}

#[derive(clap::Args)]
#[command(allow_negative_numbers = true)]
struct AutolabelArgs {
    #[command(flatten)]
    input: InputArgs,
    /// The `train --data` folder to write (images/, train.json, test.json, autolabel.json, preview/, corners.ply).
    #[arg(long)]
    out: PathBuf,
    /// True labels to score the autolabels against (COCO, matched by image name);
    /// by default the recording folder's labels.json when it has one (generated sequences do).
    #[arg(long)]
    truth_labels: Option<PathBuf>,
    /// Autolabel settings as JSON (any subset; see autolabel.json of a run).
    #[arg(long)]
    autolabel_config: Option<PathBuf>,
    /// A detector whose confident detections that no 3D corner confirms are
    /// marked "unsure" (COCO ignore regions) rather than left as background.
    #[arg(long, default_value = SHIPPED_CHECKPOINT, conflicts_with = "without_teacher")]
    teacher: PathBuf,
    /// No teacher: only the 3D sensor's unsure corners become ignore regions.
    #[arg(long)]
    without_teacher: bool,
    #[command(flatten)]
    backend: BackendArg,
}

#[derive(clap::Args)]
struct RegisterColourArgs {
    /// An RGB-D folder (TUM RGB-D or 7-Scenes layout).
    #[arg(long)]
    sequence: PathBuf,
    /// The calib.json to write.
    #[arg(long)]
    out: PathBuf,
    /// Frames spread over the sequence whose contours are fitted.
    #[arg(long, default_value_t = 10, value_parser = datasets::cli::positive_count)]
    frames: usize,
}

#[derive(clap::Args)]
#[command(allow_negative_numbers = true)]
struct PlanesArgs {
    cloud: PathBuf,
    /// Print one JSON object instead of a table.
    #[arg(long)]
    json: bool,
}

#[derive(clap::Args)]
#[command(allow_negative_numbers = true)]
struct EvalArgs {
    /// Ground-truth trajectory: a TUM, KITTI or EuRoC file, or a recording with --gt-topic.
    #[arg(long)]
    gt: PathBuf,
    /// Estimated trajectory: a file, or a recording with --est-topic.
    #[arg(long)]
    est: PathBuf,
    /// The pose topic of --gt when it is a recording (as `evo_ape bag`).
    #[arg(long)]
    gt_topic: Option<String>,
    /// The pose topic of --est when it is a recording.
    #[arg(long)]
    est_topic: Option<String>,
    /// Alignment of the estimate onto the ground truth before errors are taken.
    #[arg(long, value_enum, default_value_t = Alignment::None)]
    align: Alignment,
    /// Largest timestamp difference (s) of an associated pair.
    #[arg(long, default_value_t = 0.01, value_parser = datasets::cli::positive)]
    max_diff: f64,
    /// The world description that says where the levels are; by default the
    /// `world.json` beside the ground truth, when there is one.
    #[arg(long)]
    world: Option<PathBuf>,
    /// Print one JSON object instead of a table.
    #[arg(long)]
    json: bool,
}

fn main() -> std::process::ExitCode {
    // Training and detection free and reallocate the same large buffers.
    infer::kernels::allocator::keep_freed_memory();
    let cli = Cli::parse();
    datasets::cli::exit_code(match cli.command {
        Command::Eval(args) => eval(&args),
        Command::Planes(args) => planes(&args),
        Command::Run(args) => run(&args),
        Command::Autolabel(args) => autolabel(&args),
        Command::Inspect(args) => inspect(&args),
        Command::RegisterColour(args) => register_colour(&args),
        Command::Bench(args) => bench(&args),
        Command::Benchmark(args) => benchmark(&args),
    })
}

fn world_beside(gt: &Path) -> Option<PathBuf> {
    let candidate = gt.parent()?.join("world.json");
    candidate.is_file().then_some(candidate)
}

/// A trajectory file, or a pose topic of a recording.
fn trajectory_input(path: &Path, topic: Option<&str>, flag: &str) -> Result<datasets::io::formats::Trajectory> {
    let trajectory = read_trajectory_input(path, topic, flag)?;
    // Duplicate stamps with other poses, or poses out of order, would be
    // matched to the wrong partner without a word.
    let repeated = trajectory.check_increasing(path)?;
    if repeated > 0 {
        eprintln!(
            "note: {}: {repeated} time stamp(s) written twice with poses within {} m and {} degree, read as they are",
            path.display(),
            datasets::io::formats::trajectory::DUPLICATE_TOLERANCE_M,
            datasets::io::formats::trajectory::DUPLICATE_TOLERANCE_DEG
        );
    }
    Ok(trajectory)
}

fn read_trajectory_input(path: &Path, topic: Option<&str>, flag: &str) -> Result<datasets::io::formats::Trajectory> {
    match topic {
        Some(topic) => {
            let recording = datasets::io::recording::Recording::open(path)?;
            Ok(datasets::io::recording::pose_topic::read_pose_topic(&recording, topic)?)
        }
        None if path.is_dir() || datasets::io::recording::Recording::open(path).is_ok() => {
            anyhow::bail!("{}: a recording; name its pose topic with {flag}", path.display())
        }
        None => Ok(read_trajectory(path)?.0),
    }
}

fn inspect(args: &InspectArgs) -> Result<()> {
    let recording = datasets::io::recording::Recording::open(&args.path)?;
    print!("{}", recording.info());
    println!("Roles for `localize run --bag`:");
    match localize::input::bag_sequence::find_roles(&recording, &args.topics.options(None)) {
        Ok((_, notes)) => notes.iter().for_each(|n| println!("  {n}")),
        Err(e) => println!("  not runnable as it is: {e}"),
    }
    Ok(())
}

fn eval(args: &EvalArgs) -> Result<()> {
    let gt = trajectory_input(&args.gt, args.gt_topic.as_deref(), "--gt-topic")?;
    let est = trajectory_input(&args.est, args.est_topic.as_deref(), "--est-topic")?;
    if !(args.max_diff >= 0.0 && args.max_diff.is_finite()) {
        anyhow::bail!("--max-diff must be a finite number >= 0, got {}", args.max_diff);
    }
    let comparison = compare(&gt, &est, args.align, args.max_diff)
        .with_context(|| format!("comparing {} with {}", args.est.display(), args.gt.display()))?;
    let world = args.world.clone().or_else(|| world_beside(&args.gt));
    let levels = match &world {
        Some(path) => LevelMap::read(path)?.per_segment(&comparison, &gt),
        None => Vec::new(),
    };
    let s = comparison.summary;
    if args.json {
        let mut object = serde_json::to_value(s)?;
        object["align"] = serde_json::to_value(args.align)?;
        object["scale"] = comparison.alignment.scale.into();
        object["levels"] = serde_json::to_value(&levels)?;
        println!("{object}");
    } else {
        println!("matched poses: {} (alignment {:?}, scale {:.6})", s.matched, args.align, comparison.alignment.scale);
        println!(
            "{:<10} {:>8} {:>10} {:>10} {:>10} {:>10}",
            "segment", "poses", "rmse_x", "rmse_y", "rmse_z", "ate_rmse"
        );
        let row = |name: &str, s: &ErrorSummary| {
            println!(
                "{name:<10} {:>8} {:>10.6} {:>10.6} {:>10.6} {:>10.6}",
                s.matched, s.rmse_x, s.rmse_y, s.rmse_z, s.ate_rmse
            )
        };
        for level in &levels {
            row(&level.name, &level.errors);
        }
        row("all", &s);
        println!("ate: mean {:.6} median {:.6} max {:.6}", s.ate_mean, s.ate_median, s.ate_max);
    }
    Ok(())
}

fn planes(args: &PlanesArgs) -> Result<()> {
    let cloud = datasets::io::formats::read_cloud(&args.cloud, datasets::io::formats::NonFinite::Drop)?;
    let geometry = localize::config::LocalizeConfig::default().geometry_stages()?;
    let sensor = cloud.viewpoint.translation.vector;
    let result = geometry.run(&cloud.points, &sensor).with_context(|| format!("{}", args.cloud.display()))?;
    if args.json {
        let planes: Vec<serde_json::Value> = result
            .planes
            .planes
            .iter()
            .map(|p| {
                serde_json::json!({
                    "normal": [p.normal.x, p.normal.y, p.normal.z],
                    "distance": p.distance,
                    "inliers": p.inliers.len(),
                    "rms": p.rms_m,
                })
            })
            .collect();
        let corners: Vec<serde_json::Value> = result
            .corners
            .corners
            .iter()
            .map(|c| serde_json::json!({"position": [c.position.x, c.position.y, c.position.z], "planes": c.planes}))
            .collect();
        let edges: Vec<serde_json::Value> = result
            .corners
            .edges
            .iter()
            .map(|e| {
                serde_json::json!({
                    "point": [e.point.x, e.point.y, e.point.z],
                    "direction": [e.direction.x, e.direction.y, e.direction.z],
                    "planes": e.planes,
                    "angle_deg": e.angle_deg,
                })
            })
            .collect();
        println!(
            "{}",
            serde_json::json!({"points": cloud.len(), "planes": planes, "corners": corners, "edges": edges})
        );
    } else {
        println!("{}: {} points ({} non-finite dropped)", args.cloud.display(), cloud.len(), cloud.dropped_non_finite);
        println!("{:>3} {:>28} {:>9} {:>8} {:>7}", "#", "normal", "distance", "inliers", "rms");
        for (k, p) in result.planes.planes.iter().enumerate() {
            println!(
                "{k:>3} [{:>7.3} {:>7.3} {:>7.3}] {:>9.3} {:>8} {:>7.3}",
                p.normal.x,
                p.normal.y,
                p.normal.z,
                p.distance,
                p.inliers.len(),
                p.rms_m
            );
        }
        println!("corners:");
        for c in &result.corners.corners {
            println!("  [{:>7.3} {:>7.3} {:>7.3}] planes {:?}", c.position.x, c.position.y, c.position.z, c.planes);
        }
        for e in &result.corners.edges {
            println!("edge between planes {:?} at {:.1} deg", e.planes, e.angle_deg);
        }
    }
    Ok(())
}

/// The defaults with the `--config` file at `path` over them.
fn read_config(path: Option<&Path>) -> Result<LocalizeConfig> {
    match read_config_file(path)? {
        Some(file) => LocalizeConfig::default().overlaid(&file).map_err(|m| config_error(path, &m)),
        None => Ok(LocalizeConfig::default()),
    }
}

/// A `--config` file's JSON, to lay over the defaults that apply.
fn read_config_file(path: Option<&Path>) -> Result<Option<serde_json::Value>> {
    Ok(path.map(datasets::settings_file::read).transpose()?)
}

fn config_error(path: Option<&Path>, message: &str) -> anyhow::Error {
    let name = path.map_or_else(String::new, |p| p.display().to_string());
    anyhow::anyhow!("{name}: not a localization config: {message}")
}

fn benchmark(args: &BenchmarkArgs) -> Result<()> {
    use localize::evaluation::benchmark::{BenchmarkPlan, parse_buildings, parse_speeds, run_benchmark, write_tables};
    let mut plan = if args.quick { BenchmarkPlan::quick() } else { BenchmarkPlan::standard() };
    if let Some(text) = &args.buildings {
        plan.buildings = parse_buildings(text).map_err(|m| anyhow::anyhow!("--buildings: {m}"))?;
    }
    if let Some(text) = &args.speeds {
        plan.speeds_mps = parse_speeds(text).map_err(|m| anyhow::anyhow!("--speeds: {m}"))?;
    }
    if let Some(n) = args.max_scans {
        plan.max_scans = n;
    }
    plan.paper_seeds = args.paper_seeds.clone();
    if let Some(n) = args.detection_images {
        plan.detection_images = n;
    }
    plan.validate().map_err(|m| anyhow::anyhow!("invalid benchmark: {m}"))?;
    let config = read_config(args.config.as_deref())?;
    let show = !std::env::var("CI").is_ok_and(|v| v == "true");
    let rows = run_benchmark(&args.out, &plan, &args.detector.checkpoint, args.detector.device()?, &config, show)?;
    write_tables(&args.out, &plan, &rows)?;
    if args.json {
        println!("{}", serde_json::to_string_pretty(&rows)?);
    } else {
        print!("{}", localize::evaluation::benchmark::markdown(&rows));
        println!("errors in mm; wrote benchmark.md, benchmark.csv and benchmark.json to {}", args.out.display());
    }
    Ok(())
}

/// The recording `input` names, opened with the settings for its sensors
/// (the `--config` file over the defaults of what it carries, `camera` or not).
fn open_input(
    input: &InputArgs,
    camera: bool,
    faults: SensorFaults,
) -> Result<(Box<dyn SensorSequence>, LocalizeConfig, SensorSet)> {
    // The defaults follow the recording's sensors, the --config file goes
    // over them. The file is checked before anything is read, over the
    // defaults of the kind of 3D sensor (the IMU and wheels, found on
    // opening, change no range a setting is checked against).
    let file = read_config_file(input.config.as_deref())?;
    let range = match &input.sequence {
        Some(dir) if RgbdSequence::layout_of(dir).is_some() => RangeSensor::DepthCamera,
        _ if input.topics.depth_topic.is_some() => RangeSensor::DepthCamera,
        _ => RangeSensor::Lidar,
    };
    let assumed = SensorSet { range, imu: true, wheels: true, camera };
    let defaults_over = |sensors: &SensorSet| -> Result<LocalizeConfig> {
        let mut config = match &file {
            Some(file) => {
                sensors.default_config().overlaid(file).map_err(|m| config_error(input.config.as_deref(), &m))?
            }
            None => sensors.default_config(),
        };
        if let Some(t) = input.image_tolerance {
            config.sync.image_tolerance_s = t;
        }
        config.sync.validate().map_err(|m| anyhow::anyhow!("--image-tolerance: {m}"))?;
        Ok(config)
    };
    let config = defaults_over(&assumed)?;
    let mut sequence: Box<dyn SensorSequence> = match (&input.sequence, &input.bag) {
        (Some(dir), _) if RgbdSequence::layout_of(dir).is_some() => {
            let mut sequence = RgbdSequence::open(dir, &config.depth, config.sync.image_tolerance_s)?;
            println!("{}: RGB-D folder ({:?} layout)", dir.display(), sequence.layout);
            if let Some(path) = &input.calib {
                let calibration = datasets::io::formats::read_calibration(path)?;
                sequence = sequence.with_colour_calibration(calibration, path)?;
                println!("colour camera from {}", path.display());
            }
            Box::new(sequence)
        }
        (Some(dir), _) if input.calib.is_some() => {
            anyhow::bail!("--calib: {} is a sequence folder, whose calib.json is its calibration", dir.display())
        }
        (Some(dir), _) => Box::new(RecordedSequence::open_with(dir, &config.sync)?),
        (None, Some(bag)) => {
            let options = BagOptions { depth: config.depth.clone(), ..input.topics.options(input.calib.clone()) };
            let sequence = BagSequence::open(bag, &options, &config.sync)?;
            println!("{}: {}", bag.display(), sequence.recording.format);
            sequence.notes.iter().for_each(|n| println!("  {n}"));
            Box::new(sequence)
        }
        (None, None) => anyhow::bail!("give --sequence DIR or --bag PATH"),
    };
    let truth = match &input.gt {
        Some(gt) => {
            let (truth, _) = read_trajectory(gt)?;
            truth.check_increasing(gt)?;
            Some(truth)
        }
        None => None,
    };
    if truth.is_some() || !faults.is_empty() {
        sequence = Box::new(WithChanges { inner: sequence, truth, faults });
    }
    let sensors = SensorSet::of(&*sequence, camera);
    let config = defaults_over(&sensors)?;
    println!("sensors: {sensors}");
    Ok((sequence, config, sensors))
}

fn autolabel(args: &AutolabelArgs) -> Result<()> {
    use localize::labels::autolabel::AutolabelConfig;
    localize::labels::autolabel::check_output_folder(&args.out)?;
    // The file is checked over the defaults before anything is read, and laid
    // over the defaults of the recording's 3D sensor once it is open.
    let file = read_config_file(args.autolabel_config.as_deref())?;
    let overlay = |defaults: AutolabelConfig| match &file {
        Some(file) => defaults.overlaid(file).map_err(|m| {
            let name = args.autolabel_config.as_ref().map_or_else(String::new, |p| p.display().to_string());
            anyhow::anyhow!("{name}: not an autolabel config: {m}")
        }),
        None => Ok(defaults),
    };
    overlay(AutolabelConfig::default())?;
    let beside = args.input.sequence.as_ref().map(|d| d.join("labels.json")).filter(|p| p.is_file());
    let truth = match args.truth_labels.clone().or(beside) {
        Some(path) => {
            println!("true labels: {}", path.display());
            Some(datasets::io::formats::read_coco(&path)?)
        }
        None => None,
    };
    // The camera's images are labelled (and an RGB-D camera's edges register); only the detector is left out.
    let (sequence, localize_config, sensors) = open_input(&args.input, true, SensorFaults::default())?;
    let teacher = if args.without_teacher {
        None
    } else {
        Some(infer::detector::Detector::load(&args.teacher, args.backend.device()?)?)
    };
    let config = overlay(AutolabelConfig::for_range(sensors.range))?;
    let progress = !std::env::var("CI").is_ok_and(|v| v == "true");
    let (report, run) = localize::labels::autolabel::autolabel(
        &args.out,
        &*sequence,
        &localize_config,
        teacher.as_ref(),
        &config,
        truth.as_ref(),
        progress,
    )?;
    print!("{}", report.summary());
    if let Some(m) = localize::run::metrics(&*sequence, &run)? {
        println!("the run the labels came from: ATE {:.4} m over {} frames", m.fused.overall.ate_rmse, m.frames);
    }
    println!("wrote {} (train with: train --data {})", args.out.display(), args.out.display());
    Ok(())
}

fn run(args: &RunArgs) -> Result<()> {
    // Refused before the work, not after it.
    localize::run::check_output_folder(&args.out)?;
    let faults = SensorFaults {
        lidar_gaps: args.lidar_gap.clone(),
        camera_stop_s: args.camera_stop,
        without_imu: args.without_imu,
        without_wheels: args.without_wheels,
    };
    let (sequence, config, sensors) = open_input(&args.input, !args.without_camera, faults)?;
    let mut source = match &args.corners_from_labels {
        _ if args.without_camera => CornerSource::Off,
        Some(labels) => CornerSource::labels(labels, args.label_noise_px, args.seed)?,
        None => CornerSource::detector(&args.detector.checkpoint, args.detector.device()?, config.fusion.min_score)?,
    };
    let map = match &args.map {
        Some(dir) => Some(MapStart { map: localize::map_output::read_map(dir)?, start: args.start_pose }),
        None => None,
    };
    let progress = !std::env::var("CI").is_ok_and(|v| v == "true");
    let result = run_sequence_in_map(&*sequence, &mut source, &config, map, progress)?;
    if let Some(p) = &result.placement {
        let (t, yaw) = (p.pose.translation.vector, p.pose.rotation.euler_angles().2.to_degrees());
        println!(
            "placed in the map at ({:.3}, {:.3}, {:.3}) m, heading {yaw:.1} deg (standard deviations {:.3} / {:.3} m, \
             {:.2} deg): {:.0}% of the first scan agrees with the map ({:.0}% at the best other place; {} candidates)",
            t.x,
            t.y,
            t.z,
            p.covariance[(0, 0)].sqrt(),
            p.covariance[(1, 1)].sqrt(),
            p.covariance[(5, 5)].sqrt().to_degrees(),
            100.0 * p.agreement,
            100.0 * p.runner_up,
            p.candidates
        );
    }
    let truth = truth_in_run_frame(&*sequence, &result);
    let metrics = metrics_against(&*sequence, &result, truth.as_ref())?;
    write_outputs(&args.out, &config, &result, truth.as_ref(), metrics.as_ref())?;
    println!("wrote {}", args.out.join("trajectory.txt").display());
    for warning in localize::run::run_warnings(&*sequence, &result, metrics.as_ref()) {
        eprintln!("warning: {warning}");
    }
    if let Some(m) = &metrics {
        // Without odometry or IMU the reference is the start pose held: nothing to show.
        print!("{}", localize::run::metrics_table(m, sensors.imu || sensors.wheels));
    }
    Ok(())
}

/// `X,Y,Z,YAW_DEG` as a pose (level: roll and pitch 0).
fn parse_start_pose(text: &str) -> std::result::Result<datasets::math::Pose3, String> {
    let values: Vec<f64> = text
        .split(',')
        .map(|v| v.trim().parse::<f64>().map_err(|_| format!("`{v}` is not a number")))
        .collect::<std::result::Result<_, _>>()?;
    match values[..] {
        [x, y, z, yaw] if values.iter().all(|v| v.is_finite()) => Ok(datasets::math::Pose3::from_parts(
            datasets::math::Vec3::new(x, y, z).into(),
            localize::estimation::euler::rotation(0.0, 0.0, yaw.to_radians()),
        )),
        _ => Err(format!("`{text}`: expected four finite numbers X,Y,Z,YAW_DEG")),
    }
}

/// Scans along the route of `world`, `frames` of them evenly spaced.
fn bench(args: &BenchArgs) -> Result<()> {
    let detector = if args.detector.checkpoint.is_dir() {
        Some(infer::detector::Detector::load(&args.detector.checkpoint, args.detector.device()?)?)
    } else {
        None
    };
    let mut clouds = Vec::new();
    for path in &args.clouds {
        let cloud = datasets::io::formats::read_cloud(path, datasets::io::formats::NonFinite::Drop)?;
        let name = path.file_name().map_or_else(|| path.display().to_string(), |n| n.to_string_lossy().into_owned());
        clouds.push((name, cloud.points, cloud.viewpoint.translation.vector));
    }
    let report = localize::evaluation::stage_bench::stage_bench(detector.as_ref(), args.frames, &clouds)?;
    if args.json {
        println!("{}", serde_json::to_string(&report)?);
    } else {
        print!("{}", report.table());
    }
    Ok(())
}

fn register_colour(args: &RegisterColourArgs) -> Result<()> {
    if RgbdSequence::layout_of(&args.sequence).is_none() {
        anyhow::bail!(
            "{}: not an RGB-D folder (TUM's rgb.txt and depth.txt, or 7-Scenes' frames)",
            args.sequence.display()
        );
    }
    datasets::atomic::check_writable(args.out.parent().unwrap_or(Path::new(".")))?;
    let sequence = RgbdSequence::open(&args.sequence, &Default::default(), 0.05)?;
    let fit = sequence.fit_colour_camera(args.frames)?;
    println!(
        "colour camera over {} frames ({} contour points): fx = fy = {:.1}, cx {:.1}, cy {:.1}, baseline {:.3} m; \
         contours {:.2} px from the colour edges (unregistered: {:.2} px)",
        fit.frames,
        fit.contour_points,
        fit.camera.fx,
        fit.camera.cx,
        fit.camera.cy,
        fit.baseline_m,
        fit.mean_distance_px,
        fit.unregistered_distance_px
    );
    datasets::io::formats::write_calibration(&args.out, &RgbdSequence::calibration_of(&fit))?;
    println!("wrote {} (use it with --calib)", args.out.display());
    Ok(())
}
