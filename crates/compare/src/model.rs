//! The vocabulary every part of the comparison shares: which method ran
//! ([`Method`]), in which precision ([`Precision`]), how the run ended
//! ([`RunStatus`]), the row it produced ([`ResultRow`]) and the floors judged
//! from rows ([`Floor`]). The operator of a scene is
//! [`OperatorKind`].
//!
//! The methods produce rows, the harness and the studies collect them and the
//! report renders them; all of them import this module, and it imports none of
//! them (only the scene's operator and the error type).

use diffphys_tape::Real;
use serde::{Deserialize, Serialize};

use crate::problem::OperatorKind;
use crate::{CompareError, Result};

/// What a row measured: a gradient method, the straightforward CG baseline, or
/// the scene's setup (a row for a scene that could not be built).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Method {
    /// CG unrolled on the tape
    /// ([`NaiveUnrolled`](crate::methods::naive::NaiveUnrolled)).
    Naive,
    /// The Poisson op with its implicit adjoint
    /// ([`ImplicitSolve`](crate::methods::implicit::ImplicitSolve)).
    Implicit,
    /// The implicit gradient with multigrid-preconditioned CG for the forward
    /// and the adjoint solve ([`ImplicitMgpcg`](crate::methods::mgpcg::ImplicitMgpcg)).
    ImplicitMgpcg,
    /// The sparse Cholesky reference
    /// ([`ExactCholesky`](crate::methods::exact::ExactCholesky)).
    Exact,
    /// The straightforward CG, forward only
    /// ([`baseline_cg`](crate::methods::baseline::baseline_cg)).
    BaselineCg,
    /// Building the scene, before any method ran.
    Setup,
}

impl Method {
    /// The methods a sweep can run (`--methods`), in the order a sweep runs them.
    pub const SELECTABLE: [Method; 5] = [
        Method::Exact,
        Method::BaselineCg,
        Method::Implicit,
        Method::ImplicitMgpcg,
        Method::Naive,
    ];

    /// The name in results: `naive`, `implicit`, `implicit_mgpcg`, `exact`,
    /// `baseline_cg`, `setup` (the serde name).
    pub fn name(self) -> &'static str {
        match self {
            Method::Naive => "naive",
            Method::Implicit => "implicit",
            Method::ImplicitMgpcg => "implicit_mgpcg",
            Method::Exact => "exact",
            Method::BaselineCg => "baseline_cg",
            Method::Setup => "setup",
        }
    }

    /// Parses the name of one of [`Method::SELECTABLE`].
    ///
    /// # Errors
    /// [`CompareError::InvalidArgument`] naming the valid methods.
    pub fn parse(s: &str) -> Result<Self> {
        Method::SELECTABLE
            .into_iter()
            .find(|m| m.name() == s)
            .ok_or_else(|| {
                CompareError::invalid(format!(
                    "unknown method '{s}': expected one of {}",
                    Method::SELECTABLE.map(Method::name).join(", ")
                ))
            })
    }

    /// True for a method that computes a gradient (not the forward-only
    /// baseline or the setup): one [`gradient_method`](crate::methods::gradient_method)
    /// returns.
    pub fn is_gradient(self) -> bool {
        matches!(
            self,
            Method::Naive | Method::Implicit | Method::ImplicitMgpcg | Method::Exact
        )
    }
}

impl std::fmt::Display for Method {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

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
    /// `"f32"` or `"f64"` (the serde name).
    pub fn name(self) -> &'static str {
        match self {
            Precision::F32 => "f32",
            Precision::F64 => "f64",
        }
    }

    /// The precision of `T`.
    pub fn of<T: Real>() -> Self {
        if std::mem::size_of::<T>() < 8 {
            Precision::F32
        } else {
            Precision::F64
        }
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

/// How a run ended, decided where it ended: by the measurement when the method
/// returned ([`ResultRow::fail`] for an error), by the sweep when it refused a
/// run. Serialised in `results.json` as `ok`, `failed`, `skipped`,
/// `memory_limit`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum RunStatus {
    /// The run completed (its figures may still be non-finite).
    #[default]
    Ok,
    /// The run failed; the row's `error` says why.
    Failed,
    /// The run was not attempted ([`CompareError::Skipped`]: a naive tape over
    /// its limit).
    Skipped,
    /// The run was refused before it allocated by the memory guard
    /// ([`CompareError::MemoryLimit`]).
    MemoryLimit,
}

