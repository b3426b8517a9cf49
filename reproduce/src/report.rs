//! `report.md`: the paper's Table 1 and Table 2 from our run, its figures
//! 8a and 8b, the paper's own numbers beside ours, and where it ran.

use std::fmt::Write as _;
use std::path::Path;

use infer::config::Backbone;
use train::compare::{markdown_table, reduction_percent};

use crate::experiment::{ErrorRow, Results};
use crate::plan::{Plan, TrunkSource};

/// The paper's figures (its Table 1, Table 2 and conclusions).
pub mod paper {
    /// Trajectory error per network, metres.
    pub const ATE_M: [(&str, f64); 3] = [("faster-rcnn", 0.16), ("vgg16", 0.24), ("alexnet", 0.28)];
    pub const RMSE_X_M: f64 = 0.053;
    pub const RMSE_Y_M: f64 = 0.02;
    /// Faster R-CNN's final training loss below VGG16's and AlexNet's, percent.
    pub const LOSS_REDUCTION_VS_VGG16: f64 = 55.18;
    pub const LOSS_REDUCTION_VS_ALEXNET: f64 = 69.05;
}

/// The machine the run used.
#[derive(Debug, Clone)]
pub struct Machine {
    pub cpu: String,
    pub cores: usize,
    pub memory_gib: Option<f64>,
    pub os: String,
}

impl Machine {
    pub fn here() -> Self {
        let cpuinfo = std::fs::read_to_string("/proc/cpuinfo").unwrap_or_default();
        let cpu = cpuinfo
            .lines()
            .find(|l| l.starts_with("model name"))
            .and_then(|l| l.split(':').nth(1))
            .map(|s| s.trim().to_string())
            .unwrap_or_else(|| std::env::consts::ARCH.to_string());
        let memory_gib = std::fs::read_to_string("/proc/meminfo").ok().and_then(|m| {
            let line = m.lines().find(|l| l.starts_with("MemTotal:"))?;
            let kib: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
            Some(kib / (1024.0 * 1024.0))
        });
        Self {
            cpu,
            cores: std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1),
            memory_gib,
            os: std::env::consts::OS.to_string(),
        }
    }
}

fn m(v: f64) -> String {
    format!("{v:.4}")
}

fn error_table(s: &mut String, rows: &[(String, &[ErrorRow])]) {
    let _ = writeln!(s, "| method | level | frames | RMSE x | RMSE y | RMSE z | ATE |");
    let _ = writeln!(s, "|---|---|---|---|---|---|---|");
    for (method, errors) in rows {
        for e in *errors {
            let _ = writeln!(
                s,
                "| {method} | {} | {} | {} | {} | {} | {} |",
                e.level,
                e.matched,
                m(e.rmse_x),
                m(e.rmse_y),
                m(e.rmse_z),
                m(e.ate_rmse)
            );
        }
    }
}

/// The report's Markdown; picture paths are relative to `out`.
pub fn markdown(plan: &Plan, results: &Results, machine: &Machine, invocation_s: f64) -> String {
    let mut s = String::new();
    introduction(&mut s, plan, results, machine, invocation_s);
    let _ = writeln!(s, "\n## Table 1: training (paper's Table 1)\n");
    let _ = write!(s, "{}", markdown_table(&results.records));
    let _ = writeln!(s, "\n![Figure 8a: training and validation loss](compare/losses.png)\n");

    localization_table(&mut s, results);
    paper_beside_ours(&mut s, results);
    s
}

/// The machine, the time, the data and where the networks started.
fn introduction(s: &mut String, plan: &Plan, results: &Results, machine: &Machine, invocation_s: f64) {
    let _ = writeln!(s, "# Reproduction: 2D corners + 3D planes, Faster R-CNN vs VGG16 vs AlexNet\n");
    let stage_s = results.data.seconds
        + results.trunks.iter().map(|t| t.seconds).sum::<f64>()
        + results.runs.iter().map(|r| r.seconds).sum::<f64>()
        + results.localization.iter().map(|l| l.seconds).sum::<f64>();
    let _ = writeln!(
        s,
        "{} run on {} ({} cores{}, {}). The stages took {:.1} min in all; this invocation took {:.1} min{}.\n",
        if plan.quick { "A `--quick` smoke" } else { "The full" },
        machine.cpu,
        machine.cores,
        machine.memory_gib.map(|g| format!(", {g:.0} GiB")).unwrap_or_default(),
        machine.os,
        stage_s / 60.0,
        invocation_s / 60.0,
        if results.reused.is_empty() {
            String::new()
        } else {
            format!(" (reused from an earlier invocation: {})", results.reused.join(", "))
        }
    );
    if plan.quick {
        let _ = writeln!(s, "**Smoke run: tiny data and two epochs; its numbers say only that every stage works.**\n");
    }
    let d = &results.data;
    match &plan.recorded {
        Some(dir) => {
            let _ = writeln!(
                s,
                "Data: recorded, from `{}`: {} labeled images ({} corner labels) and a {}-frame sequence.\n",
                dir.display(),
                d.detection_images,
                d.detection_labels,
                d.frames
            );
        }
        None => {
            let _ = writeln!(
                s,
                "Data: {} labeled images ({} corner labels; {} for training) and a {}-frame sequence over a {:.1} m \
                 route through three levels joined by ramps, at {} m/s and {} Hz (`data/`).\n",
                d.detection_images,
                d.detection_labels,
                plan.datagen.detection.train,
                d.frames,
                d.route_length_m,
                plan.datagen.sequence.speed_mps,
                plan.datagen.sequence.rate_hz
            );
        }
    }
    let _ = writeln!(s, "Transferred from:\n");
    for t in &results.trunks {
        let source = match &plan.trunks {
            TrunkSource::Shipped(_) => "shipped, pretrained by `pretrain` on a generated corpus of other worlds",
            TrunkSource::Pretrain { .. } => "pretrained in this run on a generated corpus of other worlds",
        };
        let what =
            if matches!(t.start, train::Start::Detector(_)) { "whole network (trunk and heads)" } else { "trunk" };
        let _ = writeln!(
            s,
            "- {} {what} ({source}; corpus test AP@0.5 {})",
            t.family,
            t.corpus_ap50.map(|a| format!("{a:.3}")).unwrap_or_else(|| "unknown".into())
        );
    }
}

