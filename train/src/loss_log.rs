//! The loss log of a training run, `losses.csv`:
//! `kind,epoch,iteration,loss,<4 parts>,lr,elapsed_s`, where `kind` is
//! `train` (one row per iteration), `train_epoch` or `valid_epoch` (means
//! over an epoch). Rows keep their values at full precision until written,
//! so a run's summary does not depend on the text's six decimals.

use std::fmt::Write as _;

use infer::config::Backbone;

use crate::losses::{FASTER_RCNN_PARTS, GRID_PARTS};

/// Losses per row: the total and its four parts.
pub const LOSS_VALUES: usize = 5;

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RowKind {
    /// One training iteration.
    Train,
    /// The mean over an epoch's training iterations.
    TrainEpoch,
    /// The validation loss after an epoch.
    ValidEpoch,
}

impl RowKind {
    pub fn as_str(self) -> &'static str {
        match self {
            RowKind::Train => "train",
            RowKind::TrainEpoch => "train_epoch",
            RowKind::ValidEpoch => "valid_epoch",
        }
    }

    fn parse(text: &str) -> Option<Self> {
        [RowKind::Train, RowKind::TrainEpoch, RowKind::ValidEpoch].into_iter().find(|k| k.as_str() == text)
    }
}

#[derive(Debug, Clone, PartialEq)]
pub struct LossRow {
    pub kind: RowKind,
    /// 1-based.
    pub epoch: usize,
    /// 0-based over the whole run; an epoch row carries its last iteration.
    pub iteration: usize,
    /// The total loss, then its parts: up to [`LOSS_VALUES`]; the text pads
    /// a network's missing parts with a bare `0`.
    pub values: Vec<f64>,
    pub lr: f64,
    pub elapsed_s: f64,
}

impl LossRow {
    pub fn loss(&self) -> f64 {
        self.values[0]
    }
}

/// One point of a loss curve.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LossPoint {
    pub epoch: usize,
    pub iteration: usize,
    pub loss: f64,
    pub elapsed_s: f64,
}

#[derive(Debug, Clone, PartialEq)]
pub struct LossLog {
    /// Names of the four loss parts, as the header writes them.
    parts: Vec<String>,
    rows: Vec<LossRow>,
}

impl LossLog {
    /// An empty log with the parts of `backbone`'s loss.
    pub fn new(backbone: Backbone) -> Self {
        let parts = if backbone == Backbone::FasterRcnn { FASTER_RCNN_PARTS } else { GRID_PARTS };
        Self { parts: parts.iter().map(|p| p.to_string()).collect(), rows: Vec::new() }
    }

    /// Appends a row; `values` is the total and up to four parts.
    pub fn push(&mut self, kind: RowKind, epoch: usize, iteration: usize, values: &[f64], lr: f64, elapsed_s: f64) {
        let values = values[..values.len().min(LOSS_VALUES)].to_vec();
        self.rows.push(LossRow { kind, epoch, iteration, values, lr, elapsed_s });
    }

    pub fn rows(&self) -> &[LossRow] {
        &self.rows
    }

    /// The rows of one kind as curve points.
    pub fn points(&self, kind: RowKind) -> Vec<LossPoint> {
        self.rows
            .iter()
            .filter(|r| r.kind == kind)
            .map(|r| LossPoint { epoch: r.epoch, iteration: r.iteration, loss: r.loss(), elapsed_s: r.elapsed_s })
            .collect()
    }

    /// The loss of the last row of `kind`.
    pub fn last(&self, kind: RowKind) -> Option<f64> {
        self.rows.iter().rfind(|r| r.kind == kind).map(LossRow::loss)
    }

    /// The log as `losses.csv` text.
    pub fn to_csv(&self) -> String {
        let mut csv = format!("kind,epoch,iteration,loss,{},lr,elapsed_s\n", self.parts.join(","));
        for r in &self.rows {
            let mut values: Vec<String> = r.values.iter().map(|v| format!("{v:.6}")).collect();
            values.resize(LOSS_VALUES, "0".into());
            let _ = writeln!(
                csv,
                "{},{},{},{},{:.6e},{:.2}",
                r.kind.as_str(),
                r.epoch,
                r.iteration,
                values.join(","),
                r.lr,
                r.elapsed_s
            );
        }
        csv
    }

