//! Ctrl-C and termination as a request, not a kill: the binary points SIGINT and SIGTERM at
//! [`flag`], long work polls [`requested`] at its safe points (between training steps,
//! frames, images) and stops there with an error, so that staging folders are removed and a
//! training run keeps a checkpoint to resume from. A second signal ends the process at once.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, LazyLock};

static FLAG: LazyLock<Arc<AtomicBool>> = LazyLock::new(|| Arc::new(AtomicBool::new(false)));

/// The flag the signal handlers set.
pub fn flag() -> Arc<AtomicBool> {
    FLAG.clone()
}

/// Whether a stop was asked for.
pub fn requested() -> bool {
    FLAG.load(Ordering::Relaxed)
}

/// Asks for a stop, as a signal would (for tests and for callers that stop work themselves).
pub fn request() {
    FLAG.store(true, Ordering::Relaxed);
}

/// Withdraws a request (tests that ask for a stop and then go on).
pub fn clear() {
    FLAG.store(false, Ordering::Relaxed);
}
