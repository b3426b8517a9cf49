//! End to end across crates: a generated sequence localized by the
//! `localize` crate, with the shipped detector and with ground-truth corners.

use datasets::generate::{DatagenConfig, generate};
use localize::config::LocalizeConfig;
use localize::corner_source::CornerSource;
use localize::run::{metrics, run_sequence, write_outputs};
use localize::sequence::RecordedSequence;

/// The package folder, read when the test runs (cargo sets it), so that a
/// test binary reused from another checkout still finds its files.
fn manifest_dir() -> std::path::PathBuf {
    std::env::var_os("CARGO_MANIFEST_DIR").map_or_else(|| env!("CARGO_MANIFEST_DIR").into(), Into::into)
}

fn short_sequence(dir: &std::path::Path, frames: usize) -> RecordedSequence {
    let mut config = DatagenConfig::default();
    config.detection.images = 2;
    config.detection.train = 1;
    config.sequence.frames = Some(frames);
    // Ten times the paper's speed: 0.5 m between frames, the first 15 m of
    // the route (the first level, the first ramp and part of the second level).
    config.sequence.speed_mps = 0.5;
    generate(dir, &config).unwrap();
    RecordedSequence::open(&dir.join("sequence")).unwrap()
}

#[test]
fn fused_localization_beats_odometry_and_imu_on_a_generated_route() {
    let dir = tempfile::tempdir().unwrap();
    let sequence = short_sequence(dir.path(), 30);
    let mut corners = CornerSource::labels(&dir.path().join("sequence/labels.json"), 2.0, 1).unwrap();
    let config = LocalizeConfig::default();
    let result = run_sequence(&sequence, &mut corners, &config, false).unwrap();
    let m = metrics(&sequence, &result).unwrap().expect("ground truth is there");
    assert_eq!(m.frames, 30);
    let (fused, odometry) = (m.fused.overall, m.odometry_imu.overall);
    assert!(fused.ate_rmse < 0.05, "fused ATE {} m", fused.ate_rmse);
    assert!(fused.ate_rmse < odometry.ate_rmse / 2.0, "fused {} vs odometry/IMU {}", fused.ate_rmse, odometry.ate_rmse);
    assert!(m.fused.levels.iter().any(|l| l.name == "ramps"), "{:?}", m.fused.levels);
    let out = dir.path().join("run");
    write_outputs(&out, &config, &result, sequence.ground_truth.as_ref(), Some(&m)).unwrap();
    for file in ["trajectory.txt", "reference.txt", "frames.csv", "metrics.json", "trajectory.png", "config.json"] {
        assert!(out.join(file).is_file(), "{file} missing");
    }
    let (written, _) = datasets::formats::read_trajectory(&out.join("trajectory.txt")).unwrap();
    assert_eq!(written.len(), 30);
}

#[test]
fn the_shipped_detectors_run_inside_localization() {
    let dir = tempfile::tempdir().unwrap();
    let sequence = short_sequence(dir.path(), 4);
    // Each backbone's shipped checkpoint is of that backbone and finds corners.
    for backbone in ["faster-rcnn", "vgg16", "alexnet"] {
        let checkpoint = manifest_dir().join("../checkpoints").join(backbone);
        let config = infer::checkpoint::read_config(&checkpoint).unwrap();
        assert_eq!(config.backbone.name(), backbone);
        let mut detector = CornerSource::detector(&checkpoint, infer::backend::CpuBackend::Flex.device(), 0.3).unwrap();
        let result = run_sequence(&sequence, &mut detector, &LocalizeConfig::default(), false).unwrap();
        assert_eq!(result.trajectory.len(), 4);
        let found = result.frames.iter().map(|f| f.detections).sum::<usize>();
        assert!(found > 0, "{backbone}: no corner in 4 frames");
    }
    // A detector of another kind of file is refused with the path named.
    let error = CornerSource::detector(dir.path(), infer::backend::CpuBackend::Flex.device(), 0.3).err().unwrap();
    assert!(error.to_string().contains(&dir.path().display().to_string()), "{error}");
}
