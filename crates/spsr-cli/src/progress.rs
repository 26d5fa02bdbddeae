//! The current stage, on one rewritten line of stderr.

use std::io::Write;
use std::sync::atomic::{AtomicUsize, Ordering};

/// Shows the current stage on one rewritten line of stderr (only on a terminal).
pub(crate) struct Progress {
    enabled: bool,
    step: AtomicUsize,
}

impl Progress {
    pub(crate) fn new(enabled: bool) -> Self {
        Progress {
            enabled,
            step: AtomicUsize::new(0),
        }
    }

    pub(crate) fn stage(&self, name: &str) {
        if !self.enabled {
            return;
        }
        let n = self.step.fetch_add(1, Ordering::Relaxed) + 1;
        let mut err = std::io::stderr().lock();
        // \x1b[K erases the rest of the previous, possibly longer, line.
        let _ = write!(err, "\r[{n}] {name} ...\x1b[K");
        let _ = err.flush();
    }
}

impl Progress {
    /// Prints a line to stderr, first erasing the stage line when there is one.
    pub(crate) fn note(&self, line: &str) {
        let mut err = std::io::stderr().lock();
        if self.enabled && self.step.load(Ordering::Relaxed) > 0 {
            let _ = write!(err, "\r\x1b[K");
        }
        let _ = writeln!(err, "{line}");
    }
}

impl Drop for Progress {
    fn drop(&mut self) {
        if self.enabled && self.step.load(Ordering::Relaxed) > 0 {
            let mut err = std::io::stderr().lock();
            let _ = write!(err, "\r\x1b[K");
            let _ = err.flush();
        }
    }
}
