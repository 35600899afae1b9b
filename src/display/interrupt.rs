//! Ctrl-C and SIGTERM as a request to stop: long commands check [`STOP`] between steps and leave their output
//! whole (a checkpoint saved, a cache not half-written) instead of dying mid-write.

use std::sync::atomic::{AtomicBool, Ordering};

/// Set by SIGINT/SIGTERM: training checkpoints and stops at the next step.
pub static STOP: AtomicBool = AtomicBool::new(false);

extern "C" fn on_signal(_: libc::c_int) {
    STOP.store(true, Ordering::Relaxed);
}

/// From now on Ctrl-C and SIGTERM set [`STOP`] instead of killing the process.
pub fn catch_interrupts() {
    // SAFETY: the handler only stores to an atomic, which is async-signal-safe.
    unsafe {
        libc::signal(libc::SIGINT, on_signal as *const () as libc::sighandler_t);
        libc::signal(libc::SIGTERM, on_signal as *const () as libc::sighandler_t);
    }
}
