//! How many labelled corners the network can see at all: the share of a
//! COCO set's corner points with an edge pixel of the preprocessed (Canny)
//! input within 4 network pixels, and the edge density, for given Canny
//! thresholds. A detector's recall cannot exceed the first number.
//!
//!     cargo run --release -p datasets --example edge_support -- out/data/detection/test.json 15 40

use std::path::PathBuf;

use anyhow::{Context, Result};
use datasets::preprocess::{ImageToNet, PreprocessConfig, preprocess};

fn main() -> Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [set, low, high] = args.as_slice() else {
        anyhow::bail!("usage: edge_support ANNOTATIONS.json CANNY_LOW CANNY_HIGH");
    };
    let set = PathBuf::from(set);
    let config = PreprocessConfig {
        canny_low: low.parse().context("CANNY_LOW")?,
        canny_high: high.parse().context("CANNY_HIGH")?,
        ..Default::default()
    };
    config.validate().map_err(anyhow::Error::msg)?;
    let coco = datasets::io::formats::read_coco(&set)?;
    let root = set.parent().unwrap_or(std::path::Path::new("."));
    let (mut seen, mut total, mut density) = (0usize, 0usize, 0.0f64);
    for entry in &coco.images {
        let image = datasets::atomic::read_image(&root.join(&entry.file_name))?;
        let edges = preprocess(&image, &config);
        let s = config.size as i64;
        density += edges.pixels().filter(|p| p[0] > 0).count() as f64 / (s * s) as f64;
        let map = ImageToNet::new(entry.width, entry.height, config.size);
        for point in coco.annotations.iter().filter(|a| a.image_id == entry.id).filter_map(|a| a.point) {
            let (x, y) = ((point[0] * map.sx).round() as i64, (point[1] * map.sy).round() as i64);
            let near = (y - 4..=y + 4).any(|v| {
                (x - 4..=x + 4)
                    .any(|u| u >= 0 && v >= 0 && u < s && v < s && edges.get_pixel(u as u32, v as u32)[0] > 0)
            });
            total += 1;
            seen += usize::from(near);
        }
    }
    println!(
        "Canny {low}/{high}: {seen} of {total} corners ({:.1}%) have an edge within 4 px; edge density {:.3}",
        100.0 * seen as f64 / total.max(1) as f64,
        density / coco.images.len().max(1) as f64
    );
    Ok(())
}
