//! Where a frame's 2D corners come from: the trained detector (the default),
//! or, behind a flag, the ground-truth projections of `labels.json` with
//! seeded pixel noise, to test the rest of the pipeline apart from the detector;
//! or none (the camera left out: LIDAR and odometry/IMU alone).

use std::collections::HashMap;
use std::path::Path;
use std::time::Instant;

use datasets::InvalidSetting;
use image::DynamicImage;
use infer::detector::Detector;
use rand::rngs::ChaCha8Rng;
use rand::{RngExt, SeedableRng};

use crate::error::Result;
use crate::input::frame_fault::FrameFault;

pub enum CornerSource {
    Detector {
        detector: Box<Detector>,
        min_score: f32,
    },
    Labels {
        by_image: HashMap<String, Vec<[f64; 2]>>,
        noise_px: f64,
        rng: Box<ChaCha8Rng>,
    },
    /// The camera left out: every frame has no 2D corners.
    Off,
}

impl CornerSource {
    pub fn detector(checkpoint: &Path, device: burn::prelude::Device, min_score: f32) -> Result<Self> {
        let detector = Detector::load(checkpoint, device)?;
        Ok(Self::Detector { detector: Box::new(detector), min_score })
    }

    /// Corner pixels from a COCO file with `point`s, by image file stem.
    pub fn labels(path: &Path, noise_px: f64, seed: u64) -> Result<Self> {
        if !(0.0..=1000.0).contains(&noise_px) {
            let problem = format!("{noise_px} px outside [0, 1000]");
            return Err(InvalidSetting::field("label_noise_px", problem).into());
        }
        let coco = datasets::io::formats::read_coco(path)?;
        let mut by_image: HashMap<String, Vec<[f64; 2]>> = HashMap::new();
        let names: HashMap<u64, String> = coco
            .images
            .iter()
            .map(|im| {
                let stem = Path::new(&im.file_name).file_stem().and_then(|s| s.to_str()).unwrap_or_default();
                (im.id, stem.to_string())
            })
            .collect();
        // Every labelled image has an entry, with or without corners: a frame
        // whose image the file does not list is told apart from one without corners.
        for name in names.values() {
            by_image.entry(name.clone()).or_default();
        }
        for a in &coco.annotations {
            let (Some(p), Some(name)) = (a.point, names.get(&a.image_id)) else { continue };
            by_image.entry(name.clone()).or_default().push([p[0] as f64, p[1] as f64]);
        }
        Ok(Self::Labels { by_image, noise_px, rng: Box::new(ChaCha8Rng::seed_from_u64(seed)) })
    }

    /// The corners of one frame (image file stem `stem`) and the milliseconds taken.
    pub fn corners(
        &mut self,
        stem: &str,
        image: Option<&DynamicImage>,
    ) -> (std::result::Result<Vec<[f64; 2]>, FrameFault>, f64) {
        let start = Instant::now();
        let found = match self {
            Self::Detector { detector, min_score } => match image {
                Some(im) => Ok(detector
                    .detect(im)
                    .into_iter()
                    .filter(|d| d.score >= *min_score)
                    .map(|d| {
                        let [x, y] = d.bbox.centre();
                        [x as f64, y as f64]
                    })
                    .collect()),
                None => Err(FrameFault::NoImage),
            },
            // Labels stand in for the detector, so they need the image the
            // detector would have seen: no image, no corners.
            Self::Labels { by_image, noise_px, rng } => match (image, by_image.get(stem)) {
                (None, _) => Err(FrameFault::NoImage),
                (Some(_), None) => Err(FrameFault::NotInLabels { stem: stem.to_string() }),
                (Some(_), Some(points)) => Ok(points
                    .iter()
                    .map(|&[x, y]| [x + *noise_px * gaussian(rng), y + *noise_px * gaussian(rng)])
                    .collect()),
            },
            Self::Off => Err(FrameFault::CameraOff),
        };
        (found, start.elapsed().as_secs_f64() * 1e3)
    }
}

/// A standard normal draw (Box-Muller).
fn gaussian(rng: &mut ChaCha8Rng) -> f64 {
    let u1: f64 = rng.random::<f64>().max(1e-300);
    let u2: f64 = rng.random();
    (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
}
