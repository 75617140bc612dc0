//! Measuring methods: one run into one [`ResultRow`](crate::report::ResultRow), sweeps over sizes, stopping
//! rules, precisions and operators, the harness's charts and its floors.

use std::path::{Path, PathBuf};

use diffphys_tape::Real;
use ndarray::Array2;
use serde::{Deserialize, Serialize};

use crate::methods::exact::ExactCholesky;
use crate::methods::implicit::ImplicitSolve;
use crate::methods::mgpcg::ImplicitMgpcg;
use crate::methods::naive::NaiveUnrolled;
use crate::methods::GradientMethod;
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

/// A scalar type of the study.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Precision {
    /// `f32`.
    F32,
    /// `f64`.
    F64,
}

impl Precision {
    /// `"f32"` or `"f64"`.
    pub fn name(self) -> &'static str {
        match self {
            Precision::F32 => "f32",
            Precision::F64 => "f64",
        }
    }

    /// The precision of `T`.
    pub fn of<T: Real>() -> Self {
        Precision::parse(T::NAME).expect("Real is implemented for f32 and f64 only")
    }

    /// Parses `f32` or `f64`.
    ///
    /// # Errors
    /// [`CompareError::InvalidArgument`] for anything else.
    pub fn parse(s: &str) -> Result<Self> {
        match s {
            "f32" => Ok(Precision::F32),
            "f64" => Ok(Precision::F64),
            other => Err(CompareError::invalid(format!(
                "unknown precision '{other}': expected f32 or f64"
            ))),
        }
    }
}

impl std::fmt::Display for Precision {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// The gradient methods the harness compares.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub enum MethodKind {
    /// CG unrolled on the tape ([`NaiveUnrolled`]).
    Naive,
    /// The Poisson op with its implicit adjoint.
    Implicit,
    /// The implicit gradient with MG-PCG solves ([`ImplicitMgpcg`]).
    ImplicitMgpcg,
    /// The sparse Cholesky reference.
    Exact,
}

impl MethodKind {
    /// The method's name in results.
    pub fn name(self) -> &'static str {
        match self {
            MethodKind::Naive => "naive",
            MethodKind::Implicit => "implicit",
            MethodKind::ImplicitMgpcg => "implicit_mgpcg",
            MethodKind::Exact => "exact",
        }
    }
}

/// The method of `kind` in precision `T`.
pub fn method<T: Real>(kind: MethodKind) -> Box<dyn GradientMethod<T>> {
    match kind {
        MethodKind::Naive => Box::new(NaiveUnrolled::default()),
        MethodKind::Implicit => Box::new(ImplicitSolve),
        MethodKind::ImplicitMgpcg => Box::new(ImplicitMgpcg::default()),
        MethodKind::Exact => Box::new(ExactCholesky),
    }
}

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
