//! `autolabel` end to end: a generated route localized without the detector,
//! its scans' persistent 3D corners projected into its images, scored
//! against the generator's true labels, and written as a folder the
//! trainer reads.

use datasets::simulator::generate::{DatagenConfig, generate};
use localize::config::LocalizeConfig;
use localize::input::sequence::RecordedSequence;
use localize::labels::autolabel::{AutolabelConfig, autolabel};

#[test]
fn autolabels_of_a_generated_route_land_on_the_true_corners_and_train_reads_them() {
    let dir = tempfile::tempdir().unwrap();
    let mut data = DatagenConfig::default();
    data.detection.images = 2;
    data.detection.train = 1;
    data.sequence.frames = Some(40);
    data.sequence.speed_mps = 0.5;
    generate(dir.path(), &data).unwrap();
    let sequence = RecordedSequence::open(&dir.path().join("sequence")).unwrap();
    let truth = datasets::io::formats::read_coco(&dir.path().join("sequence/labels.json")).unwrap();
    let out = dir.path().join("labels");
    let config = AutolabelConfig::default();
    let checkpoint = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../checkpoints/faster-rcnn");
    let device = infer::backend::ComputeBackend::Flex.device().unwrap();
    let teacher = infer::detector::Detector::load(&checkpoint, device).unwrap();
    let localize = LocalizeConfig::default();
    let (report, run) = autolabel(&out, &sequence, &localize, Some(&teacher), &config, Some(&truth), false).unwrap();
    // Every image of the 20 m is labelled, the last fifth held out for testing.
    assert_eq!(report.images, 40);
    assert_eq!((report.train_images, report.test_images), (32, 8));
    assert!(report.persistent_corners >= 8, "{report:?}");
    assert!(report.persistent_corners < run.corner_tracks.as_ref().unwrap().tracks.len());
    assert!(report.labels_per_image.mean >= 0.5, "{report:?}");
    assert!(report.occlusion_checked && report.hidden > 0, "{report:?}");
    let score = &report.against_truth[0];
    assert!(report.against_truth[1].precision >= score.precision && report.against_truth[1].radius_px == 20.0);
    assert_eq!(score.images, 40);
    // The LIDAR's corners are few (no ceiling, few boxes) but where they are labelled they are right.
    assert!(score.precision >= 0.9, "{score:?}");
    assert!(score.recall >= 0.05, "{score:?}");
    assert!(score.median_error_px < 4.0, "{score:?}");
    // The folder holds what `train --data` reads, and what a user looks at.
    let train = datasets::io::formats::read_coco(&out.join("train.json")).unwrap();
    train.validate(&out).unwrap();
    assert_eq!(train.images.len(), 32);
    assert!(out.join(&train.images[0].file_name).is_file());
    assert!(out.join("preview").read_dir().unwrap().count() >= 1);
    // Where the 3D sensor cannot tell, the teacher's detections and the unsure
    // corners are ignore regions, never within the match radius of a label,
    // and the trainer reads them as such.
    assert!(report.teacher && report.ignore_regions > 0, "{report:?}");
    let crowd: Vec<_> = train.annotations.iter().filter(|a| a.iscrowd == 1).collect();
    // (A region's box is clipped to the image; whole boxes are centred on their point.)
    for region in crowd.iter().filter(|r| r.bbox[2] == 96.0 && r.bbox[3] == 96.0) {
        let c = region.bbox().centre();
        let near = train.annotations_of(region.image_id).filter(|a| a.iscrowd == 0).any(|a| {
            let p = a.point.unwrap();
            (p[0] - c[0]).hypot(p[1] - c[1]) <= config.match_radius_px as f32
        });
        assert!(!near, "{region:?}");
    }
    let loaded = infer::labeled::load_coco_set(&out.join("train.json"), &Default::default()).unwrap();
    assert_eq!(loaded.iter().map(|im| im.ignore.len()).sum::<usize>(), crowd.len());
    assert_eq!(loaded.iter().map(|im| im.truth.len()).sum::<usize>(), train.annotations.len() - crowd.len());
    assert!(out.join("run/trajectory.txt").is_file() && out.join("autolabel.json").is_file());
    let corners =
        datasets::io::formats::read_ply(&out.join("corners.ply"), datasets::io::formats::NonFinite::Reject).unwrap();
    assert_eq!(corners.len(), report.persistent_corners);
    // A second run into the same folder replaces it; a folder of other files is refused.
    let other = dir.path().join("other");
    std::fs::create_dir_all(&other).unwrap();
    std::fs::write(other.join("notes.txt"), "mine").unwrap();
    let Err(refused) = autolabel(&other, &sequence, &localize, None, &config, None, false) else {
        panic!("a folder of other files was written into");
    };
    assert!(refused.to_string().contains("other") && refused.to_string().contains("earlier autolabel"), "{refused}");
}
