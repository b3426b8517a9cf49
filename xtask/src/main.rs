//! `cargo xtask ci`: the checks a change must pass, in one command:
//! rustfmt (check only), clippy with warnings denied, then the tests.

use std::process::{Command, ExitCode};

fn run(args: &[&str]) -> bool {
    eprintln!("$ cargo {}", args.join(" "));
    Command::new(env!("CARGO")).args(args).status().is_ok_and(|s| s.success())
}

fn main() -> ExitCode {
    let task = std::env::args().nth(1);
    match task.as_deref() {
        Some("ci") => {
            let ok = run(&["fmt", "--all", "--", "--check"])
                && run(&["clippy", "--workspace", "--all-targets", "--", "-D", "warnings"])
                && run(&["test", "--workspace"]);
            if ok { ExitCode::SUCCESS } else { ExitCode::FAILURE }
        }
        _ => {
            eprintln!("usage: cargo xtask ci   (fmt check, clippy -D warnings, tests)");
            ExitCode::from(2)
        }
    }
}