    /// Reads `losses.csv` text by its header's column names; the error
    /// says which line is wrong.
    pub fn parse(text: &str) -> Result<Self, String> {
        let mut lines = text.lines();
        let header: Vec<&str> = lines.next().ok_or("empty loss log")?.split(',').collect();
        let col = |name: &str| header.iter().position(|h| *h == name).ok_or_else(|| format!("no column {name}"));
        let (kind, epoch, iteration, loss, lr, elapsed) =
            (col("kind")?, col("epoch")?, col("iteration")?, col("loss")?, col("lr")?, col("elapsed_s")?);
        // The parts sit between the loss and the learning rate.
        if lr < loss {
            return Err("column lr before column loss".into());
        }
        let parts: Vec<String> = header[loss + 1..lr].iter().map(|p| p.to_string()).collect();
        if parts.len() + 1 > LOSS_VALUES {
            return Err(format!("{} loss parts, at most {}", parts.len(), LOSS_VALUES - 1));
        }
        let mut log = Self { parts, rows: Vec::new() };
        for (n, line) in lines.enumerate() {
            let f: Vec<&str> = line.split(',').collect();
            let bad = || format!("line {}: cannot read {line:?}", n + 2);
            if f.len() != header.len() {
                return Err(bad());
            }
            let kind =
                RowKind::parse(f[kind]).ok_or_else(|| format!("line {}: unknown row kind {:?}", n + 2, f[kind]))?;
            let number = |i: usize| f[i].parse::<f64>().map_err(|_| bad());
            // Padding (a bare `0`) is not a value.
            let given = (loss..lr).rev().skip_while(|&i| f[i] == "0").count();
            let values: Vec<f64> = (loss..loss + given).map(number).collect::<Result<_, _>>()?;
            let (epoch, iteration) = (f[epoch].parse().map_err(|_| bad())?, f[iteration].parse().map_err(|_| bad())?);
            log.push(kind, epoch, iteration, &values, number(lr)?, number(elapsed)?);
        }
        Ok(log)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn written_text_reads_back_to_the_same_text() {
        let mut log = LossLog::new(Backbone::FasterRcnn);
        log.push(RowKind::Train, 1, 0, &[1.25, 0.5, 0.25, 0.375, 0.125], 1e-3, 0.5);
        log.push(RowKind::Train, 1, 1, &[0.987654321, 0.1, 0.2, 0.3, 0.387654321], 2.5e-4, 1.234);
        log.push(RowKind::TrainEpoch, 1, 1, &[1.1, 0.3, 0.225, 0.3375, 0.2375], 2.5e-4, 1.5);
        log.push(RowKind::ValidEpoch, 1, 1, &[0.9, 0.2, 0.2, 0.3, 0.2], 2.5e-4, 1.5);
        let text = log.to_csv();
        assert_eq!(
            text.lines().next().unwrap(),
            "kind,epoch,iteration,loss,rpn_objectness,rpn_box,classifier,box,lr,elapsed_s"
        );
        assert_eq!(
            text.lines().nth(2).unwrap(),
            "train,1,1,0.987654,0.100000,0.200000,0.300000,0.387654,2.500000e-4,1.23"
        );
        let back = LossLog::parse(&text).unwrap();
        assert_eq!(back.to_csv(), text);
        assert_eq!(back.points(RowKind::Train).len(), 2);
        assert_eq!(back.last(RowKind::TrainEpoch), Some(1.1));
        assert_eq!(back.last(RowKind::ValidEpoch), Some(0.9));
        // In memory the values keep full precision; read back, six decimals.
        assert_eq!(log.points(RowKind::Train)[1].loss, 0.987654321);
        assert_eq!(back.points(RowKind::Train)[1].loss, 0.987654);
    }

    #[test]
    fn missing_parts_are_written_as_a_bare_zero_and_read_back_as_absent() {
        let mut log = LossLog::new(Backbone::Alexnet);
        log.push(RowKind::Train, 1, 0, &[2.5, 0.5, 0.25, 1.75], 2e-3, 0.19);
        log.push(RowKind::TrainEpoch, 1, 0, &[2.5, 0.5, 0.25, 1.75, 0.0], 2e-3, 0.19);
        let text = log.to_csv();
        assert_eq!(text.lines().nth(1).unwrap(), "train,1,0,2.500000,0.500000,0.250000,1.750000,0,2.000000e-3,0.19");
        assert_eq!(
            text.lines().nth(2).unwrap(),
            "train_epoch,1,0,2.500000,0.500000,0.250000,1.750000,0.000000,2.000000e-3,0.19"
        );
        let back = LossLog::parse(&text).unwrap();
        assert_eq!(back.rows()[0].values.len(), 4);
        assert_eq!(back.rows()[1].values.len(), 5);
        assert_eq!(back.to_csv(), text);
    }

    #[test]
    fn malformed_logs_name_the_line() {
        let header = "kind,epoch,iteration,loss,a,b,c,d,lr,elapsed_s\n";
        let err = LossLog::parse(&format!("{header}train,1,0,abc,0,0,0,0,1e-3,0\n")).unwrap_err();
        assert!(err.contains("line 2"), "{err}");
        let err = LossLog::parse(&format!("{header}test,1,0,1,0,0,0,0,1e-3,0\n")).unwrap_err();
        assert!(err.contains("unknown row kind"), "{err}");
        let err = LossLog::parse(&format!("{header}train,1,0,1,0,0\n")).unwrap_err();
        assert!(err.contains("line 2"), "{err}");
        assert!(LossLog::parse("kind,epoch,loss,lr,elapsed_s\n").unwrap_err().contains("no column iteration"));
        assert!(LossLog::parse("").is_err());
    }
}
