//! Progress bars on stderr (indicatif), drawn only when stderr is a terminal.

use std::io::IsTerminal;

use indicatif::{ProgressBar, ProgressStyle};

/// Factory of progress bars: hidden unless enabled and stderr is a terminal.
#[derive(Clone, Debug)]
pub struct Progress {
    visible: bool,
}

impl Progress {
    /// Bars are drawn when `enabled` and stderr is a terminal.
    pub fn new(enabled: bool) -> Self {
        Self {
            visible: enabled && std::io::stderr().is_terminal(),
        }
    }

    /// Never draws.
    pub fn hidden() -> Self {
        Self { visible: false }
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
}
