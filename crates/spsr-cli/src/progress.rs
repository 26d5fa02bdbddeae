//! The progress bar of a run on a terminal: `[k/N] stage`, a bar, the elapsed time and an
//! estimate of the time left (indicatif). Nothing is drawn when stderr is not a terminal.

use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};

const TEMPLATE: &str = "{prefix} {bar:24.cyan/blue} {msg:<24} {elapsed:>4} elapsed, ~{eta} left";

/// Counts the stages of a run and shows the current one. The bar's position is the number of
/// stages finished, its length the number planned (`N`), so the estimate of the time left
/// is indicatif's from the pace of the stages so far.
pub(crate) struct Progress {
    bar: ProgressBar,
    /// The stage running now, from 1; 0 before the first.
    current: AtomicU64,
}

impl Progress {
    /// A run of `stages` stages (more can be announced with [`Progress::add_stages`]), drawn
    /// on stderr when `terminal` is true.
    pub(crate) fn new(stages: usize, terminal: bool) -> Self {
        let target = if terminal {
            ProgressDrawTarget::stderr()
        } else {
            ProgressDrawTarget::hidden()
        };
        let bar = ProgressBar::with_draw_target(Some(stages as u64), target);
        if let Ok(style) = ProgressStyle::with_template(TEMPLATE) {
            bar.set_style(style.progress_chars("=> "));
        }
        if terminal {
            // Redraws the elapsed time while a long stage runs.
            bar.enable_steady_tick(Duration::from_millis(200));
        }
        Progress {
            bar,
            current: AtomicU64::new(0),
        }
    }

    /// Plans `n` more stages (such as estimating normals, once the input turns out to have
    /// none).
    pub(crate) fn add_stages(&self, n: usize) {
        self.bar.inc_length(n as u64);
    }

    /// Starts the next stage.
    pub(crate) fn stage(&self, name: &str) {
        let k = self.current.fetch_add(1, Ordering::Relaxed) + 1;
        // A stage the plan did not foresee lengthens it rather than showing k > N.
        if self.bar.length().is_some_and(|n| k > n) {
            self.bar.set_length(k);
        }
        self.bar.set_position(k - 1);
        let n = self.bar.length().unwrap_or(k);
        self.bar.set_prefix(format!("[{k}/{n}]"));
        self.bar.set_message(name.to_string());
    }

    /// `(k, N)`: the stage running now and the number planned.
    #[cfg(test)]
    fn counts(&self) -> (u64, u64) {
        (
            self.current.load(Ordering::Relaxed),
            self.bar.length().unwrap_or(0),
        )
    }

    /// Prints a line to stderr, above the bar while one is drawn.
    pub(crate) fn note(&self, line: &str) {
        self.bar.suspend(|| eprintln!("{line}"));
    }
}

impl Drop for Progress {
    fn drop(&mut self) {
        self.bar.finish_and_clear();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stages_are_counted_against_the_plan() {
        let p = Progress::new(3, false);
        assert_eq!(p.counts(), (0, 3));
        p.stage("reading");
        assert_eq!(p.counts(), (1, 3));
        p.add_stages(1);
        p.stage("estimating normals");
        p.stage("solving");
        assert_eq!(p.counts(), (3, 4));
        assert_eq!(p.bar.position(), 2, "two stages finished");
        p.stage("writing");
        // One stage more than planned lengthens the plan.
        p.stage("unforeseen");
        assert_eq!(p.counts(), (5, 5));
    }

    #[test]
    fn nothing_is_drawn_off_a_terminal() {
        let p = Progress::new(2, false);
        p.stage("reading");
        assert!(p.bar.is_hidden());
    }
}
