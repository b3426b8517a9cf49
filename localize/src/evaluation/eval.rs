//! Trajectory error as `evo_ape` computes it: poses associated by timestamp,
//! an optional Umeyama alignment (SE(3) or Sim(3)) of the estimate onto the
//! reference, then the translation error of every matched pose, summarised as
//! per-axis RMSE (the paper's Table 2) and the absolute trajectory error.

use datasets::io::formats::Trajectory;
use datasets::math::Vec3;
use serde::Serialize;

use crate::evaluation::similarity::{Similarity, umeyama};

/// How the estimate is aligned to the reference before errors are taken.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Alignment {
    /// Compare in the frames as given (both trajectories share a world frame).
    #[default]
    None,
    /// Best rotation and translation (evo `-a`).
    Se3,
    /// Best rotation, translation and scale (evo `-as`), for monocular estimates.
    Sim3,
}

/// The poses of two trajectories that were matched in time: `pairs[k]` =
/// (index in the reference, index in the estimate).
#[derive(Debug, Clone, PartialEq)]
pub struct Association {
    pub pairs: Vec<(usize, usize)>,
}

/// Associates as `evo.core.sync.associate_trajectories` does: every pose of
/// the shorter trajectory takes the nearest stamp of the longer one (first on
/// ties) and is kept when they differ by at most `max_diff` seconds.
pub fn associate(reference: &Trajectory, estimate: &Trajectory, max_diff: f64) -> Association {
    let estimate_longer = estimate.len() > reference.len();
    let (short, long) =
        if estimate_longer { (&reference.stamps, &estimate.stamps) } else { (&estimate.stamps, &reference.stamps) };
    let mut pairs = Vec::new();
    for (i_short, &t) in short.iter().enumerate() {
        let Some(i_long) = nearest_stamp(long, t) else { continue };
        if (long[i_long] - t).abs() <= max_diff {
            pairs.push(if estimate_longer { (i_short, i_long) } else { (i_long, i_short) });
        }
    }
    Association { pairs }
}

/// Index of the stamp nearest to `t` in an increasing list (the first of two
/// equally near, as `numpy.argmin`).
fn nearest_stamp(stamps: &[f64], t: f64) -> Option<usize> {
    if stamps.is_empty() {
        return None;
    }
    let above = stamps.partition_point(|&s| s < t);
    let candidates = [above.checked_sub(1), (above < stamps.len()).then_some(above)];
    candidates.into_iter().flatten().min_by(|&a, &b| {
        let (da, db) = ((stamps[a] - t).abs(), (stamps[b] - t).abs());
        da.total_cmp(&db).then(a.cmp(&b))
    })
}

/// Summary statistics of a set of translation errors.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, serde::Deserialize)]
pub struct ErrorSummary {
    pub matched: usize,
    pub rmse_x: f64,
    pub rmse_y: f64,
    pub rmse_z: f64,
    /// Absolute trajectory error: RMSE of the 3D translation error.
    pub ate_rmse: f64,
    pub ate_mean: f64,
    pub ate_median: f64,
    pub ate_max: f64,
}

impl ErrorSummary {
    /// Statistics of error vectors (estimate minus reference); `None` for none.
    pub fn of(errors: &[Vec3]) -> Option<Self> {
        let n = errors.len();
        if n == 0 {
            return None;
        }
        let rms = |f: &dyn Fn(&Vec3) -> f64| (errors.iter().map(|e| f(e).powi(2)).sum::<f64>() / n as f64).sqrt();
        let mut norms: Vec<f64> = errors.iter().map(|e| e.norm()).collect();
        norms.sort_by(f64::total_cmp);
        // numpy's median: the mean of the two middle values for an even count.
        let median = if n % 2 == 1 { norms[n / 2] } else { 0.5 * (norms[n / 2 - 1] + norms[n / 2]) };
        Some(Self {
            matched: n,
            rmse_x: rms(&|e| e.x),
            rmse_y: rms(&|e| e.y),
            rmse_z: rms(&|e| e.z),
            ate_rmse: rms(&|e| e.norm()),
            ate_mean: norms.iter().sum::<f64>() / n as f64,
            ate_median: median,
            ate_max: norms[n - 1],
        })
    }
}

/// The outcome of comparing an estimate with a reference.
#[derive(Debug, Clone)]
pub struct Comparison {
    pub association: Association,
    pub alignment: Similarity,
    /// Aligned estimate minus reference, one per matched pose.
    pub errors: Vec<Vec3>,
    pub summary: ErrorSummary,
}

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum EvalError {
    #[error("no poses matched within {max_diff} s (reference {reference} poses, estimate {estimate} poses)")]
    NothingMatched { max_diff: f64, reference: usize, estimate: usize },
    #[error("{0} matched poses cannot be aligned (need at least 3 that do not all coincide)")]
    Degenerate(usize),
}

pub fn compare(
    reference: &Trajectory,
    estimate: &Trajectory,
    alignment: Alignment,
    max_diff: f64,
) -> Result<Comparison, EvalError> {
    let association = associate(reference, estimate, max_diff);
    if association.pairs.is_empty() {
        return Err(EvalError::NothingMatched { max_diff, reference: reference.len(), estimate: estimate.len() });
    }
    let reference_positions: Vec<Vec3> =
        association.pairs.iter().map(|&(r, _)| reference.poses[r].translation.vector).collect();
    let estimate_positions: Vec<Vec3> =
        association.pairs.iter().map(|&(_, e)| estimate.poses[e].translation.vector).collect();
    let similarity = match alignment {
        Alignment::None => Similarity::identity(),
        Alignment::Se3 | Alignment::Sim3 => {
            umeyama(&estimate_positions, &reference_positions, alignment == Alignment::Sim3)
                .ok_or(EvalError::Degenerate(association.pairs.len()))?
        }
    };
    let errors: Vec<Vec3> =
        estimate_positions.iter().zip(&reference_positions).map(|(e, r)| similarity.apply(e) - r).collect();
    let summary = ErrorSummary::of(&errors).expect("at least one pair");
    Ok(Comparison { association, alignment: similarity, errors, summary })
}
