//! The stages of the experiment, in order: data, trunks, fine-tuning,
//! comparison, localization. Each stage is skipped when it already finished
//! with the same inputs (see `stage`); the training runs also resume from
//! their last epoch when interrupted.

use std::path::{Path, PathBuf};
use std::time::Instant;

use infer::config::Backbone;
use infer::metrics::EvalMetrics;
use localize::input::corner_source::CornerSource;
use localize::input::sequence::RecordedSequence;
use localize::run::{RunMetrics, TrajectoryMetrics, metrics_against, run_sequence, truth_in_run_frame, write_outputs};
use serde::{Deserialize, Serialize};
use train::compare::{RunRecord, csv_table, markdown_table, read_run, write_loss_plots};
use train::{Start, TrainConfig};

use crate::error::{ReproduceError, Result};
use crate::plan::{FineTune, Plan, TrunkSource, pretrained_families, starts_from_whole_network};
use crate::stage::{file_fingerprint, run_stage};

#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct DataOutputs {
    pub detection_images: usize,
    pub detection_labels: usize,
    pub frames: usize,
    pub route_length_m: f64,
    pub seconds: f64,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct TrunkOutputs {
    pub family: Backbone,
    /// Where the fine-tuning starts: the trunk file, or the checkpoint when
    /// the whole network is the start.
    pub start: Start,
    pub fingerprint: String,
    /// `shipped` or `pretrained here`.
    pub origin: String,
    /// AP@0.5 of the pretraining network on its corpus's test split.
    pub corpus_ap50: Option<f64>,
    pub seconds: f64,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct TrainOutputs {
    pub backbone: Backbone,
    pub run: PathBuf,
    pub metrics: EvalMetrics,
    pub final_train_loss: f64,
    pub final_valid_loss: Option<f64>,
    pub seconds: f64,
}

/// One row of Table 2.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct ErrorRow {
    pub level: String,
    pub matched: usize,
    pub rmse_x: f64,
    pub rmse_y: f64,
    pub rmse_z: f64,
    pub ate_rmse: f64,
}

fn error_rows(t: &TrajectoryMetrics) -> Vec<ErrorRow> {
    let row = |level: &str, e: &localize::evaluation::eval::ErrorSummary| ErrorRow {
        level: level.to_string(),
        matched: e.matched,
        rmse_x: e.rmse_x,
        rmse_y: e.rmse_y,
        rmse_z: e.rmse_z,
        ate_rmse: e.ate_rmse,
    };
    t.levels.iter().map(|l| row(&l.name, &l.errors)).chain([row("all", &t.overall)]).collect()
}

#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct LocalizeOutputs {
    pub backbone: Backbone,
    pub dir: PathBuf,
    pub fused: Vec<ErrorRow>,
    pub odometry_imu: Vec<ErrorRow>,
    pub frames: usize,
    pub fused_frames: usize,
    pub mean_total_ms: f64,
    pub seconds: f64,
}

/// Everything the report needs.
#[derive(Debug, Clone)]
pub struct Results {
    pub data: DataOutputs,
    pub trunks: Vec<TrunkOutputs>,
    pub runs: Vec<TrainOutputs>,
    pub records: Vec<RunRecord>,
    pub localization: Vec<LocalizeOutputs>,
    /// Stages skipped because they had finished before.
    pub reused: Vec<String>,
}

/// Announces a stage on the terminal.
fn announce(step: usize, total: usize, what: &str) {
    eprintln!("[{step}/{total}] {what}");
}

pub fn run(out: &Path, plan: &Plan, show_progress: bool) -> Result<Results> {
    if out.exists() && !out.is_dir() {
        return Err(ReproduceError::Missing { path: out.to_path_buf(), what: "exists and is not a folder".into() });
    }
    std::fs::create_dir_all(out).map_err(|source| ReproduceError::Io {
        path: out.to_path_buf(),
        what: "create the folder",
        source,
    })?;
    let families = pretrained_families(&plan.runs);
    let total = 1 + families.len() + plan.runs.len() * 2 + 1;
    let mut step = 0;
    let mut reused = Vec::new();
    let mut note = |reused_now: bool, what: String| {
        if reused_now {
            eprintln!("    done before, skipped");
            reused.push(what);
        }
    };

    step += 1;
    announce(step, total, "data: the labeled images and the sequence");
    let (data_dir, data_key, data, was) = data_stage(out, plan)?;
    note(was, "data".into());

    let mut trunks = Vec::new();
    for &family in &families {
        step += 1;
        announce(step, total, &format!("pretrained {family}"));
        let (trunk, was) = trunk_stage(out, plan, family, &trunks, show_progress)?;
        note(was && trunk.origin != "shipped", format!("trunk {family}"));
        trunks.push(trunk);
    }

    let mut runs = Vec::new();
    for ft in &plan.runs {
        step += 1;
        announce(step, total, &format!("fine-tune {} for {} epochs", ft.backbone, ft.epochs));
        let trunk = trunks.iter().find(|t| t.family == ft.backbone).expect("every backbone has a pretrained start");
        let (outputs, was) = fine_tune(out, plan, ft, (&data_dir, &data_key), trunk, show_progress)?;
        note(was, format!("training {}", ft.backbone));
        runs.push(outputs);
    }
    let records = runs.iter().map(|r| read_run(&r.run)).collect::<Result<Vec<_>, _>>()?;
    let compare_dir = out.join("compare");
    std::fs::create_dir_all(&compare_dir).map_err(|e| datasets::DataError::io(&compare_dir, e))?;
    write_loss_plots(&records, &compare_dir.join("losses"))?;
    datasets::atomic::write_bytes(&compare_dir.join("table.md"), markdown_table(&records).as_bytes())?;
    datasets::atomic::write_bytes(&compare_dir.join("table.csv"), csv_table(&records).as_bytes())?;

    let mut localization = Vec::new();
    for r in &runs {
        step += 1;
        announce(step, total, &format!("localize the sequence with {}", r.backbone));
        let (outputs, was) = localize_stage(out, plan, r, (&data_dir, &data_key), show_progress)?;
        note(was, format!("localization {}", r.backbone));
        localization.push(outputs);
    }
    step += 1;
    announce(step, total, "report");
    Ok(Results { data, trunks, runs, records, localization, reused })
}

