//! The process-wide registry of temporary files being written, so that an interrupt handler
//! can delete them: the one piece of global state in the library. Outputs are written to a
//! temporary file beside the destination and renamed into place when complete; while that
//! happens the temporary file is registered here.

use std::path::{Path, PathBuf};

/// Temporary files being written (or spooled from standard input) right now.
static UNFINISHED: std::sync::Mutex<Vec<PathBuf>> = std::sync::Mutex::new(Vec::new());

/// Registration of a temporary file in [`UNFINISHED`] for as long as the guard lives.
pub(crate) struct Unfinished(PathBuf);

impl Unfinished {
    pub(crate) fn register(path: &Path) -> Self {
        let mut list = UNFINISHED.lock().unwrap_or_else(|e| e.into_inner());
        list.push(path.to_path_buf());
        Unfinished(path.to_path_buf())
    }
}

impl Drop for Unfinished {
    fn drop(&mut self) {
        let mut list = UNFINISHED.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(i) = list.iter().position(|p| *p == self.0) {
            list.swap_remove(i);
        }
    }
}

/// Deletes every temporary file spsr is writing at this moment and returns how many it
/// deleted. For an interrupt handler that then ends the process: the outputs being written
/// never appear (a finished output has already been renamed into place and is not touched).
pub fn remove_unfinished_files() -> usize {
    let list = UNFINISHED.lock().unwrap_or_else(|e| e.into_inner());
    list.iter()
        .filter(|p| {
            if p.is_dir() {
                // A slab run's work folder, with its spill files.
                std::fs::remove_dir_all(p).is_ok()
            } else {
                std::fs::remove_file(p).is_ok()
            }
        })
        .count()
}
