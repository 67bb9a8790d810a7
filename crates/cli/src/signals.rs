//! Stopping long commands cleanly: SIGINT (Ctrl-C) and SIGTERM set a
//! [`Cancel`] token that the pipeline checks between items; the command then
//! stops after the item in flight, and `main` exits 128 + the signal's
//! number (130, 143), as shells do. A second signal stops at once.

use std::sync::atomic::{AtomicI32, Ordering};

use revisit_pipeline::Cancel;
use signal_hook::consts::{SIGINT, SIGTERM};

/// The signal that asked to stop, 0 if none.
static RECEIVED: AtomicI32 = AtomicI32::new(0);

/// A token that SIGINT and SIGTERM cancel from now on.
pub fn cancel_on_signals() -> anyhow::Result<Cancel> {
    let cancel = Cancel::new();
    let mut signals = signal_hook::iterator::Signals::new([SIGINT, SIGTERM])?;
    let token = cancel.clone();
    std::thread::spawn(move || {
        for signal in signals.forever() {
            if RECEIVED.swap(signal, Ordering::SeqCst) != 0 {
                std::process::exit(128 + signal);
            }
            token.cancel();
        }
    });
    Ok(cancel)
}

/// The exit code for a command stopped by a signal: 128 + its number.
pub fn exit_code() -> Option<u8> {
    match RECEIVED.load(Ordering::SeqCst) {
        0 => None,
        signal => u8::try_from(128 + signal).ok(),
    }
}

/// The signal's name, for the one line said on stopping.
pub fn name() -> &'static str {
    match RECEIVED.load(Ordering::SeqCst) {
        SIGINT => "SIGINT",
        SIGTERM => "SIGTERM",
        _ => "a signal",
    }
}
