//! `fuzz`: the stable fuzz runner over every parser, and the seed corpus
//! for the libFuzzer targets of `fuzz/libfuzzer/`.

use std::path::PathBuf;
use std::time::Duration;

use anyhow::{Context, Result, bail};
use clap::{Parser, Subcommand};
use fuzz::Target;
use fuzz::runner::{Budget, run};

#[global_allocator]
static ALLOCATOR: fuzz::alloc_cap::CappedAllocator = fuzz::alloc_cap::CappedAllocator;

#[derive(Parser)]
#[command(name = "fuzz", about = "Fuzz the project's parsers with seeded mutations of real and generated files")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(clap::Args)]
#[command(allow_negative_numbers = true)]
struct SeedArgs {
    /// Folders whose files seed the targets they fit (by name and extension),
    /// besides the generated seeds.
    #[arg(long = "seeds", default_values = ["datasets/tests/data", "checkpoints"])]
    seeds: Vec<PathBuf>,
}

#[derive(Subcommand)]
enum Command {
    /// Run targets until the time or the cases are spent; stop at the first bug.
    Run {
        /// A target name, or `all` (the time is shared evenly).
        #[arg(long, default_value = "all")]
        target: String,
        /// Seconds in all.
        #[arg(long, value_parser = datasets::cli::positive, conflicts_with = "cases")]
        seconds: Option<f64>,
        /// Cases per target instead of a time.
        #[arg(long, value_parser = datasets::cli::positive_count)]
        cases: Option<usize>,
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Where a crashing input is written.
        #[arg(long, default_value = "fuzz-crashes")]
        crashes: PathBuf,
        #[command(flatten)]
        seeds: SeedArgs,
    },
    /// Write every target's seeds as a libFuzzer corpus: OUT/<target>/<n>.
    Seeds {
        #[arg(long)]
        out: PathBuf,
        #[command(flatten)]
        seeds: SeedArgs,
    },
    /// Write the input of one case of a run (to replay a reported case).
    Case {
        #[arg(long)]
        target: String,
        #[arg(long)]
        case: u64,
        #[arg(long, default_value_t = 1)]
        seed: u64,
        #[arg(long)]
        out: PathBuf,
        #[command(flatten)]
        seeds: SeedArgs,
    },
    /// List the targets.
    List,
}

fn targets(name: &str) -> Result<Vec<Target>> {
    if name == "all" {
        return Ok(Target::ALL.to_vec());
    }
    match Target::from_name(name) {
        Some(t) => Ok(vec![t]),
        None => {
            let names: Vec<&str> = Target::ALL.iter().map(|t| t.name()).collect();
            bail!("--target {name}: no such target (all, {})", names.join(", "))
        }
    }
}

fn main() -> std::process::ExitCode {
    datasets::cli::exit_code(run_main())
}

fn run_main() -> Result<()> {
    match Cli::parse().command {
        Command::List => {
            Target::ALL.iter().for_each(|t| println!("{}", t.name()));
            Ok(())
        }
        Command::Seeds { out, seeds } => {
            let corpus = fuzz::seeds::collect(&seeds.seeds);
            for (name, inputs) in &corpus {
                let dir = out.join(name);
                std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
                for (k, input) in inputs.iter().enumerate() {
                    datasets::atomic::write_bytes(&dir.join(format!("seed-{k:04}")), input)?;
                }
                println!("{name}: {} seeds", inputs.len());
            }
            Ok(())
        }
        Command::Case { target, case, seed, out, seeds } => {
            let [target] = targets(&target)?[..] else { bail!("--target: give one target") };
            let corpus = fuzz::seeds::collect(&seeds.seeds);
            let inputs = corpus.get(target.name()).cloned().unwrap_or_default();
            let inputs = if inputs.is_empty() { vec![Vec::new()] } else { inputs };
            datasets::atomic::write_bytes(&out, &fuzz::mutate::case_input(&inputs, seed, case))?;
            println!("wrote {}", out.display());
            Ok(())
        }
        Command::Run { target, seconds, cases, seed, crashes, seeds } => {
            let chosen = targets(&target)?;
            let corpus = fuzz::seeds::collect(&seeds.seeds);
            let budget = match (seconds, cases) {
                (_, Some(n)) => Budget::Cases(n as u64),
                (Some(s), None) => Budget::Time(Duration::from_secs_f64(s / chosen.len() as f64)),
                (None, None) => Budget::Time(Duration::from_secs(60 / chosen.len() as u64 + 1)),
            };
            println!("{:<18} {:>6} {:>12} {:>10} {:>14}", "target", "seeds", "executions", "exec/s", "slowest case");
            let mut total = 0;
            for target in chosen {
                let inputs = corpus.get(target.name()).cloned().unwrap_or_default();
                let bar = indicatif::ProgressBar::new_spinner().with_message(target.name());
                let outcome = run(target, &inputs, seed, budget, &mut |n| bar.set_position(n));
                bar.finish_and_clear();
                match outcome {
                    Ok(stats) => {
                        total += stats.executions;
                        println!(
                            "{:<18} {:>6} {:>12} {:>10.0} {:>11.1} ms",
                            target.name(),
                            stats.seeds,
                            stats.executions,
                            stats.executions as f64 / stats.elapsed.as_secs_f64().max(1e-9),
                            stats.slowest.1.as_secs_f64() * 1e3
                        );
                    }
                    Err(crash) => {
                        let file = crashes.join(format!("{}-case-{}", target.name(), crash.case));
                        datasets::atomic::write_bytes(&file, &crash.input)?;
                        bail!("{crash}; input written to {}", file.display());
                    }
                }
            }
            println!("{total} executions, no crash");
            Ok(())
        }
    }
}
