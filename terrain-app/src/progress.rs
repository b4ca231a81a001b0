//! A one-line progress display on stderr for long steps run on several threads (the DSS
//! errors and the PVS of `terrain bake`): `\rLABEL:  42 %, 12 s`, redrawn at each new tenth.

use std::io::Write;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Instant;

/// A progress line; `update` may be called from any thread.
#[derive(Debug)]
pub struct Progress {
    label: &'static str,
    start: Instant,
    /// The last tenth printed, plus one (0: none yet).
    shown: AtomicU64,
    enabled: bool,
}

impl Progress {
    /// A progress line for `label`; prints nothing when `enabled` is false.
    pub fn new(label: &'static str, enabled: bool) -> Self {
        Self { label, start: Instant::now(), shown: AtomicU64::new(0), enabled }
    }

    /// `done` of `total` units are finished: redraws the line when a new tenth is reached.
    pub fn update(&self, done: f64, total: f64) {
        if !self.enabled {
            return;
        }
        let frac = if total > 0.0 { (done / total).clamp(0.0, 1.0) } else { 1.0 };
        let tenth = (frac * 10.0) as u64 + 1;
        if self.shown.fetch_max(tenth, Ordering::Relaxed) < tenth {
            let mut err = std::io::stderr();
            let _ = write!(
                err,
                "\r{}: {:3.0} %, {:.0} s",
                self.label,
                100.0 * frac,
                self.start.elapsed().as_secs_f64()
            );
            let _ = err.flush();
        }
    }

    /// Ends the line with the total time.
    pub fn finish(&self) {
        if self.enabled {
            eprintln!("\r{}: 100 %, {:.1} s", self.label, self.start.elapsed().as_secs_f64());
        }
    }
}
