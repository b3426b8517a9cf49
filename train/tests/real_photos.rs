//! Fine-tuning the shipped pretrained detector on real photographs, as a
//! user would on their own: York Urban's indoor photos (read from the
//! shared data folder beside the repository, skipped without it) with
//! their derived junctions as weak labels, split in halves by
//! `coco_halves`, preprocessed with thresholds that follow each photo's
//! contrast; the training loss falls and the test half is scored.

use std::path::{Path, PathBuf};

use datasets::io::formats::{coco_halves, labelled_photos, write_coco};
use infer::config::Backbone;
use train::{Start, TrainConfig};

fn repository() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

#[test]
fn the_pretrained_detector_fine_tunes_on_york_urban_photos() {
    let york = repository().join("../shared/data/york_urban_lines");
    if !york.is_dir() {
        eprintln!("skipped: {} is not here", york.display());
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    // Six indoor photos (corridors and rooms), linked as a user's folder.
    let photos_dir = dir.path().join("photos");
    std::fs::create_dir(&photos_dir).unwrap();
    for name in ["P1020826", "P1020828", "P1020829", "P1020830", "P1020833", "P1020838"] {
        let photo = york.join(format!("images/{name}.jpg"));
        assert!(photo.is_file(), "{} is missing", photo.display());
        std::fs::copy(&photo, photos_dir.join(format!("{name}.jpg"))).unwrap();
    }
    let photos = labelled_photos(&photos_dir, &york.join("junctions_derived")).unwrap();
    assert_eq!(photos.len(), 6);
    let split = coco_halves(&photos, 2, 96.0).unwrap();
    let [train_half, test_half] = &split.halves;
    assert_eq!((train_half.images.len(), test_half.images.len()), (3, 3));
    assert!(train_half.annotations.len() > 60, "{} junctions", train_half.annotations.len());
    let data = dir.path().join("york");
    std::fs::create_dir(&data).unwrap();
    write_coco(&data.join("train.json"), train_half).unwrap();
    write_coco(&data.join("test.json"), test_half).unwrap();

    let mut config = TrainConfig::new(Backbone::FasterRcnn, 0.25, data);
    config.start_from(Start::Detector(repository().join("checkpoints/pretrained/faster-rcnn/detector")));
    config.epochs = 4;
    config.batch_size = 3;
    config.val_fraction = 0.0;
    config.augment = false;
    config.warmup_iterations = 1;
    // Thresholds that follow each photo's contrast (`--adaptive-canny`).
    config.detector.preprocess.adaptive_canny = Some(Default::default());
    let run = dir.path().join("run");
    train::train(Some(config), &run, false).unwrap();
    let csv = std::fs::read_to_string(run.join("losses.csv")).unwrap();
    let losses: Vec<f64> = csv
        .lines()
        .filter(|l| l.starts_with("train,"))
        .map(|l| l.split(',').nth(3).unwrap().parse().unwrap())
        .collect();
    eprintln!("training losses {losses:?}");
    assert_eq!(losses.len(), 4, "one step an epoch: {losses:?}");
    assert!(losses[3] < 0.9 * losses[0], "the loss on real photos falls: {losses:?}");
    let metrics: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(run.join("metrics.json")).unwrap()).unwrap();
    assert_eq!(metrics["images"], 3);
    assert_eq!(metrics["ground_truths"].as_u64().unwrap() as usize, test_half.annotations.len());
    // The checkpoint keeps the choice, so inference preprocesses the same way.
    let kept = infer::checkpoint::read_config(&run.join("checkpoint")).unwrap();
    assert_eq!(kept.preprocess.adaptive_canny, Some(Default::default()));
}
