//! A one-line progress display on stderr for long steps run on several threads (the DSS
//! errors and the PVS of `terrain bake`): `\rLABEL:  42 %, 12 s`, redrawn at each new tenth on
//! a terminal; elsewhere (a log, CI) plain lines at each quarter, never carriage returns
//! ([`on_terminal`]).

use std::io::{IsTerminal, Write};
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Instant;

/// Whether stderr is a terminal: progress is redrawn in place there, and written as a few
/// plain lines elsewhere.
pub fn on_terminal() -> bool {
    std::io::stderr().is_terminal()
}

/// A progress line; `update` may be called from any thread.
#[derive(Debug)]
pub struct Progress {
    label: &'static str,
    start: Instant,
    /// The last tenth printed, plus one (0: none yet).
    shown: AtomicU64,
    enabled: bool,
    /// Redrawn in place (a terminal) or plain lines at each quarter.
    terminal: bool,
}

impl Progress {
    /// A progress line for `label`; prints nothing when `enabled` is false.
    pub fn new(label: &'static str, enabled: bool) -> Self {
        Self {
            label,
            start: Instant::now(),
            shown: AtomicU64::new(0),
            enabled,
            terminal: on_terminal(),
        }
    }

    /// `done` of `total` units are finished: redraws the line when a new tenth is reached.
    pub fn update(&self, done: f64, total: f64) {
        if !self.enabled {
            return;
        }
        let frac = if total > 0.0 { (done / total).clamp(0.0, 1.0) } else { 1.0 };
        let steps = if self.terminal { 10.0 } else { 4.0 };
        let step = (frac * steps) as u64 + 1;
        if self.shown.fetch_max(step, Ordering::Relaxed) < step {
            let mut err = std::io::stderr();
            let secs = self.start.elapsed().as_secs_f64();
            let _ = if self.terminal {
                write!(err, "\r{}: {:3.0} %, {secs:.0} s", self.label, 100.0 * frac)
            } else if frac < 1.0 && step > 1 {
                writeln!(err, "{}: {:3.0} %, {secs:.0} s", self.label, 100.0 * frac)
            } else {
                Ok(())
            };
            let _ = err.flush();
        }
    }

    /// Ends the line with the total time.
    pub fn finish(&self) {
        if self.enabled {
            let cr = if self.terminal { "\r" } else { "" };
            eprintln!("{cr}{}: 100 %, {:.1} s", self.label, self.start.elapsed().as_secs_f64());
        }
    }
}

/// CPU seconds (user + system, every thread) this process has used so far
/// ([`crate::clock::process_cpu_s`]); `None` where the platform has no such clock.
fn process_cpu_seconds() -> Option<f64> {
    Some(crate::clock::process_cpu_s()).filter(|s| s.is_finite())
}

/// The stages of a long command (`terrain bake`'s blocks and tables) with their wall and CPU
/// seconds, for one summary line at the end.
#[derive(Debug)]
pub struct Stages {
    start: Instant,
    cpu0: Option<f64>,
    mark: (Instant, Option<f64>),
    done: Vec<(&'static str, f64, Option<f64>)>,
}

impl Default for Stages {
    fn default() -> Self {
        Self::new()
    }
}

impl Stages {
    /// Starts the clock (the first stage starts now).
    pub fn new() -> Self {
        let (now, cpu) = (Instant::now(), process_cpu_seconds());
        Self { start: now, cpu0: cpu, mark: (now, cpu), done: Vec::new() }
    }

    /// Ends the current stage, named `name`, and starts the next. Returns its (wall, CPU)
    /// seconds.
    pub fn end(&mut self, name: &'static str) -> (f64, Option<f64>) {
        let (now, cpu) = (Instant::now(), process_cpu_seconds());
        let wall = now.duration_since(self.mark.0).as_secs_f64();
        let used = cpu.zip(self.mark.1).map(|(b, a)| b - a);
        self.done.push((name, wall, used));
        self.mark = (now, cpu);
        (wall, used)
    }

    /// `stages (wall s / CPU s): a 1.2 / 2.3, b ...; total ...`.
    pub fn summary(&self) -> String {
        let cpu = |c: Option<f64>| c.map_or("?".to_string(), |c| format!("{c:.1}"));
        let parts: Vec<String> =
            self.done.iter().map(|(n, w, c)| format!("{n} {w:.1} / {}", cpu(*c))).collect();
        let total_cpu = process_cpu_seconds().zip(self.cpu0).map(|(b, a)| b - a);
        format!(
            "stages (wall s / CPU s): {}; total {:.1} / {}",
            parts.join(", "),
            self.start.elapsed().as_secs_f64(),
            cpu(total_cpu)
        )
    }
}
