//! What a diffphys run shows and writes, apart from what it measures: SVG
//! charts ([`chart`]: line charts, heat maps, panels of fields on one colour
//! scale, quiver plots), progress on stderr ([`progress`]: a bar on a terminal,
//! one line per message in a log), fields and gradients as `.npy` files with an
//! index ([`npy`]), and number formatting ([`format`](mod@format)).
//!
//! The comparison harness (`diffphys-compare`) and the learning scenes both
//! report through it; neither depends on the other for it.

#![warn(missing_docs)]

pub mod chart;
mod error;
pub mod format;
pub mod npy;
pub mod progress;

pub use error::{ReportError, Result};
pub use progress::{progress_bar, NoProgress, Progress};

/// The process's peak resident set size in bytes (`VmHWM` of
/// `/proc/self/status`; `None` where there is no such file).
pub fn peak_rss_bytes() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024)
}

/// Prints the peak resident memory after `phase` (a learning run reports
/// it as it goes; buffer pools are freed with the runs that made them).
pub fn print_memory(phase: &str) {
    println!(
        "  memory after {phase}: peak RSS {:.0} MB",
        peak_rss_bytes().unwrap_or(0) as f64 / 1e6
    );
}
