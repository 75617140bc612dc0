//! Measuring methods: one run into one [`ResultRow`](crate::model::ResultRow),
//! sweeps over sizes, stopping rules, precisions and operators, the harness's
//! charts and its floors. It runs the [`methods`](crate::methods) and
//! produces the rows of [`model`](crate::model); rendering them is the
//! [`report`](crate::report)'s.

use std::path::{Path, PathBuf};

use diffphys_tape::Real;
use ndarray::Array2;

use crate::{CompareError, Result};

mod charts;
mod floors;
mod measure;
mod policy;
mod sweep;
mod timing;

#[cfg(feature = "cli")]
pub use crate::cli::progress_bar;
pub use charts::write_charts;
pub(crate) use charts::{series_by_method, write_chart};
pub use floors::{compute_floors, FLOOR_N, FLOOR_RTOL, MGPCG_FLOOR_N};
pub use measure::{
    finite_difference_error, measure, measure_baseline, measure_baseline_with, measure_with,
};
pub use policy::{Statistic, Timed, TimingPolicy};
pub(crate) use sweep::{exact_reference, ExactCache};
pub use sweep::{naive_bytes_per_iteration, run_sweep, run_sweep_npy, stop_label, SweepConfig};
pub use timing::{cg_speedup, time_cg_iterations, time_fused_cg, IterationTiming};

/// `‖g − g*‖ / ‖g*‖` in `f64` (`‖g − g*‖` if `g* = 0`); `None` if `g` holds a
/// non-finite value or the shapes differ.
pub fn relative_error<T: Real>(g: &Array2<T>, exact: &Array2<f64>) -> Option<f64> {
    if g.dim() != exact.dim() || g.iter().any(|v| !v.is_finite()) {
        return None;
    }
    let (mut num, mut den) = (0.0, 0.0);
    for (&a, &b) in g.iter().zip(exact) {
        num += (a.as_f64() - b).powi(2);
        den += b * b;
    }
    Some(if den > 0.0 {
        (num / den).sqrt()
    } else {
        num.sqrt()
    })
}

/// Creates the output folder.
///
/// # Errors
/// [`CompareError::Io`].
pub fn prepare_out_dir(out: &Path) -> Result<PathBuf> {
    std::fs::create_dir_all(out).map_err(|e| CompareError::io(out, e))?;
    Ok(out.to_path_buf())
}
