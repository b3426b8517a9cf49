//! `coco-from-points --images DIR --points DIR --out DIR`: a detection data
//! set that `train --data` reads, made from photographs with point labels
//! (York Urban's derived junctions, or any `NAME.csv` of points beside
//! `NAME.jpg`): a square box around every point, the photos split into a
//! training and a test half. The photos are not copied: `train.json` and
//! `test.json` name them by absolute path, so that data under a research
//! licence stays where it is.

use std::path::PathBuf;

use anyhow::{Context, Result, bail};
use clap::Parser;
use datasets::io::formats::{CocoDataset, coco_halves, labelled_photos, write_coco};

/// Make train.json and test.json (COCO) from photographs and point labels.
#[derive(Debug, Parser)]
#[command(name = "coco-from-points", version)]
struct Args {
    /// A folder of photographs (.jpg, .jpeg, .png); those without a points file are left out.
    #[arg(long)]
    images: PathBuf,
    /// A folder of NAME.csv point files: a header starting `x,y`, then x,y
    /// in MATLAB's pixel convention (centres at integers from 1) and an
    /// optional kind, as York Urban's junctions_derived/.
    #[arg(long)]
    points: PathBuf,
    /// Output folder for train.json and test.json.
    #[arg(long)]
    out: PathBuf,
    /// Every N-th photo (sorted by name: the 2nd, 4th, ... for 2) goes to the test half.
    #[arg(long, default_value_t = 2, value_parser = clap::value_parser!(u64).range(2..))]
    test_every: u64,
    /// Side of the square box around each point, in image pixels (the
    /// generated data's labels are 96 px).
    #[arg(long, default_value_t = 96.0)]
    box_size: f32,
}

fn main() -> Result<()> {
    let args = Args::parse();
    if !(4.0..=256.0).contains(&args.box_size) {
        bail!("--box-size {} is outside 4..256 pixels", args.box_size);
    }
    let photos = labelled_photos(&args.images, &args.points)?;
    if (photos.len() as u64) < args.test_every {
        bail!(
            "{}: {} labelled photos, too few for a test half of every {}-th",
            args.images.display(),
            photos.len(),
            args.test_every
        );
    }
    let split = coco_halves(&photos, args.test_every as usize, args.box_size)?;
    std::fs::create_dir_all(&args.out).with_context(|| format!("creating {}", args.out.display()))?;
    let [train, test] = &split.halves;
    let files = [(args.out.join("train.json"), train), (args.out.join("test.json"), test)];
    // Both checked before either is written: no half-written pair.
    for (path, half) in &files {
        half.validate(path)?;
    }
    for (path, half) in &files {
        write_coco(path, half)?;
    }
    let report = |half: &CocoDataset| format!("{} photos, {} points", half.images.len(), half.annotations.len());
    println!("train.json: {}; test.json: {}", report(train), report(test));
    if split.outside > 0 {
        println!("{} points outside their photo left out", split.outside);
    }
    println!("wrote {}", args.out.display());
    Ok(())
}
