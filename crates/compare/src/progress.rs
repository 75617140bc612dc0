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
