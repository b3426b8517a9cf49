//! The paper's experiment end to end: generate the data, take (or make) the
//! pretrained networks, fine-tune the three networks, compare their loss
//! curves, localize the sequence with each detector and write a report.

pub mod error;
pub mod experiment;
pub mod plan;
pub mod report;
pub mod stage;

pub use error::ReproduceError;
pub use experiment::Results;
pub use plan::Plan;

use std::path::Path;
use std::time::Instant;

use error::Result;

pub const REPORT_FILE: &str = "report.md";

/// Runs (or resumes) the experiment in `out` and writes `out/report.md`.
pub fn reproduce(out: &Path, plan: &Plan, show_progress: bool) -> Result<Results> {
    let started = Instant::now();
    let results = experiment::run(out, plan, show_progress)?;
    datasets::atomic::write_json(&out.join("plan.json"), plan)?;
    let text = report::markdown(plan, &results, &report::Machine::here(), started.elapsed().as_secs_f64());
    datasets::atomic::write_bytes(&out.join(REPORT_FILE), text.as_bytes())?;
    Ok(results)
}
