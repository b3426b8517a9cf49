//! Comparison of training runs (the paper's Table 1 and Figure 8a): each
//! run's loss log and metrics read back from its folder, one picture of all
//! loss curves and one table.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use datasets::plot::{canvas, plot_error, register_font, write_png};
use infer::checkpoint::{self, CheckpointMeta};
use infer::metrics::EvalMetrics;
use plotters::coord::Shift;
use plotters::coord::types::RangedCoordf64;
use plotters::prelude::*;

use crate::config::TrainConfig;
use crate::error::{Result, TrainError, read_json};
pub use crate::loss_log::LossPoint;
use crate::loss_log::{LossLog, RowKind};
use crate::run_folder::{CONFIG_FILE, RunFolder};

/// What the comparison needs of one run folder.
#[derive(Debug, Clone)]
pub struct RunRecord {
    pub name: String,
    pub dir: PathBuf,
    pub config: TrainConfig,
    /// Loss of every training iteration.
    pub iterations: Vec<LossPoint>,
    /// Mean training loss of every epoch.
    pub train_epochs: Vec<LossPoint>,
    /// Validation loss after every epoch.
    pub valid_epochs: Vec<LossPoint>,
    pub metrics: Option<EvalMetrics>,
    pub meta: Option<CheckpointMeta>,
}

impl RunRecord {
    pub fn final_train(&self) -> Option<f64> {
        self.train_epochs.last().map(|p| p.loss)
    }

    pub fn final_valid(&self) -> Option<f64> {
        self.valid_epochs.last().map(|p| p.loss)
    }

    pub fn seconds(&self) -> Option<f64> {
        self.meta.as_ref().map(|m| m.train_seconds).or_else(|| self.train_epochs.last().map(|p| p.elapsed_s))
    }

    /// `pretrained file` (or `scratch`), with the frozen layers.
    pub fn start(&self) -> String {
        let from = match self.config.start.path() {
            Some(p) => {
                let name = p.file_name().map(|f| f.to_string_lossy().into_owned());
                match name {
                    // Every `pretrain` output has the same file name; its
                    // folder says which trunk it is.
                    Some(n) if n == crate::pretrain::TRUNK_FILE => {
                        let folder = p.parent().and_then(|d| d.file_name()).map(|d| d.to_string_lossy());
                        format!("pretrained {}", folder.as_deref().unwrap_or("trunk"))
                    }
                    Some(n) => n,
                    None => p.display().to_string(),
                }
            }
            None => "scratch".into(),
        };
        let from = if self.config.pretrained_prune { format!("{from}, pruned") } else { from };
        if self.config.freeze > 0 { format!("{from}, {} frozen", self.config.freeze) } else { from }
    }
}

/// Reads a run folder written by `train`.
pub fn read_run(dir: &Path) -> Result<RunRecord> {
    let folder = RunFolder::new(dir);
    if !folder.holds_run() {
        return Err(TrainError::Folder {
            path: dir.to_path_buf(),
            what: format!("not a training run (no {CONFIG_FILE})"),
        });
    }
    let config: TrainConfig = read_json(&folder.config_path(), "settings")?;
    let losses_path = folder.losses_path();
    let text = datasets::atomic::read_text(&losses_path)?;
    let log = LossLog::parse(&text).map_err(|what| TrainError::LossLog { path: losses_path.clone(), what })?;
    let train_epochs = log.points(RowKind::TrainEpoch);
    if train_epochs.is_empty() {
        return Err(TrainError::LossLog { path: losses_path, what: "no completed epoch yet".into() });
    }
    let metrics_path = folder.metrics_path();
    let metrics = if metrics_path.is_file() { Some(read_json(&metrics_path, "metrics")?) } else { None };
    let meta = checkpoint::read_meta(&folder.checkpoint_dir()).ok();
    let name = dir.file_name().map(|f| f.to_string_lossy().into_owned()).unwrap_or_else(|| dir.display().to_string());
    Ok(RunRecord {
        name,
        dir: dir.to_path_buf(),
        config,
        iterations: log.points(RowKind::Train),
        train_epochs,
        valid_epochs: log.points(RowKind::ValidEpoch),
        metrics,
        meta,
    })
}

/// How much lower the first run's final training loss is than `other`'s, in
/// percent of the other's (the paper's 55.18% and 69.05%).
pub fn reduction_percent(first: f64, other: f64) -> f64 {
    100.0 * (other - first) / other
}

