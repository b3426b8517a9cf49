//! The stable runner: feeds a target its seeds and then seeded mutations of
//! them, for a number of cases or a time, and stops at the first bug: a
//! panic (with the input that caused it), or a case that runs past the hang
//! limit (reported, then the process aborts, since a hung parser cannot be
//! stopped from outside its thread).

use std::panic::AssertUnwindSafe;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::{Duration, Instant};

use crate::alloc_cap::CURRENT;
use crate::mutate::case_input;
use crate::targets::Target;

/// How long one case may run before it counts as a hang.
pub const HANG_LIMIT: Duration = Duration::from_secs(20);

#[derive(Debug, Clone, Copy)]
pub enum Budget {
    Cases(u64),
    Time(Duration),
}

#[derive(Debug, Clone)]
pub struct RunStats {
    pub target: Target,
    pub executions: u64,
    pub seeds: usize,
    pub elapsed: Duration,
    /// The slowest case and its time.
    pub slowest: (u64, Duration),
}

/// A case that made the target panic.
#[derive(Debug, Clone)]
pub struct Crash {
    pub target: Target,
    pub case: u64,
    pub message: String,
    pub input: Vec<u8>,
}

impl std::fmt::Display for Crash {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "target `{}`, case {}: panicked: {} ({} input bytes)",
            self.target.name(),
            self.case,
            self.message,
            self.input.len()
        )
    }
}

/// Runs `target` from `first_case` on within `budget`; `progress` hears the
/// number of executions so far now and then.
pub fn run(
    target: Target,
    seeds: &[Vec<u8>],
    seed: u64,
    budget: Budget,
    progress: &mut dyn FnMut(u64),
) -> Result<RunStats, Box<Crash>> {
    let seeds: Vec<Vec<u8>> = if seeds.is_empty() { vec![Vec::new()] } else { seeds.to_vec() };
    let watch = Watchdog::start(target);
    let started = Instant::now();
    let mut slowest = (0, Duration::ZERO);
    let mut case = 0u64;
    let outcome = loop {
        let done = match budget {
            Budget::Cases(n) => case >= n,
            Budget::Time(t) => case >= seeds.len() as u64 && started.elapsed() >= t,
        };
        if done {
            break Ok(());
        }
        let input = case_input(&seeds, seed, case);
        CURRENT.with(|c| c.set((target.name(), case)));
        watch.begin(case);
        let began = Instant::now();
        let result = std::panic::catch_unwind(AssertUnwindSafe(|| target.run(&input)));
        let took = began.elapsed();
        if took > slowest.1 {
            slowest = (case, took);
        }
        if let Err(payload) = result {
            let message = payload
                .downcast_ref::<String>()
                .cloned()
                .or_else(|| payload.downcast_ref::<&str>().map(|s| s.to_string()))
                .unwrap_or_else(|| "a panic without a message".into());
            break Err(Box::new(Crash { target, case, message, input }));
        }
        case += 1;
        if case.is_multiple_of(256) {
            progress(case);
        }
    };
    watch.stop();
    progress(case);
    outcome.map(|()| RunStats { target, executions: case, seeds: seeds.len(), elapsed: started.elapsed(), slowest })
}

/// Aborts the process when one case runs past [`HANG_LIMIT`].
struct Watchdog {
    case: Arc<AtomicU64>,
    since_ms: Arc<AtomicU64>,
    stop: Arc<AtomicBool>,
    origin: Instant,
}

impl Watchdog {
    fn start(target: Target) -> Self {
        let watch = Self {
            case: Arc::new(AtomicU64::new(0)),
            since_ms: Arc::new(AtomicU64::new(0)),
            stop: Arc::new(AtomicBool::new(false)),
            origin: Instant::now(),
        };
        let (case, since_ms, stop, origin) =
            (watch.case.clone(), watch.since_ms.clone(), watch.stop.clone(), watch.origin);
        std::thread::spawn(move || {
            while !stop.load(Ordering::Relaxed) {
                std::thread::sleep(Duration::from_millis(200));
                let running = origin.elapsed().as_millis() as u64 - since_ms.load(Ordering::Relaxed);
                if !stop.load(Ordering::Relaxed) && running > HANG_LIMIT.as_millis() as u64 {
                    eprintln!(
                        "fuzz: target `{}`, case {} has run {:.0} s: a hang",
                        target.name(),
                        case.load(Ordering::Relaxed),
                        running as f64 / 1e3
                    );
                    std::process::abort();
                }
            }
        });
        watch
    }

    fn begin(&self, case: u64) {
        self.case.store(case, Ordering::Relaxed);
        self.since_ms.store(self.origin.elapsed().as_millis() as u64, Ordering::Relaxed);
    }

    fn stop(&self) {
        self.stop.store(true, Ordering::Relaxed);
    }
}