/// The data folder, what identifies its content for the later stages, and
/// its figures. Generated data is made here; recorded data is only read.
fn data_stage(out: &Path, plan: &Plan) -> Result<(PathBuf, serde_json::Value, DataOutputs, bool)> {
    if let Some(dir) = &plan.recorded {
        let train_json = dir.join("detection/train.json");
        let test_json = dir.join("detection/test.json");
        let train = datasets::io::formats::read_coco(&train_json)?;
        let test = datasets::io::formats::read_coco(&test_json)?;
        let sequence = RecordedSequence::open(&dir.join("sequence"))?;
        let route_length_m = sequence
            .ground_truth
            .as_ref()
            .map(|t| {
                let p: Vec<_> = t.positions().collect();
                p.windows(2).map(|w| (w[1] - w[0]).norm()).sum()
            })
            .unwrap_or(f64::NAN);
        let data = DataOutputs {
            detection_images: train.images.len() + test.images.len(),
            detection_labels: train.annotations.len() + test.annotations.len(),
            frames: sequence.frames.len(),
            route_length_m,
            seconds: 0.0,
        };
        let key = serde_json::json!({
            "recorded": dir,
            "train": file_fingerprint(&train_json)?,
            "test": file_fingerprint(&test_json)?,
            "frames": data.frames,
        });
        return Ok((dir.clone(), key, data, true));
    }
    let dir = out.join("data");
    let (data, was) = run_stage(&dir, &plan.datagen, || {
        let started = Instant::now();
        let s = datasets::simulator::generate::generate(&dir, &plan.datagen)?;
        Ok(DataOutputs {
            detection_images: s.detection_images,
            detection_labels: s.detection_labels,
            frames: s.frames,
            route_length_m: s.route_length_m,
            seconds: started.elapsed().as_secs_f64(),
        })
    })?;
    Ok((dir, serde_json::to_value(&plan.datagen)?, data, was))
}

/// Where `family`'s fine-tuning starts, in a pretraining folder (or the
/// shipped `pretrained/<family>/`): the whole network's checkpoint for
/// faster-rcnn, the trunk otherwise.
fn pretrained_start(dir: &Path, family: Backbone) -> Start {
    if starts_from_whole_network(family) {
        Start::Detector(dir.join(train::pretrain::DETECTOR_DIR))
    } else {
        Start::Trunk(dir.join(train::pretrain::TRUNK_FILE))
    }
}

/// What identifies a start's content: the trunk file's, or the checkpoint
/// weights'.
fn start_fingerprint(start: &Start) -> Result<String> {
    match start {
        Start::Scratch => Ok("scratch".into()),
        Start::Trunk(path) => file_fingerprint(path),
        Start::Detector(dir) => file_fingerprint(&dir.join(infer::checkpoint::WEIGHTS_FILE)),
    }
}

