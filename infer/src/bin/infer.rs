//! `infer --checkpoint DIR IMAGE...` prints detections as JSON;
//! `infer eval --checkpoint DIR --data DIR` scores a checkpoint on a test set.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use clap::{Args, Parser, Subcommand};
use image::{DynamicImage, Rgb};
use infer::backend::CpuBackend;
use infer::{Detection, Detector};
use serde::Serialize;

#[derive(Debug, Parser)]
#[command(name = "infer", version, args_conflicts_with_subcommands = true, allow_negative_numbers = true)]
struct Cli {
    #[command(subcommand)]
    command: Option<Command>,
    #[command(flatten)]
    detect: DetectArgs,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Evaluate a checkpoint on a COCO-form test set: AP@0.5, precision, recall, pixel error.
    Eval(EvalArgs),
}

#[derive(Debug, Args)]
#[command(allow_negative_numbers = true)]
struct DetectArgs {
    /// Checkpoint folder (config.json, model.bpk, meta.json).
    #[arg(long)]
    checkpoint: Option<PathBuf>,
    /// Images to run the detector on.
    images: Vec<PathBuf>,
    /// Write each image with its boxes drawn into this folder.
    #[arg(long)]
    draw: Option<PathBuf>,
    /// Keep detections at or above this score (default: the checkpoint's, 0.05).
    #[arg(long)]
    min_score: Option<f32>,
    #[arg(long, value_enum, default_value_t)]
    backend: CpuBackend,
}

#[derive(Debug, Args)]
#[command(allow_negative_numbers = true)]
struct EvalArgs {
    #[arg(long)]
    checkpoint: PathBuf,
    /// A `datagen` detection folder (its test.json is used) or a COCO JSON file.
    #[arg(long)]
    data: PathBuf,
    /// Print one JSON object instead of a table.
    #[arg(long)]
    json: bool,
    #[arg(long, value_enum, default_value_t)]
    backend: CpuBackend,
}

#[derive(Serialize)]
struct ImageDetections<'a> {
    image: &'a Path,
    width: u32,
    height: u32,
    detections: Vec<Detection>,
}

fn main() -> std::process::ExitCode {
    datasets::cli::exit_code(run_main())
}

fn run_main() -> Result<()> {
    let cli = Cli::parse();
    match cli.command {
        Some(Command::Eval(args)) => eval(args),
        None => detect(cli.detect),
    }
}

fn load(checkpoint: &Path, backend: CpuBackend) -> Result<Detector> {
    Ok(Detector::load(checkpoint, backend.device())?)
}

fn detect(args: DetectArgs) -> Result<()> {
    let Some(checkpoint) = args.checkpoint else { bail!("--checkpoint DIR is required (or use `infer eval`)") };
    if args.images.is_empty() {
        bail!("no images given: infer --checkpoint DIR IMAGE...");
    }
    let mut detector = load(&checkpoint, args.backend)?;
    if let Some(score) = args.min_score {
        if !(0.0..=1.0).contains(&score) {
            bail!("--min-score {score} is outside 0..1");
        }
        detector.config.detection.score_threshold = score;
    }
    let images: Vec<DynamicImage> =
        args.images.iter().map(|p| datasets::atomic::read_image(p)).collect::<Result<_, _>>()?;
    let found = detector.detect_many(&images);
    let mut out = Vec::new();
    for ((path, image), detections) in args.images.iter().zip(&images).zip(found) {
        if let Some(dir) = &args.draw {
            let mut canvas = image.to_rgb8();
            for d in &detections {
                let b = d.bbox;
                let rect = imageproc::rect::Rect::at(b.x1 as i32, b.y1 as i32)
                    .of_size(b.width().max(1.0) as u32, b.height().max(1.0) as u32);
                let shade = (255.0 * d.score) as u8;
                imageproc::drawing::draw_hollow_rect_mut(&mut canvas, rect, Rgb([255, 255 - shade, 0]));
            }
            let name = path.file_stem().and_then(|s| s.to_str()).unwrap_or("image");
            let target = dir.join(format!("{name}_detections.png"));
            datasets::atomic::write_image(&target, &DynamicImage::ImageRgb8(canvas))
                .with_context(|| format!("drawing {}", path.display()))?;
        }
        out.push(ImageDetections { image: path, width: image.width(), height: image.height(), detections });
    }
    println!("{}", serde_json::to_string_pretty(&out)?);
    Ok(())
}

fn eval(args: EvalArgs) -> Result<()> {
    let annotations = if args.data.is_dir() { args.data.join("test.json") } else { args.data.clone() };
    let detector = load(&args.checkpoint, args.backend)?;
    let set = infer::labeled::load_coco_set(&annotations, &detector.config.preprocess)?;
    let m = infer::eval::evaluate_set(&detector, &set, 8);
    if args.json {
        println!(
            "{}",
            serde_json::json!({
                "ap50": m.ap50, "precision": m.precision, "recall": m.recall,
                "mean_pixel_error": m.mean_pixel_error, "images": m.images,
                "ground_truths": m.ground_truths, "detections": m.detections, "operating_score": m.operating_score,
            })
        );
    } else {
        println!("checkpoint   {}", args.checkpoint.display());
        println!("test set     {} ({} images, {} corners)", annotations.display(), m.images, m.ground_truths);
        println!("AP@0.5       {:.4}", m.ap50);
        println!("precision    {:.4}  (score >= {})", m.precision, m.operating_score);
        println!("recall       {:.4}", m.recall);
        let error = m.mean_pixel_error.map_or("none found".to_string(), |e| format!("{e:.2} px"));
        println!("pixel error  {error} (mean over true positives)");
    }
    Ok(())
}