fn fmt(v: Option<f64>, digits: usize) -> String {
    v.map(|v| format!("{v:.digits$}")).unwrap_or_else(|| "-".into())
}

const COLUMNS: [&str; 13] = [
    "run",
    "backbone",
    "width",
    "start",
    "epochs",
    "final train loss",
    "final valid loss",
    "first run's train loss lower by (%)",
    "AP@0.5",
    "AP rank",
    "pixel error (px)",
    "train time (min)",
    "folder",
];

/// The table's rows, as text cells in the order of [`COLUMNS`].
fn rows(runs: &[RunRecord]) -> Vec<Vec<String>> {
    let first = runs.first().and_then(RunRecord::final_train);
    let mut by_ap: Vec<(usize, f64)> =
        runs.iter().enumerate().filter_map(|(i, r)| r.metrics.as_ref().map(|m| (i, m.ap50))).collect();
    by_ap.sort_by(|a, b| b.1.total_cmp(&a.1));
    runs.iter()
        .enumerate()
        .map(|(i, r)| {
            let reduction = match (i, first, r.final_train()) {
                (0, ..) => "-".to_string(),
                (_, Some(f), Some(o)) => format!("{:.2}", reduction_percent(f, o)),
                _ => "-".into(),
            };
            let rank = by_ap.iter().position(|(k, _)| *k == i).map(|p| (p + 1).to_string()).unwrap_or("-".into());
            vec![
                r.name.clone(),
                r.config.detector.backbone.to_string(),
                format!("{}", r.config.detector.width),
                r.start(),
                r.train_epochs.len().to_string(),
                fmt(r.final_train(), 4),
                fmt(r.final_valid(), 4),
                reduction,
                fmt(r.metrics.as_ref().map(|m| m.ap50), 3),
                rank,
                fmt(r.metrics.as_ref().and_then(|m| m.mean_pixel_error), 2),
                fmt(r.seconds().map(|s| s / 60.0), 1),
                r.dir.display().to_string(),
            ]
        })
        .collect()
}

pub const LOSS_NOTE: &str = "The losses are different functions: faster-rcnn's is the sum of the RPN objectness, \
RPN box, classifier and box-regression losses; vgg16's and alexnet's is the grid head's presence, offset and size \
losses. Their values (and the percentages) compare training progress, not detectors: rank the networks by AP@0.5.";

pub fn markdown_table(runs: &[RunRecord]) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "| {} |", COLUMNS.join(" | "));
    let _ = writeln!(s, "|{}", "---|".repeat(COLUMNS.len()));
    for row in rows(runs) {
        let _ = writeln!(s, "| {} |", row.join(" | "));
    }
    let _ = writeln!(s, "\n{LOSS_NOTE}");
    s
}

pub fn csv_table(runs: &[RunRecord]) -> String {
    let quote = |c: &str| {
        if c.contains(',') || c.contains('"') { format!("\"{}\"", c.replace('"', "\"\"")) } else { c.to_string() }
    };
    let mut s = COLUMNS.iter().map(|c| quote(c)).collect::<Vec<_>>().join(",") + "\n";
    for row in rows(runs) {
        s += &(row.iter().map(|c| quote(c)).collect::<Vec<_>>().join(",") + "\n");
    }
    s
}

const PALETTE: [RGBColor; 8] = [
    RGBColor(31, 119, 180),
    RGBColor(214, 39, 40),
    RGBColor(44, 160, 44),
    RGBColor(255, 127, 14),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
    RGBColor(227, 119, 194),
    RGBColor(23, 190, 207),
];

const PLOT_SIZE: (u32, u32) = (1400, 560);

/// Writes the loss curves of all runs as `stem.png` and `stem.svg`.
pub fn write_loss_plots(runs: &[RunRecord], stem: &Path) -> Result<()> {
    register_font();
    let png = stem.with_extension("png");
    let mut pixels = canvas(PLOT_SIZE.0, PLOT_SIZE.1);
    draw(BitMapBackend::with_buffer(&mut pixels, PLOT_SIZE).into_drawing_area(), runs)
        .map_err(|e| plot_error(&png, e))?;
    write_png(&png, PLOT_SIZE.0, PLOT_SIZE.1, pixels)?;
    let svg_path = stem.with_extension("svg");
    let mut svg = String::new();
    draw(SVGBackend::with_string(&mut svg, PLOT_SIZE).into_drawing_area(), runs)
        .map_err(|e| plot_error(&svg_path, e))?;
    datasets::atomic::write_bytes(&svg_path, svg.as_bytes())?;
    Ok(())
}

