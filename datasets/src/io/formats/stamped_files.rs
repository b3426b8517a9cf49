//! The files of a sequence folder named by their time (`cloud/<t>.pcd`,
//! `rgb/<t>.png`), listed in time order: what localization and the MCAP
//! export both read.

use std::path::{Path, PathBuf};

use crate::error::{DataError, Result};

/// The file stem of a frame: its timestamp in seconds with six decimals,
/// zero-padded to ten integer digits so that names sort in time order
/// (tools that take files in name order, KISS-ICP among them, need that).
pub fn stamp_name(stamp: f64) -> String {
    format!("{stamp:017.6}")
}

/// The time a file stem gives: seconds (`10.5`, `0000000010.500000`), or
/// nanoseconds when it has 16 digits or more and no point.
pub fn parse_stamp_name(stem: &str) -> Option<f64> {
    if stem.len() >= 16 && stem.bytes().all(|b| b.is_ascii_digit()) {
        let ns: i64 = stem.parse().ok()?;
        return Some(crate::io::recording::wire::ns_to_s(ns));
    }
    stem.parse::<f64>().ok().filter(|t| t.is_finite())
}

pub const CLOUD_EXTENSIONS: [&str; 3] = ["pcd", "ply", "bin"];
pub const IMAGE_EXTENSIONS: [&str; 3] = ["png", "jpg", "jpeg"];

/// The files of `dir` with one of `extensions` (`what` they hold, for the
/// message), by time, with their times in seconds; a name that is not a
/// time, or a time two files share, is an error naming the file.
pub fn stamped_files(dir: &Path, extensions: &[&str], what: &str) -> Result<Vec<(f64, PathBuf)>> {
    let entries = std::fs::read_dir(dir).map_err(|e| DataError::io(dir, e))?;
    let mut files = Vec::new();
    for entry in entries {
        let path = entry.map_err(|e| DataError::io(dir, e))?.path();
        let Some(ext) = path.extension().and_then(|e| e.to_str()) else { continue };
        if !extensions.contains(&ext.to_ascii_lowercase().as_str()) {
            continue;
        }
        let stem = path.file_stem().and_then(|s| s.to_str()).unwrap_or_default();
        let stamp = parse_stamp_name(stem).ok_or_else(|| {
            DataError::invalid(
                &path,
                format!("{what} file name is not a timestamp (seconds, or nanoseconds with 16+ digits)"),
            )
        })?;
        files.push((stamp, path));
    }
    files.sort_by(|a, b| a.0.total_cmp(&b.0));
    for w in files.windows(2) {
        if w[1].0 == w[0].0 {
            return Err(DataError::invalid(
                &w[1].1,
                format!("duplicate timestamp {} (also {})", w[1].0, w[0].1.display()),
            ));
        }
    }
    Ok(files)
}
