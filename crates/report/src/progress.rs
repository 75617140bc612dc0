//! Progress reporting for long runs: sweeps, studies and trainings report
//! through [`Progress`]; a program passes an `indicatif` bar ([`progress_bar`])
//! or [`LineProgress`] for a log, tests and libraries [`NoProgress`].

use std::io::IsTerminal;

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};

/// Receives the progress of a sweep or a study. Every method has a no-op
/// default, so an implementation overrides only what it shows.
pub trait Progress {
    /// A run of `total` steps named `label` begins.
    fn begin(&self, _total: usize, _label: &str) {}

    /// What is running now.
    fn set_message(&self, _message: String) {}

    /// `steps` more steps are done.
    fn inc(&self, _steps: u64) {}

    /// The run is over.
    fn finish(&self) {}
}

/// Reports nothing.
#[derive(Debug, Clone, Copy, Default)]
pub struct NoProgress;

impl Progress for NoProgress {}

/// Writes one line to stderr per step message, `[done/total mm:ss] message`:
/// progress for a long run whose stderr is not a terminal (a log file, a pipe),
/// where a redrawn bar would not show.
#[derive(Debug)]
pub struct LineProgress {
    started: std::time::Instant,
    total: std::cell::Cell<usize>,
    done: std::cell::Cell<u64>,
    label: std::cell::RefCell<String>,
}

impl Default for LineProgress {
    fn default() -> Self {
        LineProgress {
            started: std::time::Instant::now(),
            total: std::cell::Cell::new(0),
            done: std::cell::Cell::new(0),
            label: std::cell::RefCell::new(String::new()),
        }
    }
}

impl LineProgress {
    /// The line [`Progress::set_message`] writes for `message` now.
    pub fn line(&self, message: &str) -> String {
        let s = self.started.elapsed().as_secs();
        format!(
            "{} [{}/{} {:02}:{:02}] {message}",
            self.label.borrow(),
            self.done.get(),
            self.total.get(),
            s / 60,
            s % 60
        )
    }
}

impl Progress for LineProgress {
    fn begin(&self, total: usize, label: &str) {
        self.total.set(total);
        self.done.set(0);
        *self.label.borrow_mut() = label.to_string();
    }

    fn set_message(&self, message: String) {
        eprintln!("{}", self.line(&message));
    }

    fn inc(&self, steps: u64) {
        self.done.set(self.done.get() + steps);
    }

    fn finish(&self) {
        eprintln!("{}", self.line("done"));
    }
}

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