impl RunStatus {
    /// The status of a run that ended in `e`, by the error's type.
    pub fn of_error(e: &CompareError) -> Self {
        match e {
            CompareError::Skipped(_) => RunStatus::Skipped,
            CompareError::MemoryLimit { .. } => RunStatus::MemoryLimit,
            _ => RunStatus::Failed,
        }
    }

    /// The serde name: `ok`, `failed`, `skipped`, `memory_limit`.
    pub fn name(self) -> &'static str {
        match self {
            RunStatus::Ok => "ok",
            RunStatus::Failed => "failed",
            RunStatus::Skipped => "skipped",
            RunStatus::MemoryLimit => "memory_limit",
        }
    }

    /// True for a run that was never attempted (skipped or refused for memory).
    pub fn not_run(self) -> bool {
        matches!(self, RunStatus::Skipped | RunStatus::MemoryLimit)
    }
}

impl std::fmt::Display for RunStatus {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// One measured run of one method on one scene. Serialised as a `results.json`
/// entry; `null` where a figure does not apply (no backward for a baseline, no
/// heap figure without the counting allocator, no error against exact when the
/// run failed).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ResultRow {
    /// `naive`, `implicit`, `exact`, `baseline_cg`, `setup`.
    pub method: Method,
    /// `f32` or `f64`.
    pub precision: Precision,
    /// Cells per axis.
    pub n: usize,
    /// CG iterations of the forward solve (the fixed count, or what the tolerance
    /// needed); `null` for a direct solve.
    pub iterations: Option<usize>,
    /// The relative tolerance asked for; `null` for a fixed iteration count.
    pub rtol: Option<f64>,
    /// Seconds for the forward solve and the loss.
    pub forward_s: Option<f64>,
    /// Seconds for the gradient after the forward.
    pub backward_s: Option<f64>,
    /// Peak bytes held by the tape (0 without a tape).
    pub tape_bytes: usize,
    /// Peak heap bytes during the run above what was allocated before it
    /// (counting allocator); `null` if no counting allocator is installed.
    pub peak_heap_bytes: Option<usize>,
    /// `‖g − g_exact‖ / ‖g_exact‖` against the `f64` Cholesky gradient; `null`
    /// if the run failed or produced non-finite values.
    pub grad_rel_err: Option<f64>,
    /// True if the loss and every gradient entry stayed finite and no
    /// non-finite error was raised.
    pub finite: bool,
    /// The error, if the run failed.
    pub error: Option<String>,
    /// How the run ended: `ok`, `failed`, `skipped`, `memory_limit`, set where
    /// the run ended ([`ResultRow::fail`]); a file written before the field
    /// existed reads as `ok`, and [`read_results_json`](crate::report::read_results_json)
    /// makes a row with an error `failed`.
    #[serde(default)]
    pub status: RunStatus,
    /// A variant of the method shown beside it in tables (`naive (x0)`); not
    /// serialised.
    #[serde(skip)]
    pub variant: Option<String>,
    /// The operator (`laplacian`, `aniso100`): the conditioning axis.
    pub operator: OperatorKind,
    /// The iteration cap of a tolerance run, or the fixed count.
    pub max_iters: Option<usize>,
    /// CG iterations of the adjoint solve (implicit method).
    pub adjoint_iterations: Option<usize>,
    /// The relative residual `‖b − A p‖/‖b‖` the forward solution reached
    /// (recomputed in `f64`), to read beside the requested [`ResultRow::rtol`]: a
    /// tolerance below the rounding floor of the precision is not reached.
    #[serde(alias = "forward_residual")]
    pub reached_relative_residual: Option<f64>,
    /// The loss value.
    pub loss: Option<f64>,
    /// Relative error of the gradient's directional derivative against a central
    /// finite difference of the method's own loss (small grids only): small for a
    /// gradient that is the derivative of what the method computed.
    pub fd_rel_err: Option<f64>,
    /// Untimed warm-up runs before the timed ones
    /// ([`TimingPolicy`](crate::harness::TimingPolicy)).
    #[serde(default)]
    pub warmup_runs: usize,
    /// Forward + backward seconds of every timed run, in run order; the row's
    /// times are those of the run the policy's statistic picked. Empty for a
    /// run that was not timed.
    #[serde(default)]
    pub run_times_s: Vec<f64>,
}

