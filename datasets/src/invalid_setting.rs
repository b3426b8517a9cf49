//! The error of a setting the code cannot run with: which field, and why.
//! Every config section's `validate` returns it; a section that holds
//! another prefixes the inner field with [`InvalidSetting::within`], so the
//! user reads the full path (`lidar.beams`) of what to change.

/// A setting outside what the code can run with.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{}{problem}", if field.is_empty() { String::new() } else { format!("{field}: ") })]
pub struct InvalidSetting {
    /// The dotted path of the field (`world.ramp_slope_deg`), or empty when
    /// the problem is between fields rather than in one.
    pub field: String,
    /// What is wrong with it, with the value.
    pub problem: String,
}

impl InvalidSetting {
    /// A field whose value is wrong.
    pub fn field(field: impl Into<String>, problem: impl Into<String>) -> Self {
        Self { field: field.into(), problem: problem.into() }
    }

    /// A problem between several fields (no one field is at fault).
    pub fn between(problem: impl Into<String>) -> Self {
        Self { field: String::new(), problem: problem.into() }
    }

    /// `Ok` when `value` is finite and in (0, hi]; a NaN fails.
    pub fn positive(field: &str, value: f64, hi: f64) -> Result<(), Self> {
        Self::range(field, value, 0.0, hi, true)
    }

    /// `Ok` when `value` is finite and in [0, hi].
    pub fn non_negative(field: &str, value: f64, hi: f64) -> Result<(), Self> {
        Self::range(field, value, 0.0, hi, false)
    }

    /// `Ok` when `value` is finite, above `lo` (or at it, unless `lo_open`)
    /// and at most `hi`; the message gives the interval.
    pub fn range(field: &str, value: f64, lo: f64, hi: f64, lo_open: bool) -> Result<(), Self> {
        let above = if lo_open { value > lo } else { value >= lo };
        if value.is_finite() && above && value <= hi {
            return Ok(());
        }
        Err(Self::field(field, format!("{value} outside {}{lo}, {hi}]", if lo_open { "(" } else { "[" })))
    }

    /// `Ok` when the count is in lo..=hi.
    pub fn count(field: &str, value: usize, lo: usize, hi: usize) -> Result<(), Self> {
        if (lo..=hi).contains(&value) {
            Ok(())
        } else {
            Err(Self::field(field, format!("{value} outside {lo}..={hi}")))
        }
    }

    /// The same problem seen from the section that holds this one.
    pub fn within(self, section: &str) -> Self {
        let field = if self.field.is_empty() { section.to_string() } else { format!("{section}.{}", self.field) };
        Self { field, ..self }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_path_grows_outwards_and_prints_before_the_problem() {
        let e = InvalidSetting::field("beams", "0 outside 1..=256").within("lidar").within("generate");
        assert_eq!(e.field, "generate.lidar.beams");
        assert_eq!(e.to_string(), "generate.lidar.beams: 0 outside 1..=256");
        let between = InvalidSetting::between("train split 5 is larger than the 3 images");
        assert_eq!(between.to_string(), "train split 5 is larger than the 3 images");
        assert_eq!(between.within("detection").to_string(), "detection: train split 5 is larger than the 3 images");
    }

    #[test]
    fn range_checks_name_the_interval_and_refuse_nan() {
        assert_eq!(InvalidSetting::positive("a", 0.5, 1.0), Ok(()));
        assert_eq!(InvalidSetting::positive("a", 0.0, 1.0).unwrap_err().to_string(), "a: 0 outside (0, 1]");
        assert_eq!(InvalidSetting::non_negative("a", 0.0, 1.0), Ok(()));
        assert!(InvalidSetting::non_negative("a", f64::NAN, 1.0).is_err());
        assert!(InvalidSetting::positive("a", f64::INFINITY, f64::INFINITY).is_err());
        assert_eq!(InvalidSetting::count("k", 0, 1, 9).unwrap_err().to_string(), "k: 0 outside 1..=9");
    }
}
