//! The paper's experiment end to end in its `--quick` form: generate, pretrain
//! three networks (the vgg16 and alexnet trunks, then the whole faster-rcnn
//! from the vgg16 trunk), fine-tune three networks, compare, localize with each, report;
//! then a second invocation that reuses every finished stage, and a third
//! with one changed setting that redoes only what depends on it.

use infer::config::Backbone;
use reproduce::plan::Plan;

#[test]
fn quick_reproduction_writes_a_sane_report_and_resumes() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path();
    let plan = Plan::quick();
    let results = reproduce::reproduce(out, &plan, false).unwrap();
    assert!(results.reused.is_empty(), "{:?}", results.reused);

    // faster-rcnn starts from its whole pretrained network, the others from trunks.
    let starts: Vec<_> = results.trunks.iter().map(|t| (t.family, t.path.is_dir())).collect();
    assert_eq!(starts, [(Backbone::Vgg16, false), (Backbone::Alexnet, false), (Backbone::FasterRcnn, true)]);
    assert_eq!(results.runs.len(), 3);
    for r in &results.runs {
        assert!((0.0..=1.0).contains(&r.metrics.ap50), "{:?} AP {}", r.backbone, r.metrics.ap50);
        assert!(r.final_train_loss.is_finite() && r.final_train_loss > 0.0, "{:?}", r);
        assert!(r.run.join("checkpoint/model.bpk").is_file());
    }
    assert_eq!(results.localization.len(), 3);
    for l in &results.localization {
        let all = |rows: &[reproduce::experiment::ErrorRow]| rows.iter().find(|r| r.level == "all").unwrap().clone();
        let (fused, odometry) = (all(&l.fused), all(&l.odometry_imu));
        assert_eq!(fused.matched, results.data.frames);
        assert!(fused.ate_rmse.is_finite() && fused.ate_rmse < 0.5, "{:?}: fused ATE {}", l.backbone, fused.ate_rmse);
        assert!(fused.ate_rmse < odometry.ate_rmse, "{:?}: fused {fused:?} vs {odometry:?}", l.backbone);
        assert!(l.fused.iter().any(|r| r.level == "ramps"), "{:?}", l.fused);
        assert!(l.dir.join("trajectory.png").is_file());
    }
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

    // Run again: nothing to do but the report.
    let again = reproduce::reproduce(out, &plan, false).unwrap();
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
