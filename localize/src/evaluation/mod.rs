//! Against the ground truth: trajectory metrics as evo computes them, levels and ramps, alignment, plots, and the benchmark.

pub mod benchmark;
pub mod eval;
pub mod levels;
pub mod normal_paths;
pub mod plot;
pub mod similarity;
pub mod stage_bench;
