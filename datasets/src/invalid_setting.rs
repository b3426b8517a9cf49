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
}