impl ResultRow {
    /// A row with the identifying fields set and every figure empty.
    pub fn new(method: Method, precision: Precision, n: usize, operator: OperatorKind) -> Self {
        ResultRow {
            method,
            precision,
            n,
            iterations: None,
            rtol: None,
            forward_s: None,
            backward_s: None,
            tape_bytes: 0,
            peak_heap_bytes: None,
            grad_rel_err: None,
            finite: true,
            error: None,
            status: RunStatus::Ok,
            variant: None,
            operator,
            max_iters: None,
            adjoint_iterations: None,
            reached_relative_residual: None,
            loss: None,
            fd_rel_err: None,
            warmup_runs: 0,
            run_times_s: Vec::new(),
        }
    }

    /// `forward_s + backward_s` (the forward alone if there is no backward).
    pub fn total_s(&self) -> Option<f64> {
        self.forward_s.map(|f| f + self.backward_s.unwrap_or(0.0))
    }

    /// Records that the run ended in `e`: its message and its status.
    pub fn fail(&mut self, e: &CompareError) {
        self.error = Some(e.to_string());
        self.status = RunStatus::of_error(e);
    }

    /// True for a run that was attempted and failed (not skipped or refused).
    pub fn failed(&self) -> bool {
        self.status == RunStatus::Failed
    }

    /// True for a run that completed (its figures may still be non-finite).
    pub fn ok(&self) -> bool {
        self.status == RunStatus::Ok
    }

    /// `method precision`, the label of this row's curve in charts.
    pub fn series_label(&self) -> String {
        format!("{} {}", self.method, self.precision)
    }
}

/// One performance floor of the project, measured as a ratio in this run.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Floor {
    /// A short key (`heap_ratio`, …), used in the closing JSON line.
    pub key: String,
    /// What is compared, in words.
    pub description: String,
    /// The measured figure; `None` if the run did not include what it needs.
    pub measured: Option<f64>,
    /// The bound it must meet.
    pub limit: f64,
    /// True if `measured ≥ limit`, false if `measured ≤ limit` is required.
    pub at_least: bool,
    /// Why it was not measured, or a remark on the measurement.
    pub note: String,
}

/// The verdict on a floor: a floor without a measurement is not measured,
/// never held.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Verdict {
    /// Measured and within its bound.
    Holds,
    /// Measured and outside its bound.
    Fails,
    /// The run did not include what the floor needs.
    NotMeasured,
}

impl Verdict {
    /// `holds`, `FAILS` or `not measured`, as tables print it.
    pub fn label(self) -> &'static str {
        match self {
            Verdict::Holds => "holds",
            Verdict::Fails => "FAILS",
            Verdict::NotMeasured => "not measured",
        }
    }
}

impl Floor {
    /// Whether the floor holds; `None` if it was not measured.
    pub fn holds(&self) -> Option<bool> {
        self.measured.map(|m| {
            if self.at_least {
                m >= self.limit
            } else {
                m <= self.limit
            }
        })
    }

    /// The verdict: [`Verdict::NotMeasured`] without a measurement.
    pub fn verdict(&self) -> Verdict {
        match self.holds() {
            Some(true) => Verdict::Holds,
            Some(false) => Verdict::Fails,
            None => Verdict::NotMeasured,
        }
    }
}
