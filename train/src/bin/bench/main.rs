//! Benchmarks that print figures (never timed tests: machines are shared).
//!
//!     cargo run --release --bin bench -- detectors [--backend flex|ndarray] [--width 0.25]
//!     cargo run --release --bin bench -- conv [--json]
//!     cargo run --release --bin bench -- train-step [--model alexnet --model vgg16w4 --model vgg16]

mod classifier;
mod conv;
mod detectors;

use anyhow::Result;
use clap::{Parser, Subcommand};
use infer::config::{Backbone, DEFAULT_WIDTH};
use infer::detector_args::BackendArg;

#[derive(Debug, Parser)]
#[command(name = "bench")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Time a training step and inference of each detector.
    Detectors {
        #[command(flatten)]
        backend: BackendArg,
        #[arg(long, default_value_t = DEFAULT_WIDTH)]
        width: f32,
        #[arg(long, default_value_t = 8)]
        batch: usize,
        /// Timed training steps (after one warm-up step).
        #[arg(long, default_value_t = 3)]
        steps: usize,
        /// Run one backbone in this process (used by the parent run).
        #[arg(long, value_enum)]
        only: Option<Backbone>,
        /// Print JSON lines instead of a table.
        #[arg(long)]
        json: bool,
        /// Burn as it comes: its own convolution kernels and AdamW instead of
        /// the project's GEMM kernels and fused AdamW (for comparison).
        #[arg(long)]
        burn_kernels: bool,
    },
    /// GFLOP/s of the convolution kernels (forward, input and weight
    /// gradient): the project's GEMM kernels and Burn's flex kernels.
    Conv {
        /// Timed runs per kernel (median reported, after one warm-up).
        #[arg(long, default_value_t = 5)]
        reps: usize,
        /// Print one JSON object for the reference layer (64->64 3x3 on
        /// 8x64x112x112) instead of the table of all layers.
        #[arg(long)]
        json: bool,
    },
    /// Training-step images per second of the torchvision classifiers with
    /// Burn's kernels and with the GEMM kernels.
    TrainStep {
        /// Models to time (repeat the flag); all three by default.
        #[arg(long = "model", value_enum)]
        models: Vec<classifier::Model>,
        #[arg(long, default_value_t = 8)]
        batch: usize,
        #[arg(long, default_value_t = 2)]
        warmup: usize,
        #[arg(long, default_value_t = 5)]
        steps: usize,
        /// Time only the project's kernels (Burn's as they come take longer
        /// than the project's and are the same from build to build).
        #[arg(long)]
        project_only: bool,
        /// Print JSON lines instead of a table.
        #[arg(long)]
        json: bool,
    },
}

fn main() -> std::process::ExitCode {
    // Training and detection free and reallocate the same large buffers.
    infer::kernels::allocator::keep_freed_memory();
    datasets::cli::exit_code(run_main())
}

fn run_main() -> Result<()> {
    match Cli::parse().command {
        Command::Detectors { backend, width, batch, steps, only, json, burn_kernels } => {
            detectors::run(backend.kind, width, batch, steps, only, json, burn_kernels)
        }
        Command::Conv { reps, json } => conv::run(reps, json),
        Command::TrainStep { mut models, batch, warmup, steps, project_only, json } => {
            if models.is_empty() {
                models = vec![classifier::Model::Alexnet, classifier::Model::Vgg16w4, classifier::Model::Vgg16];
            }
            classifier::run(&models, batch, warmup.max(1), steps.max(1), !project_only, json)
        }
    }
}
