//! What the terrain-app examples share: their `--flag VALUE` arguments (the examples are
//! measurement tools, not commands: `terrain` itself parses with clap). Their median and CPU
//! clock are `terrain_app::bench`'s.
//!
//! Each example includes this as `mod common;` and uses part of it.
#![allow(dead_code)]

/// The example's arguments: flags with a value are taken out by name, the rest stay in order.
#[derive(Debug, Clone)]
pub(crate) struct Args(Vec<String>);

impl Args {
    /// The process's arguments after the program name.
    pub(crate) fn from_env() -> Self {
        Self(std::env::args().skip(1).collect())
    }

    /// The value after `flag` (the pair removed); `None` when `flag` is absent or last.
    pub(crate) fn take(&mut self, flag: &str) -> Option<String> {
        let k = self.0.iter().position(|a| a == flag)?;
        (k + 1 < self.0.len()).then(|| {
            let v = self.0.remove(k + 1);
            self.0.remove(k);
            v
        })
    }

    /// Whether the bare `flag` was given (taken out).
    pub(crate) fn flag(&mut self, flag: &str) -> bool {
        let k = self.0.iter().position(|a| a == flag);
        k.map(|k| self.0.remove(k)).is_some()
    }

    /// The value after `flag`, or `default`.
    pub(crate) fn take_or(&mut self, flag: &str, default: &str) -> String {
        self.take(flag).unwrap_or_else(|| default.to_string())
    }

    /// The arguments not taken, in order.
    pub(crate) fn rest(&self) -> &[String] {
        &self.0
    }
}
