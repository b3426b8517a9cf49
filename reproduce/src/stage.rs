//! Skipping finished stages. Each stage records, in `stage.json` inside its
//! folder, the inputs it ran with and what it produced; it is written last
//! (atomically), so a record exists only for a finished stage. A stage whose
//! record holds the same inputs is skipped and its outputs are read back.

use std::path::Path;

use crate::error::{ReproduceError, Result};
use serde::Serialize;
use serde::de::DeserializeOwned;

pub const RECORD_FILE: &str = "stage.json";

/// The recorded outputs of the stage in `dir` if it finished with `inputs`.
pub fn finished<O: DeserializeOwned>(dir: &Path, inputs: &serde_json::Value) -> Option<O> {
    let text = std::fs::read_to_string(dir.join(RECORD_FILE)).ok()?;
    let record: serde_json::Value = serde_json::from_str(&text).ok()?;
    if record.get("inputs")? != inputs {
        return None;
    }
    serde_json::from_value(record.get("outputs")?.clone()).ok()
}

/// Runs the stage in `dir` unless it already finished with the same inputs.
/// Returns the outputs and whether they were reused.
pub fn run_stage<I: Serialize, O: Serialize + DeserializeOwned>(
    dir: &Path,
    inputs: &I,
    run: impl FnOnce() -> Result<O>,
) -> Result<(O, bool)> {
    let inputs = serde_json::to_value(inputs)?;
    if let Some(outputs) = finished(dir, &inputs) {
        return Ok((outputs, true));
    }
    // A record of other inputs no longer describes the folder once the stage
    // starts rewriting it (and a stage may refuse files it did not write).
    let record = dir.join(RECORD_FILE);
    if record.exists() {
        std::fs::remove_file(&record).map_err(|source| ReproduceError::Io {
            path: record.clone(),
            what: "remove",
            source,
        })?;
    }
    let outputs = run()?;
    std::fs::create_dir_all(dir).map_err(|source| ReproduceError::Io {
        path: dir.to_path_buf(),
        what: "create the folder",
        source,
    })?;
    let record = serde_json::json!({ "inputs": inputs, "outputs": serde_json::to_value(&outputs)? });
    datasets::atomic::write_json(&dir.join(RECORD_FILE), &record)?;
    Ok((outputs, false))
}

/// A stable fingerprint of a file's bytes, so that a stage that reads a
/// file reruns when the file changes.
pub fn file_fingerprint(path: &Path) -> Result<String> {
    let bytes =
        std::fs::read(path).map_err(|source| ReproduceError::Io { path: path.to_path_buf(), what: "read", source })?;
    Ok(datasets::fingerprint::of_bytes(&bytes))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_stage_runs_once_per_inputs() {
        let dir = tempfile::tempdir().unwrap();
        let mut calls = 0;
        let mut step = |input: u32| {
            run_stage(dir.path(), &input, || {
                calls += 1;
                Ok(input * 2)
            })
            .unwrap()
        };
        assert_eq!(step(3), (6, false));
        assert_eq!(step(3), (6, true));
        assert_eq!(step(4), (8, false));
        assert_eq!(calls, 2);
    }

    #[test]
    fn a_failed_stage_leaves_no_record() {
        let dir = tempfile::tempdir().unwrap();
        let failed: Result<(u32, bool)> = run_stage(dir.path(), &1, || {
            Err(ReproduceError::Missing { path: dir.path().to_path_buf(), what: "interrupted".into() })
        });
        assert!(failed.is_err());
        assert!(!dir.path().join(RECORD_FILE).exists());
    }

    #[test]
    fn fingerprints_follow_the_bytes() {
        let dir = tempfile::tempdir().unwrap();
        let (a, b) = (dir.path().join("a"), dir.path().join("b"));
        std::fs::write(&a, b"corner").unwrap();
        std::fs::write(&b, b"corner").unwrap();
        assert_eq!(file_fingerprint(&a).unwrap(), file_fingerprint(&b).unwrap());
        std::fs::write(&b, b"corners").unwrap();
        assert_ne!(file_fingerprint(&a).unwrap(), file_fingerprint(&b).unwrap());
        // FNV-1a of the empty input is its offset basis.
        std::fs::write(&a, b"").unwrap();
        assert_eq!(file_fingerprint(&a).unwrap(), "cbf29ce484222325");
    }
}
