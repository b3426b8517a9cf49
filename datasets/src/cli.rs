//! What every binary of the project shares at its edges: how an error is
//! reported at exit, and parsers for numeric flags whose clap defaults read
//! badly.

use std::error::Error;
use std::process::ExitCode;

use indicatif::{ProgressBar, ProgressStyle};

/// An error and its causes on one line each, without a backtrace (a
/// backtrace is for bugs; these are a user's input problems). A cause whose
/// text the line above already ends with is skipped: error types that print
/// their source and also return it would otherwise say it twice.
pub fn error_report(error: &(dyn Error + 'static)) -> String {
    let mut out = format!("error: {error}");
    let mut above = error.to_string();
    let mut cause = error.source();
    while let Some(e) = cause {
        let text = e.to_string();
        if !text.is_empty() && !above.ends_with(&text) {
            out.push_str("\n  caused by: ");
            out.push_str(&text);
        }
        above = text;
        cause = e.source();
    }
    out
}

/// The exit of a binary's `main`: 0, or the error report on stderr and 1.
pub fn exit_code(outcome: anyhow::Result<()>) -> ExitCode {
    match outcome {
        Ok(()) => ExitCode::SUCCESS,
        Err(error) => {
            let root: &(dyn Error + 'static) = error.as_ref();
            eprintln!("{}", error_report(root));
            ExitCode::FAILURE
        }
    }
}

/// A count flag that must be at least 1 (`--epochs`, `--frames`, ...).
pub fn positive_count(text: &str) -> Result<usize, String> {
    whole_number(text, 1)
}

/// A count flag that may be 0.
pub fn count(text: &str) -> Result<usize, String> {
    whole_number(text, 0)
}

fn whole_number(text: &str, least: i128) -> Result<usize, String> {
    match text.trim().parse::<i128>() {
        Ok(n) if n >= least && n <= usize::MAX as i128 => Ok(n as usize),
        Ok(n) => Err(format!("must be a whole number of at least {least}, got {n}")),
        Err(_) => Err(format!("must be a whole number of at least {least}, got `{text}`")),
    }
}

/// A finite non-negative quantity (`--label-noise-px`, `--lr`, ...).
pub fn non_negative(text: &str) -> Result<f64, String> {
    match text.trim().parse::<f64>() {
        Ok(v) if v.is_finite() && v >= 0.0 => Ok(v),
        Ok(v) => Err(format!("must be a finite number of at least 0, got {v}")),
        Err(_) => Err(format!("must be a number, got `{text}`")),
    }
}

/// A finite quantity above 0 (`--lr`, `--speed`, ...).
pub fn positive(text: &str) -> Result<f64, String> {
    match text.trim().parse::<f64>() {
        Ok(v) if v.is_finite() && v > 0.0 => Ok(v),
        Ok(v) => Err(format!("must be a finite number above 0, got {v}")),
        Err(_) => Err(format!("must be a number, got `{text}`")),
    }
}

/// A bar for `len` items of the data writers, labelled `what`.
pub fn progress(len: usize, what: &str) -> ProgressBar {
    let bar = ProgressBar::new(len as u64);
    bar.set_style(
        ProgressStyle::with_template("{msg:>12} [{bar:40}] {pos}/{len} ({eta})")
            .expect("valid template")
            .progress_chars("=> "),
    );
    bar.set_message(what.to_string());
    bar
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Debug, thiserror::Error)]
    #[error("{path}: {source}")]
    struct Repeats {
        path: &'static str,
        source: std::io::Error,
    }

    #[test]
    fn a_cause_the_message_already_prints_is_not_repeated() {
        let io = std::io::Error::new(std::io::ErrorKind::AlreadyExists, "File exists");
        let error = anyhow::Error::new(Repeats { path: "/tmp/out", source: io }).context("writing the run");
        let report = error_report(error.as_ref());
        assert_eq!(report, "error: writing the run\n  caused by: /tmp/out: File exists");
    }

    #[test]
    fn a_cause_the_message_does_not_print_is_kept() {
        let error = anyhow::anyhow!("inner problem").context("outer step");
        assert_eq!(error_report(error.as_ref()), "error: outer step\n  caused by: inner problem");
    }

    #[test]
    fn counts_refuse_negative_and_fractional_values_by_name() {
        assert_eq!(positive_count("3"), Ok(3));
        assert!(positive_count("-1").unwrap_err().contains("at least 1, got -1"));
        assert!(positive_count("0").unwrap_err().contains("got 0"));
        assert!(positive_count("1.5").unwrap_err().contains("`1.5`"));
        assert_eq!(count("0"), Ok(0));
        assert!(non_negative("NaN").unwrap_err().contains("finite"));
        assert!(non_negative("-0.5").unwrap_err().contains("-0.5"));
        assert!(positive("0").unwrap_err().contains("above 0"));
        assert_eq!(positive("2e-3"), Ok(2e-3));
    }
}
