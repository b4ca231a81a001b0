//! Ctrl-C (SIGINT) and SIGTERM during `terrain bake`: the signal only sets a flag, which the
//! bake checks after each row of blocks and between its tables; it then removes what it wrote
//! (the `.NAME.part` folder of the blocks) and exits with [`EXIT_CODE`]. A second signal exits
//! at once (the standard escape when a step takes long).

use std::sync::atomic::{AtomicBool, Ordering};

/// The exit status of an interrupted command: 128 + SIGINT, as shells report it.
pub(crate) const EXIT_CODE: u8 = 130;

static INTERRUPTED: AtomicBool = AtomicBool::new(false);

/// Installs the handler: the first SIGINT/SIGTERM sets the flag, a second exits with
/// [`EXIT_CODE`]. Fails if a handler is already installed.
pub(crate) fn install() -> anyhow::Result<()> {
    ctrlc::set_handler(|| {
        if INTERRUPTED.swap(true, Ordering::SeqCst) {
            eprintln!("\ninterrupted again: stopping at once");
            std::process::exit(i32::from(EXIT_CODE));
        }
    })
    .map_err(|e| anyhow::anyhow!("could not install the Ctrl-C handler: {e}"))
}

/// Whether a SIGINT or SIGTERM has arrived since [`install`].
pub(crate) fn interrupted() -> bool {
    INTERRUPTED.load(Ordering::SeqCst)
}

/// The error an interrupted command returns; `main` exits with [`EXIT_CODE`] on it.
#[derive(Debug)]
pub(crate) struct Interrupted(pub(crate) String);

impl std::fmt::Display for Interrupted {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "interrupted: {}", self.0)
    }
}

impl std::error::Error for Interrupted {}
