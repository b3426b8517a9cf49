//! `compare` on hand-made run folders: curves read back, the paper's loss
//! reduction, AP ranking, pictures written, and bad logs named.

use std::path::Path;

use infer::config::Backbone;
use infer::metrics::EvalMetrics;
use train::compare::{csv_table, markdown_table, read_run, reduction_percent, write_loss_plots};
use train::{Start, TrainConfig};

const HEADER: &str = "kind,epoch,iteration,loss,a,b,c,d,lr,elapsed_s\n";

/// A run folder whose epochs end at the given training and validation losses.
fn fake_run(dir: &Path, backbone: Backbone, epochs: &[(f64, f64)], ap: Option<f64>) {
    std::fs::create_dir_all(dir).unwrap();
    let config = TrainConfig::new(backbone, 0.25, "data".into());
    std::fs::write(dir.join("train_config.json"), serde_json::to_string(&config).unwrap()).unwrap();
    let mut csv = HEADER.to_string();
    for (e, (train, valid)) in epochs.iter().enumerate() {
        for k in 0..3 {
            let it = e * 3 + k;
            csv += &format!("train,{},{it},{},0,0,0,0,1e-3,{}\n", e + 1, train * 1.1, it as f64);
        }
        csv += &format!("train_epoch,{},{},{train},0,0,0,0,1e-3,{}\n", e + 1, e * 3 + 2, (e * 3 + 2) as f64);
        csv += &format!("valid_epoch,{},{},{valid},0,0,0,0,1e-3,{}\n", e + 1, e * 3 + 2, (e * 3 + 2) as f64);
    }
    std::fs::write(dir.join("losses.csv"), csv).unwrap();
    if let Some(ap50) = ap {
        let m = EvalMetrics {
            ap50,
            precision: 0.5,
            recall: 0.5,
            mean_pixel_error: Some(3.0),
            images: 10,
            ground_truths: 20,
            detections: 20,
            operating_score: 0.5,
        };
        std::fs::write(dir.join("metrics.json"), serde_json::to_string(&m).unwrap()).unwrap();
    }
}

#[test]
fn reduction_is_relative_to_the_other_run() {
    // The paper's form: a loss 55.18% lower than the other's.
    assert!((reduction_percent(0.4482, 1.0) - 55.18).abs() < 1e-9);
    assert!((reduction_percent(1.0, 2.0) - 50.0).abs() < 1e-12);
    assert!(reduction_percent(2.0, 1.0) < 0.0);
}

#[test]
fn runs_are_tabulated_ranked_and_drawn() {
    let dir = tempfile::tempdir().unwrap();
    let (a, b, c) = (dir.path().join("frcnn"), dir.path().join("vgg"), dir.path().join("alex"));
    fake_run(&a, Backbone::FasterRcnn, &[(2.0, 2.2), (1.0, 1.3)], Some(0.6));
    fake_run(&b, Backbone::Vgg16, &[(3.0, 3.1), (2.0, 2.5)], Some(0.7));
    fake_run(&c, Backbone::Alexnet, &[(4.0, 4.0), (4.0, 4.5)], None);
    let runs: Vec<_> = [&a, &b, &c].iter().map(|d| read_run(d).unwrap()).collect();
    assert_eq!(runs[0].iterations.len(), 6);
    assert_eq!(runs[0].final_train(), Some(1.0));
    assert_eq!(runs[1].final_valid(), Some(2.5));
    let table = markdown_table(&runs);
    let rows: Vec<&str> = table.lines().filter(|l| l.starts_with("| ")).collect();
    assert_eq!(rows.len(), 4, "{table}");
    // 1.0 against 2.0 and 4.0: 50% and 75% lower; vgg16 ranks first on AP.
    let cells = |row: &str| row.split(" | ").map(str::to_string).collect::<Vec<_>>();
    let (vgg, alex) = (cells(rows[2]), cells(rows[3]));
    assert_eq!(vgg[7], "50.00");
    assert_eq!(alex[7], "75.00");
    assert_eq!((cells(rows[1])[9].as_str(), vgg[9].as_str(), alex[9].as_str()), ("2", "1", "-"));
    assert!(table.contains("different functions"));
    // The start says where the trunk came from: a `pretrain` trunk by its folder.
    assert_eq!(vgg[3], "scratch");
    let mut pretrained = runs[1].clone();
    pretrained.config.start = Start::Trunk("checkpoints/pretrained/vgg16/trunk.safetensors".into());
    assert_eq!(pretrained.start(), "pretrained vgg16");
    pretrained.config.start = Start::Trunk("w/hed_vgg16_bsds500.safetensors".into());
    pretrained.config.pretrained_prune = true;
    assert_eq!(pretrained.start(), "hed_vgg16_bsds500.safetensors, pruned");
    assert_eq!(csv_table(&runs).lines().count(), 4);
    write_loss_plots(&runs, &dir.path().join("losses")).unwrap();
    let png = image::open(dir.path().join("losses.png")).unwrap();
    assert_eq!((png.width(), png.height()), (1400, 560));
    let svg = std::fs::read_to_string(dir.path().join("losses.svg")).unwrap();
    assert!(svg.starts_with("<svg") && svg.contains("frcnn"));
}

#[test]
fn a_bad_loss_log_is_named() {
    let dir = tempfile::tempdir().unwrap();
    let run = dir.path().join("broken");
    fake_run(&run, Backbone::Vgg16, &[(1.0, 1.0)], None);
    std::fs::write(run.join("losses.csv"), format!("{HEADER}train,1,0,abc,0,0,0,0,1e-3,0\n")).unwrap();
    let err = format!("{:#}", read_run(&run).unwrap_err());
    assert!(err.contains("losses.csv") && err.contains("line 2"), "{err}");
    let err = format!("{:#}", read_run(dir.path()).unwrap_err());
    assert!(err.contains("not a training run"), "{err}");
}
