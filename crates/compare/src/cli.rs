//! What the command line needs beyond the library: an `indicatif` progress bar
//! on stderr, and [`Progress`] for it.

use std::io::IsTerminal;

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};

use crate::progress::Progress;

/// A progress bar on stderr, hidden when stderr is not a terminal (CI, pipes),
/// redrawn every second.
pub fn progress_bar(len: usize, what: &str) -> ProgressBar {
    let target = if std::io::stderr().is_terminal() {
        ProgressDrawTarget::stderr()
    } else {
        ProgressDrawTarget::hidden()
    };
    let bar = ProgressBar::with_draw_target(Some(len as u64), target);
    if let Ok(style) =
        ProgressStyle::with_template("{prefix} [{elapsed_precise}] {bar:32} {pos}/{len} {msg}")
    {
        bar.set_style(style);
    }
    bar.set_prefix(what.to_string());
    // Redraw every second, so the elapsed time moves during one long run (the
    // exact gradient or plain CG at 2048²).
    bar.enable_steady_tick(std::time::Duration::from_secs(1));
    bar
}

impl Progress for ProgressBar {
    fn begin(&self, total: usize, label: &str) {
        self.reset();
        self.set_length(total as u64);
        self.set_prefix(label.to_string());
    }

    fn set_message(&self, message: String) {
        ProgressBar::set_message(self, message);
    }

    fn inc(&self, steps: u64) {
        ProgressBar::inc(self, steps);
    }

    fn finish(&self) {
        self.finish_and_clear();
    }
}
