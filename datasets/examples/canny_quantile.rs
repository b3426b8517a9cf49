//! Where a fixed Canny high threshold sits in each image's own gradient
//! magnitudes (the preprocessing's grayscale resize, blur and Sobel):
//! the share of pixels below it, over a COCO set's images. Calibrates
//! `AdaptiveCanny`'s quantile so that on rendered rooms it matches the fixed
//! thresholds, while it follows the contrast of other images.
//!
//!     cargo run --release -p datasets --example canny_quantile -- out/data/detection/test.json 40

use std::path::PathBuf;

use anyhow::{Context, Result};
use datasets::canny::gradient_magnitudes;
use datasets::preprocess::{PreprocessConfig, network_gray};

fn main() -> Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [set, high] = args.as_slice() else {
        anyhow::bail!("usage: canny_quantile ANNOTATIONS.json CANNY_HIGH");
    };
    let high: f32 = high.parse().context("CANNY_HIGH")?;
    let set = PathBuf::from(set);
    let config = PreprocessConfig::default();
    let coco = datasets::io::formats::read_coco(&set)?;
    let root = set.parent().unwrap_or(std::path::Path::new("."));
    let mut shares = Vec::new();
    for entry in &coco.images {
        let image = datasets::atomic::read_image(&root.join(&entry.file_name))?;
        let magnitudes = gradient_magnitudes(&network_gray(&image, &config));
        let below = magnitudes.iter().filter(|&&m| m < high).count();
        shares.push(below as f64 / magnitudes.len() as f64);
    }
    shares.sort_by(f64::total_cmp);
    let at = |q: f64| shares[((q * (shares.len() - 1) as f64).round() as usize).min(shares.len() - 1)];
    println!(
        "{} images: share of pixels below {high}: median {:.3}, quartiles {:.3} / {:.3}, range {:.3} - {:.3}",
        shares.len(),
        at(0.5),
        at(0.25),
        at(0.75),
        at(0.0),
        at(1.0)
    );
    Ok(())
}
