//! Fuzzing of every parser the project reads users' files with. The targets
//! serve two drivers: the stable runner here (seeded mutations, bounded, in
//! the tests and for long runs on any toolchain) and the coverage-guided
//! libFuzzer targets of `fuzz/libfuzzer/` (nightly, `cargo fuzz`).

pub mod alloc_cap;
pub mod mutate;
pub mod runner;
pub mod seeds;
pub mod targets;

pub use targets::Target;