/// A log-axis tick without float noise: 0.7, not 0.7000000000000001.
fn tick_label(v: f64) -> String {
    let s = format!("{v:.3}");
    s.trim_end_matches('0').trim_end_matches('.').to_string()
}

type LossChart<'a, DB> = ChartContext<'a, DB, Cartesian2d<RangedCoordf64, LogCoord<f64>>>;

/// A chart with a linear x axis and a log loss axis, its mesh drawn.
fn loss_chart<'a, DB: DrawingBackend>(
    area: &'a DrawingArea<DB, Shift>,
    caption: &str,
    x_desc: &str,
    x: std::ops::Range<f64>,
    y: std::ops::Range<f64>,
) -> Result<LossChart<'a, DB>, DrawingAreaErrorKind<DB::ErrorType>> {
    let mut chart = ChartBuilder::on(area)
        .caption(caption, ("sans-serif", 22))
        .margin(14)
        .x_label_area_size(40)
        .y_label_area_size(60)
        .build_cartesian_2d(x, y.log_scale())?;
    chart
        .configure_mesh()
        .x_desc(x_desc)
        .y_desc("loss")
        .x_label_formatter(&|v| format!("{v:.0}"))
        .y_label_formatter(&|v| tick_label(*v))
        .max_light_lines(2)
        .draw()?;
    Ok(chart)
}

/// Left: training loss against iterations (every iteration faint, epoch
/// means solid). Right: training (solid) and validation (dashed) loss
/// against epochs. Log scale, as the runs' losses differ by their kind.
fn draw<DB: DrawingBackend>(root: DrawingArea<DB, Shift>, runs: &[RunRecord]) -> Result<(), String>
where
    DB::ErrorType: 'static,
{
    let e = |e: DrawingAreaErrorKind<DB::ErrorType>| e.to_string();
    root.fill(&WHITE).map_err(e)?;
    let all = runs.iter().flat_map(|r| r.iterations.iter().chain(&r.train_epochs).chain(&r.valid_epochs));
    let (lo, hi) = all.fold((f64::MAX, f64::MIN), |(lo, hi), p| {
        if p.loss > 0.0 && p.loss.is_finite() { (lo.min(p.loss), hi.max(p.loss)) } else { (lo, hi) }
    });
    let (lo, hi) = if lo < hi { (lo * 0.8, hi * 1.25) } else { (0.01, 10.0) };
    let max_iter = runs.iter().flat_map(|r| r.iterations.last()).map(|p| p.iteration).max().unwrap_or(1).max(1);
    let max_epoch = runs.iter().map(|r| r.train_epochs.len()).max().unwrap_or(1).max(1);
    let (left, right) = root.split_horizontally(PLOT_SIZE.0 / 2);

    let mut chart =
        loss_chart(&left, "training loss by iteration", "iteration", 0f64..max_iter as f64, lo..hi).map_err(e)?;
    for (r, colour) in runs.iter().zip(PALETTE.iter().cycle()) {
        let faint = colour.mix(0.25);
        chart
            .draw_series(LineSeries::new(r.iterations.iter().map(|p| (p.iteration as f64, p.loss)), faint))
            .map_err(e)?;
        let colour = *colour;
        chart
            .draw_series(LineSeries::new(
                r.train_epochs.iter().map(|p| (p.iteration as f64, p.loss)),
                colour.stroke_width(2),
            ))
            .map_err(e)?
            .label(format!("{} ({}, {})", r.name, r.config.detector.backbone, r.start()))
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 24, y)], colour.stroke_width(3)));
    }
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperRight)
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .label_font(("sans-serif", 14))
        .draw()
        .map_err(e)?;

    let caption = "training (solid) and validation (dashed) loss by epoch";
    let mut chart = loss_chart(&right, caption, "epoch", 0.5f64..max_epoch as f64 + 0.5, lo..hi).map_err(e)?;
    for (r, colour) in runs.iter().zip(PALETTE.iter().cycle()) {
        chart
            .draw_series(LineSeries::new(
                r.train_epochs.iter().map(|p| (p.epoch as f64, p.loss)),
                colour.stroke_width(2),
            ))
            .map_err(e)?;
        let valid: Vec<(f64, f64)> = r.valid_epochs.iter().map(|p| (p.epoch as f64, p.loss)).collect();
        chart.draw_series(DashedLineSeries::new(valid, 8, 5, colour.stroke_width(2))).map_err(e)?;
    }
    root.present().map_err(e)?;
    Ok(())
}
