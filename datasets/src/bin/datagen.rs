//! `datagen --out DIR`: generates the default detection data set and
//! localization sequence from the synthetic three-level world.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, Result, bail};
use clap::Parser;
use datasets::simulator::generate::{DatagenConfig, generate_then};

/// Generate labeled images and a full sensor sequence from the synthetic
/// three-level indoor area. Settings come from the defaults, then `--config`,
/// then the flags; the resolved settings are written to DIR/datagen.json.
#[derive(Debug, Parser)]
#[command(name = "datagen", version, allow_negative_numbers = true)]
struct Args {
    /// Output folder (created if needed).
    #[arg(long)]
    out: PathBuf,
    /// A JSON file with any part of the settings (see DIR/datagen.json of a run).
    #[arg(long)]
    config: Option<PathBuf>,
    /// Seed of every random choice: same seed, same bytes.
    #[arg(long)]
    seed: Option<u64>,
    /// 0: the paper's building (default); N >= 1: generated building N, with
    /// a robot's sensor timing (10 Hz spinning LIDAR, 15 Hz camera, 50 Hz
    /// odometry, 200 Hz IMU, 1 m/s) unless --config sets its own.
    #[arg(long)]
    building: Option<u32>,
    /// Instead of a building, one straight featureless corridor this many
    /// metres long (the hard case of LIDAR odometry), with a generated
    /// building's robot timing unless --config sets its own.
    #[arg(long, value_name = "METRES", conflicts_with = "building", value_parser = datasets::cli::positive)]
    corridor: Option<f64>,
    /// Scans of the sequence (default: the whole route once, at most 3000 scans in a generated building).
    #[arg(long, value_parser = datasets::cli::positive_count)]
    frames: Option<usize>,
    /// Robot speed in m/s (default 0.05, the paper's).
    #[arg(long)]
    speed: Option<f64>,
    /// Start this many metres along the route (default 0): a second sequence
    /// of the same building for `localize run --map`; the ground truth stays
    /// in the building's frame.
    #[arg(long, value_name = "METRES")]
    start_m: Option<f64>,
    /// LIDAR rate in Hz, and the camera's when it has none of its own (default 1, the paper's).
    #[arg(long)]
    rate: Option<f64>,
    /// Detection images in all (default 300).
    #[arg(long, value_parser = datasets::cli::count)]
    images: Option<usize>,
    /// Detection images in the training split (default 200; the rest is the test split).
    #[arg(long, value_parser = datasets::cli::count)]
    train: Option<usize>,
    /// Also write the sequence as a ROS 2 recording (one MCAP file) here.
    #[arg(long)]
    bag: Option<PathBuf>,
}

fn main() -> std::process::ExitCode {
    datasets::cli::exit_code(run_main())
}

fn run_main() -> Result<()> {
    let args = Args::parse();
    let mut config = match &args.config {
        Some(path) => {
            let text = std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
            serde_json::from_str::<DatagenConfig>(&text)
                .with_context(|| format!("{}: invalid settings", path.display()))?
        }
        None => match args.corridor {
            Some(length) => DatagenConfig::for_corridor(length),
            None => DatagenConfig::for_building(args.building.unwrap_or(0)),
        },
    };
    if let Some(building) = args.building {
        config.world.building = building;
    }
    if let Some(length) = args.corridor {
        config.world.corridor_m = length;
    }
    if let Some(seed) = args.seed {
        config.seed = seed;
    }
    if let Some(frames) = args.frames {
        config.sequence.frames = Some(frames);
    }
    if let Some(speed) = args.speed {
        config.sequence.speed_mps = speed;
    }
    if let Some(start) = args.start_m {
        config.sequence.start_m = start;
    }
    if let Some(rate) = args.rate {
        config.sequence.rate_hz = rate;
    }
    if let Some(images) = args.images {
        config.detection.images = images;
        if args.train.is_none() && config.detection.train > images {
            config.detection.train = images * 2 / 3;
        }
    }
    if let Some(train) = args.train {
        config.detection.train = train;
    }
    if let Err(invalid) = config.validate() {
        match &args.config {
            Some(path) => bail!("invalid settings (from {} and the flags): {invalid}", path.display()),
            None => bail!("invalid settings: {invalid}"),
        }
    }
    if args.out.exists() && !args.out.is_dir() {
        bail!("--out {}: exists and is not a folder", args.out.display());
    }
    let started = Instant::now();
    let mut messages = 0;
    let summary = generate_then(&args.out, &config, |out| {
        if let Some(bag) = &args.bag {
            messages = datasets::io::recording::mcap_export::write_sequence_mcap(&out.join("sequence"), bag)?;
        }
        Ok(())
    })?;
    eprintln!(
        "wrote {} detection images ({} corner labels) and {} sequence frames over a {:.1} m route to {} in {:.1} s",
        summary.detection_images,
        summary.detection_labels,
        summary.frames,
        summary.route_length_m,
        args.out.display(),
        started.elapsed().as_secs_f64()
    );
    if let Some(bag) = &args.bag {
        eprintln!("wrote {messages} messages to {}", bag.display());
    }
    if summary.frames_after_route_end > 0 {
        eprintln!(
            "note: the route ends before the last {} frames; the robot stands still for them",
            summary.frames_after_route_end
        );
    }
    Ok(())
}
