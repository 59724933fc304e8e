//! Stage times of a detection, printed to stderr when the environment
//! variable `GRAINFORCE_PROFILE` is set (to find where a big photograph's
//! time goes; `perf` is not everywhere). Off, a lap costs one branch.

use std::sync::OnceLock;
use std::time::Instant;

fn enabled() -> bool {
    static ON: OnceLock<bool> = OnceLock::new();
    *ON.get_or_init(|| std::env::var_os("GRAINFORCE_PROFILE").is_some())
}

/// A stopwatch over consecutive stages: wall and process CPU seconds.
pub struct Laps {
    start: Option<(Instant, f64)>,
}

impl Laps {
    pub fn start() -> Self {
        Laps {
            start: enabled().then(|| (Instant::now(), cpu())),
        }
    }

    /// Whether laps are printed (labels worth building only then).
    pub fn running(&self) -> bool {
        self.start.is_some()
    }

    /// Prints the time since the last lap under `label` and starts the next.
    pub fn lap(&mut self, label: &str) {
        if let Some((t, c)) = self.start {
            let (now, cpu_now) = (Instant::now(), cpu());
            eprintln!(
                "profile: {label:<40} {:7.3} s wall {:7.3} s CPU",
                (now - t).as_secs_f64(),
                cpu_now - c
            );
            self.start = Some((now, cpu_now));
        }
    }
}

fn cpu() -> f64 {
    crate::bench::cpu_seconds().unwrap_or(f64::NAN)
}