/// The pretrained start of `family`: shipped, or pretrained here on a
/// corpus (faster-rcnn's pretraining itself starting from the vgg16 trunk
/// in `before`).
fn trunk_stage(
    out: &Path,
    plan: &Plan,
    family: Backbone,
    before: &[TrunkOutputs],
    show_progress: bool,
) -> Result<(TrunkOutputs, bool)> {
    match &plan.trunks {
        TrunkSource::Shipped(checkpoints) => {
            let dir = checkpoints.join("pretrained").join(family.name());
            let start = pretrained_start(&dir, family);
            let path = start.path().expect("a pretrained start has a path");
            if !path.exists() {
                return Err(ReproduceError::Missing {
                    path: path.to_path_buf(),
                    what: format!(
                        "the shipped pretrained {family} is missing; run from the repository's root, or pass \
                         --pretrain to pretrain it on a generated corpus"
                    ),
                });
            }
            let corpus_ap50 = datasets::atomic::read_text(&dir.join(train::pretrain::META_FILE))
                .ok()
                .and_then(|t| serde_json::from_str::<train::pretrain::TrunkMeta>(&t).ok())
                .map(|m| m.corpus_test.ap50);
            let trunk = TrunkOutputs {
                family,
                fingerprint: start_fingerprint(&start)?,
                start,
                origin: "shipped".into(),
                corpus_ap50,
                seconds: 0.0,
            };
            Ok((trunk, true))
        }
        TrunkSource::Pretrain { .. } => {
            let mut config = plan.pretrain_config(family).expect("pretraining planned");
            let mut from = None;
            if family == Backbone::FasterRcnn {
                let vgg16 =
                    before.iter().find(|t| t.family == Backbone::Vgg16).ok_or_else(|| ReproduceError::Missing {
                        path: out.join("pretrain").join(Backbone::Vgg16.name()),
                        what: "faster-rcnn's pretraining starts from the vgg16 trunk, which was not made".into(),
                    })?;
                config.start = vgg16.start.clone();
                from = Some(vgg16.fingerprint.clone());
            }
            let dir = out.join("pretrain").join(family.name());
            let inputs = serde_json::json!({ "pretrain": &config, "from": from });
            run_stage(&dir, &inputs, || {
                let started = Instant::now();
                let (_, meta) = train::pretrain::pretrain(&dir, &config, show_progress)?;
                let start = pretrained_start(&dir, family);
                Ok(TrunkOutputs {
                    family,
                    fingerprint: start_fingerprint(&start)?,
                    start,
                    origin: "pretrained here".into(),
                    corpus_ap50: Some(meta.corpus_test.ap50),
                    seconds: started.elapsed().as_secs_f64(),
                })
            })
        }
    }
}

fn fine_tune(
    out: &Path,
    plan: &Plan,
    ft: &FineTune,
    (data_dir, data_key): (&Path, &serde_json::Value),
    trunk: &TrunkOutputs,
    show_progress: bool,
) -> Result<(TrainOutputs, bool)> {
    let run = out.join("runs").join(ft.backbone.name());
    let mut config = TrainConfig::new(ft.backbone, plan.width, data_dir.join("detection"));
    config.epochs = ft.epochs;
    config.backend = plan.backend;
    config.start_from(trunk.start.clone());
    let inputs = serde_json::json!({ "train": &config, "trunk": &trunk.fingerprint, "data": data_key });
    run_stage(&run, &inputs, || {
        // An interrupted run with the same settings continues; any other
        // run in the folder is from other settings and starts over.
        let previous = datasets::atomic::read_text(&train::RunFolder::new(&run).config_path())
            .ok()
            .and_then(|t| serde_json::from_str::<TrainConfig>(&t).ok());
        let summary = if previous.as_ref() == Some(&config) {
            train::train(None, &run, show_progress)?
        } else {
            if run.exists() {
                eprintln!("    {} holds a run with other settings: starting it over", run.display());
                std::fs::remove_dir_all(&run).map_err(|source| ReproduceError::Io {
                    path: run.clone(),
                    what: "clear the folder",
                    source,
                })?;
            }
            train::train(Some(config.clone()), &run, show_progress)?
        };
        Ok(TrainOutputs {
            backbone: ft.backbone,
            run: run.clone(),
            metrics: summary.metrics,
            final_train_loss: summary.final_train_loss,
            final_valid_loss: summary.final_valid_loss,
            seconds: summary.seconds,
        })
    })
}

fn localize_stage(
    out: &Path,
    plan: &Plan,
    trained: &TrainOutputs,
    (data_dir, data_key): (&Path, &serde_json::Value),
    show_progress: bool,
) -> Result<(LocalizeOutputs, bool)> {
    let dir = out.join("localize").join(trained.backbone.name());
    let checkpoint = train::RunFolder::new(&trained.run).checkpoint_dir();
    let weights = file_fingerprint(&checkpoint.join(infer::checkpoint::WEIGHTS_FILE))?;
    let inputs = serde_json::json!({ "detector": weights, "data": data_key, "config": &plan.localize });
    run_stage(&dir, &inputs, || {
        let started = Instant::now();
        let sequence = RecordedSequence::open(&data_dir.join("sequence"))?;
        let mut source = CornerSource::detector(&checkpoint, plan.backend.device()?, plan.localize.fusion.min_score)?;
        let result = run_sequence(&sequence, &mut source, &plan.localize, show_progress)?;
        // Without ground truth (a recorded sequence may have none) there are
        // trajectories but no errors.
        let truth = truth_in_run_frame(&sequence, &result);
        let m: Option<RunMetrics> = metrics_against(&sequence, &result, truth.as_ref())?;
        write_outputs(&dir, &plan.localize, &result, truth.as_ref(), m.as_ref())?;
        Ok(LocalizeOutputs {
            backbone: trained.backbone,
            dir: dir.clone(),
            fused: m.as_ref().map(|m| error_rows(&m.fused)).unwrap_or_default(),
            odometry_imu: m.as_ref().map(|m| error_rows(&m.odometry_imu)).unwrap_or_default(),
            frames: result.frames.len(),
            fused_frames: result.fused_frames(),
            mean_total_ms: result.mean_total_ms(),
            seconds: started.elapsed().as_secs_f64(),
        })
    })
}
