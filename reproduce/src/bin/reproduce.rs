//! `reproduce --out DIR` runs the paper's experiment on the built-in
//! synthetic three-level area and writes `DIR/report.md`. Run it again after
//! an interruption: finished stages are skipped, training resumes.

use std::path::PathBuf;

use anyhow::Result;
use clap::Parser;
use datasets::simulator::corpus::CorpusConfig;
use infer::detector_args::BackendArg;
use reproduce::plan::{Plan, TrunkSource};

#[derive(Debug, Parser)]
#[command(name = "reproduce", version, allow_negative_numbers = true)]
struct Args {
    /// Folder for the data, runs, pictures and the report.
    #[arg(long)]
    out: PathBuf,
    /// A smoke version of every stage in a few minutes (tiny data, two epochs).
    #[arg(long)]
    quick: bool,
    /// Pretrain the starting networks here on a generated corpus (the vgg16
    /// and alexnet trunks, then the whole faster-rcnn from the vgg16 trunk)
    /// instead of taking the shipped ones (adds about an hour on two cores).
    #[arg(long)]
    pretrain: bool,
    /// Your own data instead of the generated: `DIR/detection` (COCO
    /// train.json, test.json, images) and `DIR/sequence` (clouds, images,
    /// odometry, IMU, calibration, optional groundtruth.txt).
    #[arg(long)]
    data: Option<PathBuf>,
    /// The folder holding the shipped pretrained networks (`pretrained/<network>/`).
    #[arg(long, default_value = "checkpoints")]
    checkpoints: PathBuf,
    #[command(flatten)]
    backend: BackendArg,
}

fn main() -> std::process::ExitCode {
    // Training and detection free and reallocate the same large buffers.
    infer::kernels::allocator::keep_freed_memory();
    datasets::cli::exit_code(run_main())
}

fn run_main() -> Result<()> {
    let args = Args::parse();
    let mut plan = if args.quick { Plan::quick() } else { Plan::full(args.checkpoints.clone()) };
    if args.pretrain && !args.quick {
        plan.trunks = TrunkSource::Pretrain { corpus: CorpusConfig::default(), epochs: 3 };
    }
    plan.backend = args.backend.kind;
    if let Some(dir) = &args.data {
        if !dir.join("detection/train.json").is_file() || !dir.join("sequence").is_dir() {
            anyhow::bail!("--data {}: needs detection/train.json, detection/test.json and sequence/", dir.display());
        }
        plan.recorded = Some(dir.clone());
    }
    let show_progress = !std::env::var("CI").is_ok_and(|v| v == "true");
    reproduce::reproduce(&args.out, &plan, show_progress)?;
    println!("wrote {}", args.out.join(reproduce::REPORT_FILE).display());
    Ok(())
}
