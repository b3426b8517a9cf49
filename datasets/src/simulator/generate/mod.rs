//! Writes the default data of the project from the synthetic world: a
//! detection data set (images, Canny images, COCO train/test splits) and a
//! localization sequence (images, LIDAR clouds, odometry, IMU, ground truth,
//! calibration, corner labels), plus preview pictures.

mod config;
mod detection;
mod preview;
mod sequence;
mod world_description;

pub use config::{DatagenConfig, DetectionConfig, SequenceConfig};
pub(crate) use detection::{render_views, write_coco_splits};
pub use preview::draw_labels;
pub use sequence::{Frame, Sequence, Shot};
pub use world_description::{LevelDescription, WorldDescription};

use std::path::Path;

use crate::atomic;
use crate::error::{DataError, Result};
use crate::seed::mix;
use crate::simulator::world::World;
use crate::simulator::world::rig::Rig;
use detection::write_detection_set;
use preview::write_previews;
use sequence::write_sequence;

/// What a generation run produced, for the command's summary.
#[derive(Debug, Clone, PartialEq)]
pub struct Summary {
    pub detection_images: usize,
    pub detection_labels: usize,
    pub frames: usize,
    pub route_length_m: f64,
    /// Frames whose time runs past the end of the route (the robot waits there).
    pub frames_after_route_end: usize,
}

/// Streams of the one seed, so that each part draws its own numbers.
pub(crate) mod stream {
    pub const APPEARANCE: u64 = 1;
    pub const DETECTION: u64 = 2;
    pub const SEQUENCE_LIGHT: u64 = 3;
    pub const LIDAR: u64 = 4;
    pub const ODOMETRY: u64 = 5;
    pub const IMU: u64 = 6;
}

pub(crate) fn key(seed: u64, stream: u64, index: u64) -> u64 {
    mix(mix(seed ^ stream.wrapping_mul(0x9e37_79b9)) ^ index)
}

/// Generates the detection data set into `out/detection` and the sequence
/// into `out/sequence`, and previews into `out/preview`.
pub fn generate(out: &Path, config: &DatagenConfig) -> Result<Summary> {
    generate_then(out, config, |_| Ok(()))
}

/// `generate`, with `more` run on the finished folder before `datagen.json`
/// is written (what else the run makes from it, such as a recording of the
/// sequence): a kill in `more` leaves the run looking unfinished.
pub fn generate_then(out: &Path, config: &DatagenConfig, more: impl FnOnce(&Path) -> Result<()>) -> Result<Summary> {
    config.validate().map_err(|e| DataError::setting(out, e))?;
    let world = World::new(&config.world, key(config.seed, stream::APPEARANCE, 0));
    let rig = Rig::default();
    let route_m =
        crate::simulator::world::route::Route::new(&world.layout.route, config.sequence.turn_radius_m).length();
    if config.sequence.start_m >= route_m {
        let problem =
            format!("sequence.start_m {} m is past the end of the {route_m:.1} m route", config.sequence.start_m);
        return Err(DataError::invalid(out, problem));
    }
    // The folder is one run: an earlier run's parts go first (a longer
    // sequence would leave its extra frames), and `datagen.json` comes last,
    // so that a killed run never looks finished.
    for part in ["datagen.json", "detection", "sequence", "preview"] {
        let path = out.join(part);
        let removed = if path.is_dir() { std::fs::remove_dir_all(&path) } else { std::fs::remove_file(&path) };
        match removed {
            Err(e) if e.kind() != std::io::ErrorKind::NotFound => return Err(DataError::io(&path, e)),
            _ => {}
        }
    }
    let (detection_images, detection_labels) = write_detection_set(&out.join("detection"), &world, &rig, config)?;
    let sequence = write_sequence(&out.join("sequence"), &world, &rig, config)?;
    write_previews(&out.join("preview"), &world, &rig, &sequence)?;
    more(out)?;
    atomic::write_json(&out.join("datagen.json"), config)?;
    Ok(Summary {
        detection_images,
        detection_labels,
        frames: sequence.frames.len(),
        route_length_m: sequence.route_length_m,
        frames_after_route_end: sequence.frames_after_route_end,
    })
}
