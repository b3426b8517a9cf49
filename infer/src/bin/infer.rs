//! `infer --checkpoint DIR IMAGE...` prints detections as JSON;
//! `infer eval --checkpoint DIR --data DIR` scores a checkpoint on a test set;
//! `infer eval-points --checkpoint DIR --images DIR --points DIR` scores it
//! on photographs with point labels, beside Shi-Tomasi and Harris corners.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use clap::{Args, Parser, Subcommand};
use image::{DynamicImage, Rgb};
use infer::detector_args::BackendArg;
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
    /// Score confident detections on photographs against point labels
    /// (NAME.csv beside NAME.jpg/png; York Urban's junctions), beside
    /// Shi-Tomasi, Harris and random points given the same count per image.
    EvalPoints(EvalPointsArgs),
}

#[derive(Debug, Args)]
#[command(allow_negative_numbers = true)]
struct EvalPointsArgs {
    #[arg(long)]
    checkpoint: PathBuf,
    /// A folder of photographs (.jpg, .jpeg, .png; those without a points
    /// file are skipped), or a COCO JSON file whose images are scored (paths
    /// relative to it, as `coco-from-points` writes its halves).
    #[arg(long)]
    images: PathBuf,
    /// A folder of NAME.csv point files: a header starting `x,y`, then x,y in
    /// MATLAB pixel convention (centres at integers from 1), as York Urban's
    /// junctions_derived/.
    #[arg(long)]
    points: PathBuf,
    /// A point within this many pixels of a labelled point is a hit.
    #[arg(long, default_value_t = 12.0, value_parser = datasets::cli::non_negative)]
    radius: f64,
    /// Detections at or above this score are the detector's points.
    #[arg(long, default_value_t = 0.5)]
    min_score: f32,
    /// Print one JSON object instead of a table.
    #[arg(long)]
    json: bool,
    #[command(flatten)]
    backend: BackendArg,
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
    #[command(flatten)]
    backend: BackendArg,
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
    #[command(flatten)]
    backend: BackendArg,
}

#[derive(Serialize)]
struct ImageDetections<'a> {
    image: &'a Path,
    width: u32,
    height: u32,
    detections: Vec<Detection>,
}

fn main() -> std::process::ExitCode {
    // Training and detection free and reallocate the same large buffers.
    infer::kernels::allocator::keep_freed_memory();
    datasets::cli::exit_code(run_main())
}

fn run_main() -> Result<()> {
    let cli = Cli::parse();
    match cli.command {
        Some(Command::Eval(args)) => eval(args),
        Some(Command::EvalPoints(args)) => eval_points(args),
        None => detect(cli.detect),
    }
}

fn load(checkpoint: &Path, backend: BackendArg) -> Result<Detector> {
    Ok(Detector::load(checkpoint, backend.device()?)?)
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

/// The photographs of `dir` that have a points file in `points`, in name order.
/// The photos to score with their label files: those of a folder that have
/// a `NAME.csv` in `points`, or the images of a COCO file (`NAME.csv` for
/// each required).
fn photos_to_score(images: &Path, points: &Path) -> Result<Vec<(PathBuf, PathBuf)>> {
    if !images.is_file() {
        return Ok(datasets::io::formats::labelled_photos(images, points)?);
    }
    let coco = datasets::io::formats::read_coco(images)?;
    let root = images.parent().unwrap_or(Path::new("."));
    let mut found = Vec::new();
    for im in &coco.images {
        let photo = root.join(&im.file_name);
        let stem = photo.file_stem().and_then(|s| s.to_str()).unwrap_or_default();
        let labels = points.join(format!("{stem}.csv"));
        if !labels.is_file() {
            bail!("{}: image {} has no {}", images.display(), im.file_name, labels.display());
        }
        found.push((photo, labels));
    }
    if found.is_empty() {
        bail!("{}: no images", images.display());
    }
    Ok(found)
}

#[derive(Serialize)]
struct MethodScores {
    method: &'static str,
    points: usize,
    labels: usize,
    points_per_image: f64,
    precision: Option<f64>,
    recall: Option<f64>,
}

fn eval_points(args: EvalPointsArgs) -> Result<()> {
    use datasets::io::formats::read_point_labels;
    use infer::point_eval::{METHODS, PointScores, score_photo};
    if !(0.0..=1.0).contains(&args.min_score) {
        bail!("--min-score {} is outside 0..1", args.min_score);
    }
    let photos = photos_to_score(&args.images, &args.points)?;
    let mut detector = load(&args.checkpoint, args.backend)?;
    detector.config.detection.score_threshold = args.min_score;
    let radius = args.radius as f32;
    let mut totals = [PointScores::default(); 4];
    let bar = indicatif::ProgressBar::new(photos.len() as u64);
    if std::env::var("CI").is_ok_and(|v| v == "true") {
        bar.set_draw_target(indicatif::ProgressDrawTarget::hidden());
    }
    for (k, (photo, labels_path)) in photos.iter().enumerate() {
        let image = datasets::atomic::read_image(photo)?;
        let labels: Vec<[f32; 2]> = read_point_labels(labels_path)?.into_iter().map(|l| l.point).collect();
        // A label off the photo belongs to another image: it would count as a miss of every method.
        let (w, h) = (image.width() as f32, image.height() as f32);
        if let Some((n, p)) =
            labels.iter().enumerate().find(|(_, p)| !(0.0..=w).contains(&p[0]) || !(0.0..=h).contains(&p[1]))
        {
            bail!(
                "{}: point {} ({}, {}) lies outside the {w}x{h} photo {}",
                labels_path.display(),
                n + 1,
                // As the file has it (MATLAB's pixels, centres at whole numbers).
                p[0] + 0.5,
                p[1] + 0.5,
                photo.display()
            );
        }
        let scores = score_photo(&detector, &image, &labels, radius, k);
        for (total, score) in totals.iter_mut().zip(&scores) {
            total.add(score);
        }
        bar.inc(1);
    }
    bar.finish_and_clear();
    let rows: Vec<MethodScores> = METHODS
        .iter()
        .zip(&totals)
        .map(|(method, s)| MethodScores {
            method,
            points: s.points,
            labels: s.labels,
            points_per_image: s.points as f64 / photos.len() as f64,
            precision: s.precision(),
            recall: s.recall(),
        })
        .collect();
    if args.json {
        let out = serde_json::json!({"images": photos.len(), "radius_px": args.radius, "min_score": args.min_score, "methods": rows});
        println!("{}", serde_json::to_string_pretty(&out)?);
        return Ok(());
    }
    println!(
        "{} photos, {} labelled points; detector score >= {}; a hit is within {} px",
        photos.len(),
        totals[0].labels,
        args.min_score,
        args.radius
    );
    println!("{:<12} {:>14} {:>10} {:>8}", "method", "points/image", "precision", "recall");
    let percent = |v: Option<f64>| v.map_or("-".to_string(), |v| format!("{:.1}%", 100.0 * v));
    for r in &rows {
        println!("{:<12} {:>14.1} {:>10} {:>8}", r.method, r.points_per_image, percent(r.precision), percent(r.recall));
    }
    println!(
        "(each photo: shi-tomasi and harris give the detector's count, at least {} px apart; random the same count, anywhere)",
        args.radius
    );
    Ok(())
}
