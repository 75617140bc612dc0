//! Progress reporting for long runs, without a terminal dependency: the
//! library's sweeps and studies report through [`Progress`]; the command line
//! passes an `indicatif` bar (feature `cli`), tests and libraries [`NoProgress`].

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
