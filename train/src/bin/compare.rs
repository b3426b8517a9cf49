//! `compare RUN_DIR... --out DIR` puts training runs side by side: the loss
//! curves of all runs in `DIR/losses.png` (and `.svg`), and a table of their
//! settings, final losses, AP@0.5 and training time in `DIR/table.md` and
//! `DIR/table.csv`. The first run is the reference for the loss reductions.

use std::path::PathBuf;

use anyhow::{Result, bail};
use clap::Parser;
use train::compare::{csv_table, markdown_table, read_run, write_loss_plots};

#[derive(Debug, Parser)]
#[command(name = "compare", version, allow_negative_numbers = true)]
struct Args {
    /// Run folders written by `train`; the first is the reference.
    #[arg(required = true)]
    runs: Vec<PathBuf>,
    /// Where the picture and the tables go.
    #[arg(long, default_value = "out/compare")]
    out: PathBuf,
}

fn main() -> std::process::ExitCode {
    datasets::cli::exit_code(run_main())
}

fn run_main() -> Result<()> {
    let args = Args::parse();
    let runs = args.runs.iter().map(|d| read_run(d)).collect::<Result<Vec<_>, _>>()?;
    if runs.iter().any(|r| r.metrics.is_none()) {
        eprintln!("note: runs without metrics.json (unfinished) show no AP");
    }
    if args.out.exists() && !args.out.is_dir() {
        bail!("--out {}: not a folder", args.out.display());
    }
    std::fs::create_dir_all(&args.out).map_err(|e| datasets::DataError::io(&args.out, e))?;
    write_loss_plots(&runs, &args.out.join("losses"))?;
    let table = markdown_table(&runs);
    datasets::atomic::write_bytes(&args.out.join("table.md"), table.as_bytes())?;
    datasets::atomic::write_bytes(&args.out.join("table.csv"), csv_table(&runs).as_bytes())?;
    print!("{table}");
    eprintln!("wrote {}/losses.png, losses.svg, table.md, table.csv", args.out.display());
    Ok(())
}
