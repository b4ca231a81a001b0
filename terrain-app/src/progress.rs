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
