//! Progress on long work: indicatif bars and per-step status lines on stderr, drawn only when
//! stderr is a terminal (so logs, pipes and CI stay clean and outputs stay deterministic).

use std::io::IsTerminal;
use std::time::Duration;

use indicatif::{ProgressBar, ProgressStyle};

/// Factory of progress bars and status lines: silent unless enabled and stderr is a terminal.
#[derive(Clone, Debug)]
pub struct Progress {
    visible: bool,
}

impl Default for Progress {
    /// Enabled (drawn when stderr is a terminal).
    fn default() -> Self {
        Self::new(true)
    }
}

impl Progress {
    /// Draws when `enabled` and stderr is a terminal.
    pub fn new(enabled: bool) -> Self {
        Self {
            visible: enabled && std::io::stderr().is_terminal(),
        }
    }

    /// Never draws.
    pub fn hidden() -> Self {
        Self { visible: false }
    }

    /// Whether anything is drawn.
    pub fn is_visible(&self) -> bool {
        self.visible
    }

    /// A bar of `len` steps labelled `what`.
    pub fn bar(&self, what: &str, len: u64) -> ProgressBar {
        if !self.visible {
            return ProgressBar::hidden();
        }
        let bar = ProgressBar::new(len);
        if let Ok(style) =
            ProgressStyle::with_template("{msg:32} [{bar:30}] {pos}/{len} {elapsed_precise}")
        {
            bar.set_style(style.progress_chars("=> "));
        }
        bar.set_message(what.to_string());
        bar
    }

    /// A spinner for work of unknown length labelled `what`; finish it with
    /// [`ProgressBar::finish_and_clear`] or [`ProgressBar::finish_with_message`].
    pub fn spinner(&self, what: &str) -> ProgressBar {
        if !self.visible {
            return ProgressBar::hidden();
        }
        let bar = ProgressBar::new_spinner();
        if let Ok(style) = ProgressStyle::with_template("{spinner} {msg} {elapsed_precise}") {
            bar.set_style(style);
        }
        bar.set_message(what.to_string());
        bar.enable_steady_tick(Duration::from_millis(200));
        bar
    }

    /// A spinner that counts steps of unknown total (`what: N`), e.g. designs simulated.
    pub fn counter(&self, what: &str) -> ProgressBar {
        if !self.visible {
            return ProgressBar::hidden();
        }
        let bar = ProgressBar::new_spinner();
        if let Ok(style) = ProgressStyle::with_template("{spinner} {msg}: {pos} {elapsed_precise}")
        {
            bar.set_style(style);
        }
        bar.set_message(what.to_string());
        bar.enable_steady_tick(Duration::from_millis(200));
        bar
    }

    /// Prints one status line (`step k/n: what`) on stderr.
    pub fn step(&self, k: usize, n: usize, what: &str) {
        if self.visible {
            eprintln!("[{k}/{n}] {what}");
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hidden_progress_draws_nothing() {
        let p = Progress::hidden();
        assert!(!p.is_visible());
        let bar = p.bar("fit", 10);
        bar.inc(3);
        assert!(bar.is_hidden());
        assert!(p.spinner("search").is_hidden());
        assert!(p.counter("designs").is_hidden());
        p.step(1, 2, "nothing printed");
    }
}
