//! The paper's experiment end to end in its `--quick` form: generate, pretrain
//! three networks (the vgg16 and alexnet trunks, then the whole faster-rcnn
//! from the vgg16 trunk), fine-tune three networks, compare, localize with each, report;
//! then a second invocation that reuses every finished stage, and a third
//! with one changed setting that redoes only what depends on it. Every
//! figure the report states is recomputed here from the files the run left
//! (the checkpoints on the test split, the trajectories against the ground
//! truth), so a report that mixed up runs or misquoted a number fails.

use infer::config::Backbone;
use localize::evaluation::eval::{Alignment, compare};
use reproduce::plan::Plan;

#[test]
fn quick_reproduction_writes_a_sane_report_and_resumes() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path();
    let plan = Plan::quick();
    let results = reproduce::reproduce(out, &plan, false).unwrap();
    assert!(results.reused.is_empty(), "{:?}", results.reused);

    // faster-rcnn starts from its whole pretrained network, the others from trunks.
    let starts: Vec<_> = results
        .trunks
        .iter()
        .map(|t| (t.family, matches!(&t.start, train::Start::Detector(p) if p.is_dir())))
        .collect();
    assert_eq!(starts, [(Backbone::Vgg16, false), (Backbone::Alexnet, false), (Backbone::FasterRcnn, true)]);
    checkpoints_score_what_was_recorded(out, &plan, &results);
    let fused_rows = trajectories_give_the_recorded_errors(out, &results);
    report_quotes_the_runs(out, &fused_rows);
    resumes_only_what_changed(out, &plan, &results);
}

/// Each run's AP@0.5 is what its written checkpoint scores on the test split.
fn checkpoints_score_what_was_recorded(out: &std::path::Path, plan: &Plan, results: &reproduce::Results) {
    assert_eq!(results.runs.len(), 3);
    let test_set = out.join("data/detection/test.json");
    for r in &results.runs {
        assert!(r.final_train_loss.is_finite() && r.final_train_loss > 0.0, "{:?}", r);
        // The metrics are those of the checkpoint that was written, on the test split.
        let detector = infer::Detector::load(&r.run.join("checkpoint"), plan.backend.device().unwrap()).unwrap();
        let set = infer::labeled::load_coco_set(&test_set, &detector.config.preprocess).unwrap();
        let again = infer::eval::evaluate_set(&detector, &set, 4);
        assert!(
            (again.ap50 - r.metrics.ap50).abs() < 1e-4,
            "{:?}: AP@0.5 recorded {} but the checkpoint scores {}",
            r.backbone,
            r.metrics.ap50,
            again.ap50
        );
    }
}

/// Each backbone's fused errors are those of its trajectory file against the
/// ground truth, and below odometry/IMU's; returns the "all" rows.
fn trajectories_give_the_recorded_errors(
    out: &std::path::Path,
    results: &reproduce::Results,
) -> Vec<(Backbone, reproduce::experiment::ErrorRow)> {
    assert_eq!(results.localization.len(), 3);
    let truth = datasets::io::formats::read_tum(&out.join("data/sequence/groundtruth.txt")).unwrap();
    let mut fused_rows = Vec::new();
    for l in &results.localization {
        let all = |rows: &[reproduce::experiment::ErrorRow]| rows.iter().find(|r| r.level == "all").unwrap().clone();
        let (fused, odometry) = (all(&l.fused), all(&l.odometry_imu));
        assert_eq!(fused.matched, results.data.frames);
        assert!(fused.ate_rmse < odometry.ate_rmse, "{:?}: fused {fused:?} vs {odometry:?}", l.backbone);
        assert!(l.fused.iter().any(|r| r.level == "ramps"), "{:?}", l.fused);
        assert!(l.dir.join("trajectory.png").is_file());
        // The errors are those of the trajectory file against the ground truth.
        let estimate = datasets::io::formats::read_tum(&l.dir.join("trajectory.txt")).unwrap();
        let e = compare(&truth, &estimate, Alignment::None, 0.01).unwrap().summary;
        assert_eq!(e.matched, fused.matched);
        for (name, recorded, recomputed) in [
            ("x", fused.rmse_x, e.rmse_x),
            ("y", fused.rmse_y, e.rmse_y),
            ("z", fused.rmse_z, e.rmse_z),
            ("ATE", fused.ate_rmse, e.ate_rmse),
        ] {
            assert!(
                (recorded - recomputed).abs() < 1e-6,
                "{:?}: {name} RMSE recorded {recorded} but trajectory.txt gives {recomputed}",
                l.backbone
            );
        }
        fused_rows.push((l.backbone, fused));
    }
    fused_rows
}

/// The report has its tables and figures, the paper's numbers beside ours,
/// and each backbone's own errors.
fn report_quotes_the_runs(out: &std::path::Path, fused_rows: &[(Backbone, reproduce::experiment::ErrorRow)]) {
    for file in ["report.md", "plan.json", "compare/losses.png", "compare/losses.svg", "compare/table.csv"] {
        assert!(out.join(file).is_file(), "{file} missing");
    }
    let report = std::fs::read_to_string(out.join("report.md")).unwrap();
    for needle in ["## Table 1", "## Table 2", "](compare/losses.png)", "](localize/faster-rcnn/trajectory.png)"] {
        assert!(report.contains(needle), "report lacks {needle}:\n{report}");
    }
    // The paper's numbers stand beside ours, and every backbone has its row.
    for needle in ["55.18%", "69.05%", "0.16 m", "0.053 m", "odometry/IMU alone", "fused, alexnet"] {
        assert!(report.contains(needle), "report lacks {needle}:\n{report}");
    }
    assert!(!report.contains("NaN") && !report.contains("not run"), "{report}");
    // Table 2 quotes each backbone's own errors.
    for (backbone, e) in fused_rows {
        let row = format!(
            "| fused, {backbone} | all | {} | {:.4} | {:.4} | {:.4} | {:.4} |",
            e.matched, e.rmse_x, e.rmse_y, e.rmse_z, e.ate_rmse
        );
        assert!(report.contains(&row), "report lacks {row}:\n{report}");
    }
}

/// A second invocation reuses every stage; one more alexnet epoch redoes
/// only alexnet's training and localization.
fn resumes_only_what_changed(out: &std::path::Path, plan: &Plan, results: &reproduce::Results) {
    // Run again: nothing to do but the report.
    let again = reproduce::reproduce(out, plan, false).unwrap();
    assert_eq!(again.reused.len(), 1 + 3 + 3 + 3, "{:?}", again.reused);
    assert_eq!(again.runs[0].final_train_loss, results.runs[0].final_train_loss);

    // One more alexnet epoch: only alexnet's training and localization rerun.
    let mut longer = plan.clone();
    longer.runs.iter_mut().find(|r| r.backbone == Backbone::Alexnet).unwrap().epochs += 1;
    let third = reproduce::reproduce(out, &longer, false).unwrap();
    let redone: Vec<_> = ["training alexnet", "localization alexnet"].into_iter().map(String::from).collect();
    assert_eq!(third.reused.len(), 8, "{:?}", third.reused);
    assert!(redone.iter().all(|s| !third.reused.contains(s)), "{:?}", third.reused);
    let alexnet = third.records.iter().find(|r| r.config.detector.backbone == Backbone::Alexnet).unwrap();
    assert_eq!(alexnet.train_epochs.len(), 3);
}