/// Table 2 (the paper's), with each detector's frames corrected and Figure 8b.
fn localization_table(s: &mut String, results: &Results) {
    let _ = writeln!(s, "## Table 2: localization error in metres (paper's Table 2)\n");
    let mut rows: Vec<(String, &[ErrorRow])> =
        results.localization.iter().map(|l| (format!("fused, {}", l.backbone), l.fused.as_slice())).collect();
    if let Some(first) = results.localization.first() {
        rows.push(("odometry/IMU alone".into(), first.odometry_imu.as_slice()));
    }
    if rows.iter().all(|(_, r)| r.is_empty()) {
        let _ = writeln!(s, "The sequence has no `groundtruth.txt`: trajectories only, no errors.");
    } else {
        error_table(s, &rows);
    }
    let _ = writeln!(s);
    for l in &results.localization {
        let _ = writeln!(
            s,
            "- {}: {} of {} frames corrected by corners and walls, {:.0} ms a frame (detector included).",
            l.backbone, l.fused_frames, l.frames, l.mean_total_ms
        );
    }
    if let Some(first) = results.localization.first() {
        let _ = writeln!(
            s,
            "\n![Figure 8b: estimated, odometry/IMU and true trajectories]({}/trajectory.png)\n",
            Path::new("localize").join(first.backbone.name()).display()
        );
    }
}

/// The paper's published figures beside this run's.
fn paper_beside_ours(s: &mut String, results: &Results) {
    let _ = writeln!(s, "## The paper's figures beside ours\n");
    let _ = writeln!(s, "| quantity | paper | ours |");
    let _ = writeln!(s, "|---|---|---|");
    let overall = |b: Backbone| {
        results.localization.iter().find(|l| l.backbone == b).and_then(|l| l.fused.iter().find(|r| r.level == "all"))
    };
    for (name, paper_ate) in paper::ATE_M {
        let ours = results
            .localization
            .iter()
            .find(|l| l.backbone.name() == name)
            .and_then(|l| l.fused.iter().find(|r| r.level == "all"))
            .map(|r| m(r.ate_rmse))
            .unwrap_or_else(|| "not run".into());
        let _ = writeln!(s, "| trajectory error (ATE), {name} | {paper_ate} m | {ours} m |");
    }
    let proposed = overall(Backbone::FasterRcnn);
    let _ = writeln!(
        s,
        "| RMSE x, faster-rcnn | {} m | {} |",
        paper::RMSE_X_M,
        proposed.map(|r| format!("{} m", m(r.rmse_x))).unwrap_or_else(|| "not run".into())
    );
    let _ = writeln!(
        s,
        "| RMSE y, faster-rcnn | {} m | {} |",
        paper::RMSE_Y_M,
        proposed.map(|r| format!("{} m", m(r.rmse_y))).unwrap_or_else(|| "not run".into())
    );
    let loss = |b: Backbone| results.runs.iter().find(|r| r.backbone == b).map(|r| r.final_train_loss);
    for (other, paper_pct) in
        [(Backbone::Vgg16, paper::LOSS_REDUCTION_VS_VGG16), (Backbone::Alexnet, paper::LOSS_REDUCTION_VS_ALEXNET)]
    {
        let ours = match (loss(Backbone::FasterRcnn), loss(other)) {
            (Some(a), Some(b)) => format!("{:.2}%", reduction_percent(a, b)),
            _ => "not run".into(),
        };
        let _ = writeln!(s, "| final training loss below {other}'s | {paper_pct}% | {ours} |");
    }
    let _ = writeln!(
        s,
        "\nThe paper's losses and ours are different functions of different networks on different data; the \
         percentages compare training progress only. Its trajectory errors come from a real robot; ours from \
         the generated sequence, whose ground truth is exact.\n"
    );
}
