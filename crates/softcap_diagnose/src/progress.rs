//! Per-step status of a diagnosis on stderr (indicatif), drawn only when stderr is a terminal:
//! the baseline frames, the screen, then each hypothesis sent to re-simulation.

use indicatif::{ProgressBar, ProgressStyle};
use std::io::IsTerminal;
use std::time::Duration;

/// One status line with a bar; hidden unless enabled and stderr is a terminal.
#[derive(Clone, Debug)]
pub struct Progress {
    bar: ProgressBar,
}

impl Progress {
    /// Drawn when `enabled` and stderr is a terminal.
    pub fn new(enabled: bool) -> Self {
        if !(enabled && std::io::stderr().is_terminal()) {
            return Self::hidden();
        }
        let bar = ProgressBar::new(0);
        if let Ok(style) = ProgressStyle::with_template(
            "diagnose {spinner} {elapsed_precise} [{bar:24}] {pos}/{len} {wide_msg}",
        ) {
            bar.set_style(style.progress_chars("=> "));
        }
        bar.enable_steady_tick(Duration::from_millis(250));
        Self { bar }
    }

    /// Never draws.
    pub fn hidden() -> Self {
        Self {
            bar: ProgressBar::hidden(),
        }
    }

    /// Starts step `what` of `len` units.
    pub fn step(&self, what: impl Into<String>, len: usize) {
        self.bar.set_length(len as u64);
        self.bar.set_position(0);
        self.bar.set_message(what.into());
    }

    /// Unit `pos` of the current step is under way, described by `what`.
    pub fn at(&self, pos: usize, what: impl Into<String>) {
        self.bar.set_position(pos as u64);
        self.bar.set_message(what.into());
    }

    /// One more unit of the current step is done.
    pub fn inc(&self) {
        self.bar.inc(1);
    }

    /// Removes the status line.
    pub fn finish(&self) {
        self.bar.finish_and_clear();
    }
}
