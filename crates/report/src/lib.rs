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
