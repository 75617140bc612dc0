//! Where gradient methods fail: the studies of `diffphys-compare stability`.
//!
//! Each study provokes one failure mode and measures its outcome with the same
//! methods ([`NaiveUnrolled`], [`ImplicitSolve`], [`ExactCholesky`]) and the same
//! measurement ([`measure`], [`crate::harness::relative_error`]) as the main sweep:
//!
//! 1. precision and iteration counts: both methods in `f32` and `f64` at fixed
//!    CG iteration counts from a few up to ten times what convergence needs.
//!    Backpropagating naively through iterations past convergence divides by
//!    vanishing residual norms (`β = ‖r_{k+1}‖²/‖r_k‖²`): the gradient blows up,
//!    reported as a non-finite error naming the op and the iteration;
//! 2. the floor: the implicit gradient in `f32` on 64² at every iteration cap
//!    from convergence up to 1000 against the `f64` exact gradient;
//! 3. unconverged forward solves: the implicit gradient's error against the
//!    forward relative residual (forward stopped early, adjoint tight, and both
//!    stopped alike), the naive gradient's against its iteration count;
//! 4. conditioning: the plain Laplacian at growing sizes, anisotropic operators,
//!    and the singular all-Neumann pressure system;
//! 5. the initial guess `x0`: `∂L/∂x0` is exactly zero for the implicit method
//!    and non-zero for the naive one;
//! 6. long unrolls: the gradient norm of a loss after `N` upwind advection steps
//!    against `N`, at Courant numbers below and above 1.
//!
//! A failed run is a row with its typed error, never a silent NaN.

use std::path::Path;

use diffphys_ops::advection::{upwind_1d_tape, AdvectionParams};
use diffphys_ops::cg::{cg_solve, CgInfo, CgParams};
use diffphys_ops::{Boundary, Grid1, OpsError};
use diffphys_tape::{Real, Tape, TapeError, Var};
use indicatif::ProgressBar;
use ndarray::{Array1, Array2};
use serde::{Deserialize, Serialize};

use crate::chart::{LineChart, Series};
use crate::harness::{
    exact_reference, measure, progress_bar, series_by_method, write_chart, ExactCache,
};
use crate::methods::implicit::{implicit_initial_guess_gradient, ImplicitSeparateAdjoint};
use crate::methods::{implicit::ImplicitSolve, naive::NaiveUnrolled, GradientMethod, Stop};
use crate::problem::{OperatorKind, Problem, ProblemSpec};
use crate::report::{Floor, ResultRow};
use crate::{CompareError, Result};

/// The relative residual at which a CG solve counts as converged in `T`:
/// `1e-10` in `f64`, `1e-5` in `f32` (a few hundred times `f32`'s epsilon; the
/// true residual of an `f32` iterate stalls near `ε·‖A‖‖x‖/‖b‖` whatever the
/// iteration count).
pub fn converged_rtol<T: Real>() -> f64 {
    if std::mem::size_of::<T>() < 8 {
        1e-5
    } else {
        1e-10
    }
}

/// The iteration cap of every tolerance run of the study.
pub const TOLERANCE_CAP: usize = 20_000;

/// The bound of the `f32` floor: relative gradient error against the `f64` exact
/// gradient.
pub const F32_FLOOR_LIMIT: f64 = 1e-4;

/// What a stability run covers.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StabilityConfig {
    /// Grid size of the precision / iteration-count study.
    pub iteration_n: usize,
    /// Small fixed iteration counts, before convergence.
    pub few_iterations: Vec<usize>,
    /// Fixed iteration counts as multiples of the `f64` convergence count.
    pub convergence_multiples: Vec<f64>,
    /// Grid size of the `f32` floor.
    pub floor_n: usize,
    /// Largest iteration cap of the floor.
    pub floor_max_iters: usize,
    /// Step between the floor's iteration caps (1: every cap).
    pub floor_stride: usize,
    /// Grid size of the unconverged-forward study.
    pub unconverged_n: usize,
    /// Forward tolerances of the unconverged-forward study.
    pub forward_rtols: Vec<f64>,
    /// Sizes of the plain Laplacian (conditioning).
    pub laplacian_sizes: Vec<usize>,
    /// `(n, ratio)` of the anisotropic operators.
    pub anisotropic: Vec<(usize, f64)>,
    /// Sizes of the singular all-Neumann system.
    pub neumann_sizes: Vec<usize>,
    /// Naive runs only up to this grid size in the conditioning study (its tape
    /// grows with size × iterations).
    pub naive_max_n: usize,
    /// Grid size of the initial-guess study.
    pub x0_n: usize,
    /// Fixed iteration counts of the initial-guess study (plus a converged run).
    pub x0_iterations: Vec<usize>,
    /// Cells of the 1D periodic advection unroll.
    pub unroll_n: usize,
    /// Step counts of the unroll.
    pub unroll_steps: Vec<usize>,
    /// Courant numbers of the unroll.
    pub cfls: Vec<f64>,
}

impl StabilityConfig {
    /// The full study (under two minutes on two cores).
    pub fn full() -> Self {
        StabilityConfig {
            iteration_n: 32,
            few_iterations: vec![2, 5, 10, 20],
            convergence_multiples: vec![0.5, 0.75, 1.0, 1.25, 1.5, 2.0, 3.0, 5.0, 7.0, 10.0],
            floor_n: 64,
            floor_max_iters: 1000,
            floor_stride: 1,
            unconverged_n: 32,
            forward_rtols: vec![1e-1, 3e-2, 1e-2, 3e-3, 1e-3, 1e-4, 1e-5, 1e-6, 1e-8, 1e-10],
            laplacian_sizes: vec![16, 32, 64, 128, 256],
            anisotropic: vec![(32, 100.0), (32, 1e4), (64, 100.0), (64, 1e4)],
            neumann_sizes: vec![16, 32, 64],
            naive_max_n: 64,
            x0_n: 32,
            x0_iterations: vec![5, 20, 50],
            unroll_n: 64,
            unroll_steps: vec![1, 2, 4, 8, 16, 32, 64, 128, 256, 512, 1024, 2048],
            cfls: vec![0.5, 1.0, 1.5],
        }
    }

    /// A run of seconds for CI: small grids, every study.
    pub fn quick() -> Self {
        StabilityConfig {
            iteration_n: 12,
            few_iterations: vec![2, 5],
            convergence_multiples: vec![1.0, 2.0, 5.0, 10.0],
            floor_n: 16,
            floor_max_iters: 200,
            floor_stride: 10,
            unconverged_n: 12,
            forward_rtols: vec![1e-1, 1e-2, 1e-4, 1e-6, 1e-8],
            laplacian_sizes: vec![8, 16],
            anisotropic: vec![(12, 1e4)],
            neumann_sizes: vec![8, 12],
            naive_max_n: 16,
            x0_n: 12,
            x0_iterations: vec![5],
            unroll_n: 32,
            unroll_steps: vec![1, 4, 16, 64, 256],
            cfls: vec![0.5, 1.5],
        }
    }

    /// Checks the configuration.
    ///
    /// # Errors
    /// [`CompareError::InvalidArgument`] for a grid below 4 cells, an empty
    /// list, a zero stride or cap, or a non-positive Courant number.
    pub fn validate(&self) -> Result<()> {
        let fail = |m: &str| Err(CompareError::invalid(m.to_string()));
        let sizes = [
            self.iteration_n,
            self.floor_n,
            self.unconverged_n,
            self.x0_n,
            self.unroll_n,
        ];
        if sizes.iter().chain(&self.laplacian_sizes).any(|&n| n < 4) {
            return fail("every grid needs at least 4 cells per axis");
        }
        if self.floor_stride == 0 || self.floor_max_iters == 0 {
            return fail("the floor's stride and cap must be positive");
        }
        if self.unroll_steps.is_empty() || self.cfls.is_empty() || self.forward_rtols.is_empty() {
            return fail("unroll steps, Courant numbers and forward tolerances must be given");
        }
        if self.cfls.iter().any(|c| !(c.is_finite() && *c > 0.0)) {
            return fail("Courant numbers must be finite and positive");
        }
        Ok(())
    }
}

/// One measured run of a CG study: the sweep's row with the study it belongs
/// to and, for singular systems, how much of the gradient lies in the kernel.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StabilityRow {
    /// `iterations`, `floor`, `unconverged`, `conditioning`.
    pub study: String,
    /// The measured run.
    #[serde(flatten)]
    pub row: ResultRow,
    /// For the singular system: `|mean(g)|·√N / ‖g‖`, the share of the gradient
    /// along the constants (0 for the exact and implicit gradients, which are
    /// zero-mean by construction).
    pub null_space_fraction: Option<f64>,
    /// A variant of the method (`adjoint tight` for the unconverged study).
    pub variant: Option<String>,
}

/// Iterations a CG solve of a scene needs to converge ([`converged_rtol`]).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ConvergenceCount {
    /// Cells per axis.
    pub n: usize,
    /// The operator.
    pub operator: String,
    /// `f32` or `f64`.
    pub precision: String,
    /// The relative residual asked for.
    pub rtol: f64,
    /// Iterations the solver of the implicit path needed; `None` if it failed.
    pub iterations: Option<usize>,
    /// The relative residual it reached (above `rtol` where that lies below the
    /// precision's rounding floor); `None` if it failed.
    #[serde(default)]
    pub reached_relative_residual: Option<f64>,
    /// Its error, if it failed.
    pub error: Option<String>,
}

/// The gradient with respect to the CG initial guess, per method.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct InitialGuessRow {
    /// `naive` or `implicit`.
    pub method: String,
    /// Cells per axis.
    pub n: usize,
    /// Fixed iterations, or `None` for a tolerance run.
    pub iterations: Option<usize>,
    /// The tolerance of a tolerance run.
    pub rtol: Option<f64>,
    /// `‖∂L/∂x0‖₂`.
    pub x0_grad_norm: Option<f64>,
    /// `‖∂L/∂b‖₂`, for scale.
    pub b_grad_norm: Option<f64>,
    /// True if every entry of `∂L/∂x0` is exactly zero.
    pub x0_grad_exactly_zero: Option<bool>,
    /// The central difference of the method's own loss along a fixed direction
    /// `d` of `x0`, `(L(x0 + h d) − L(x0 − h d))/2h`: how much the computed loss
    /// really moves with the initial guess.
    pub x0_finite_difference: Option<f64>,
    /// `<∂L/∂x0, d>`, the gradient's prediction of that difference.
    pub x0_directional: Option<f64>,
    /// The error, if the run failed.
    pub error: Option<String>,
}

/// The gradient of a loss after a number of upwind advection steps.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct UnrollRow {
    /// The Courant number `dt·max|u|/dx`.
    pub cfl: f64,
    /// Steps unrolled on the tape.
    pub steps: usize,
    /// `f32` or `f64`.
    pub precision: String,
    /// The loss `½‖d_N − d*‖²`.
    pub loss: Option<f64>,
    /// `‖∂L/∂d⁰‖₂`.
    pub grad_d0_norm: Option<f64>,
    /// `‖∂L/∂u‖₂`.
    pub grad_u_norm: Option<f64>,
    /// True if nothing went non-finite.
    pub finite: bool,
    /// The error, if the run failed (naming the op and the step).
    pub error: Option<String>,
}

/// Everything a stability run measured.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StabilityResults {
    /// The configuration.
    pub config: StabilityConfig,
    /// Convergence counts of the scenes the studies are sized from.
    pub convergence: Vec<ConvergenceCount>,
    /// The CG studies' runs.
    pub rows: Vec<StabilityRow>,
    /// The initial-guess study.
    pub initial_guess: Vec<InitialGuessRow>,
    /// The advection unroll.
    pub unroll: Vec<UnrollRow>,
    /// The floors, as measured.
    pub floors: Vec<Floor>,
    /// One sentence per failure mode, with the figure measured.
    pub findings: Vec<String>,
}

/// `‖a‖₂` in `f64`, scaled by the largest entry so that norms of huge (but
/// finite) gradients do not overflow; infinite if an entry is not finite.
fn norm<T: Real>(a: impl IntoIterator<Item = T> + Clone) -> f64 {
    let scale = a
        .clone()
        .into_iter()
        .fold(0.0_f64, |m, v| m.max(v.as_f64().abs()));
    if scale == 0.0 || !scale.is_finite() {
        return scale;
    }
    scale
        * a.into_iter()
            .map(|v| (v.as_f64() / scale).powi(2))
            .sum::<f64>()
            .sqrt()
}

/// Iterations the solver of the implicit path needs on `problem` to converge:
/// to reach [`converged_rtol`], or, where that lies below the rounding floor of
/// `T` (f32 on 64² and larger), to stall at the floor
/// ([`diffphys_ops::cg::CgInfo::rounding_floor`]): either way the iterate is
/// converged to what `T` resolves.
///
/// # Errors
/// The solver's error, and [`diffphys_ops::cg::CgError::NoConvergence`] if it
/// ran into [`TOLERANCE_CAP`].
pub fn convergence_iterations<T: Real>(problem: &Problem<T>) -> Result<usize> {
    convergence_solve(problem).map(|info| info.iterations)
}

/// The solve behind [`convergence_iterations`].
fn convergence_solve<T: Real>(problem: &Problem<T>) -> Result<CgInfo> {
    let params = CgParams::default()
        .with_rel_tol(converged_rtol::<T>())
        .with_max_iters(TOLERANCE_CAP)
        .with_null_space(problem.spec.operator.null_space())
        .with_require_convergence(false);
    let (_, info) = cg_solve(&problem.operator, problem.b.view().into_dyn(), &params)
        .map_err(OpsError::from)?;
    if info.reached_cap() {
        if let Some(e) = info.failure(T::NAME) {
            return Err(OpsError::from(e).into());
        }
    }
    Ok(info)
}

fn convergence_row<T: Real>(problem: &Problem<T>) -> ConvergenceCount {
    let result = convergence_solve(problem);
    ConvergenceCount {
        n: problem.spec.n,
        operator: problem.spec.operator.label(),
        precision: T::NAME.to_string(),
        rtol: converged_rtol::<T>(),
        iterations: result.as_ref().ok().map(|i| i.iterations),
        reached_relative_residual: result.as_ref().ok().map(|i| i.relative_residual),
        error: result.err().map(|e| e.to_string()),
    }
}

fn stability_row(study: &str, row: ResultRow) -> StabilityRow {
    StabilityRow {
        study: study.to_string(),
        row,
        null_space_fraction: None,
        variant: None,
    }
}

/// The share of `g` along the constants, `|mean(g)|·√N / ‖g‖`.
pub fn null_space_fraction<T: Real>(g: &Array2<T>) -> Option<f64> {
    let n = g.len() as f64;
    let mean = g.iter().map(|v| v.as_f64()).sum::<f64>() / n;
    let total = norm(g.iter().copied());
    (total > 0.0 && total.is_finite()).then(|| mean.abs() * n.sqrt() / total)
}

/// Study 1: both methods at fixed iteration counts, `f32` and `f64`, on one scene.
///
/// # Errors
/// [`CompareError::InvalidArgument`] for a bad grid size; method failures are rows.
pub fn iteration_study<T: Real>(
    spec: ProblemSpec,
    counts: &[usize],
    exact: Option<&Array2<f64>>,
    bar: &ProgressBar,
) -> Result<Vec<StabilityRow>> {
    let problem = Problem::<T>::new(spec)?;
    let mut rows = Vec::new();
    for &k in counts {
        for m in methods::<T>() {
            bar.set_message(format!("iterations: {} {} k={k}", m.name(), T::NAME));
            let (row, _) = measure(m.as_ref(), &problem, Some(Stop::Iterations(k)), None, exact);
            rows.push(stability_row("iterations", row));
            bar.inc(1);
        }
    }
    Ok(rows)
}

fn methods<T: Real>() -> [Box<dyn GradientMethod<T>>; 2] {
    [Box::new(NaiveUnrolled::default()), Box::new(ImplicitSolve)]
}

/// Study 2, the floor: the implicit gradient in `f32` at every `stride`-th
/// fixed iteration cap from `from` to `to`, against the `f64` exact gradient.
///
/// # Errors
/// As [`iteration_study`].
pub fn floor_study(
    n: usize,
    from: usize,
    to: usize,
    stride: usize,
    exact: Option<&Array2<f64>>,
    bar: &ProgressBar,
) -> Result<Vec<StabilityRow>> {
    let problem = Problem::<f32>::new(ProblemSpec::laplacian(n))?;
    let mut caps: Vec<usize> = (from..=to).step_by(stride.max(1)).collect();
    if caps.last() != Some(&to) {
        caps.push(to);
    }
    let mut rows = Vec::with_capacity(caps.len());
    for k in caps {
        bar.set_message(format!("f32 floor: implicit k={k}"));
        let (row, _) = measure(
            &ImplicitSolve,
            &problem,
            Some(Stop::Iterations(k)),
            None,
            exact,
        );
        rows.push(stability_row("floor", row));
        bar.inc(1);
    }
    Ok(rows)
}

/// The floor as measured: the worst error of the floor rows, failing if any is
/// non-finite or failed.
pub fn f32_floor(rows: &[StabilityRow], n: usize, from: usize, to: usize) -> Floor {
    let floor_rows: Vec<&ResultRow> = rows
        .iter()
        .filter(|r| r.study == "floor")
        .map(|r| &r.row)
        .collect();
    let bad: Vec<String> = floor_rows
        .iter()
        .filter(|r| r.error.is_some() || r.grad_rel_err.is_none())
        .map(|r| {
            format!(
                "k={}: {}",
                r.max_iters.unwrap_or(0),
                r.error.as_deref().unwrap_or("non-finite gradient")
            )
        })
        .collect();
    let worst = floor_rows
        .iter()
        .filter_map(|r| r.grad_rel_err.map(|e| (e, r.max_iters.unwrap_or(0))))
        .max_by(|a, b| a.0.total_cmp(&b.0));
    let measured = match (bad.is_empty(), worst) {
        (true, Some((e, _))) => Some(e),
        // A failed or non-finite cap breaks the floor whatever the others did.
        (false, _) => Some(f64::INFINITY),
        (true, None) => None,
    };
    let mut note = format!("{} caps", floor_rows.len());
    if let Some((_, k)) = worst {
        note.push_str(&format!(", worst at k={k}"));
    }
    if !bad.is_empty() {
        note.push_str(&format!(
            "; {} caps failed or went non-finite, first: {}",
            bad.len(),
            bad[0]
        ));
    }
    Floor {
        key: "implicit_f32_floor".into(),
        description: format!(
            "worst implicit f32 gradient error vs f64 exact, {n}², every CG cap {from}..={to}"
        ),
        measured,
        limit: F32_FLOOR_LIMIT,
        at_least: false,
        note,
    }
}

/// Study 3: the implicit gradient with the forward solve stopped at each
/// tolerance (the adjoint tight, and the adjoint stopped alike), and the naive
/// gradient at fixed counts, on one `f64` scene.
///
/// # Errors
/// As [`iteration_study`].
pub fn unconverged_study(
    n: usize,
    rtols: &[f64],
    naive_counts: &[usize],
    exact: Option<&Array2<f64>>,
    bar: &ProgressBar,
) -> Result<Vec<StabilityRow>> {
    let problem = Problem::<f64>::new(ProblemSpec::laplacian(n))?;
    let tight = Stop::Tolerance {
        rtol: 1e-12,
        max_iters: TOLERANCE_CAP,
    };
    let mut rows = Vec::new();
    for &rtol in rtols {
        let stop = Stop::Tolerance {
            rtol,
            max_iters: TOLERANCE_CAP,
        };
        bar.set_message(format!("unconverged: implicit rtol {rtol:e}"));
        let tight_method = ImplicitSeparateAdjoint { adjoint: tight };
        let (row, _) = measure(&tight_method, &problem, Some(stop), None, exact);
        let mut r = stability_row("unconverged", row);
        r.variant = Some("adjoint tight".into());
        rows.push(r);
        let (row, _) = measure(&ImplicitSolve, &problem, Some(stop), None, exact);
        let mut r = stability_row("unconverged", row);
        r.variant = Some("adjoint alike".into());
        rows.push(r);
        bar.inc(2);
    }
    for &k in naive_counts {
        bar.set_message(format!("unconverged: naive k={k}"));
        let (row, _) = measure(
            &NaiveUnrolled::default(),
            &problem,
            Some(Stop::Iterations(k)),
            None,
            exact,
        );
        rows.push(stability_row("unconverged", row));
        bar.inc(1);
    }
    Ok(rows)
}

/// One conditioning scene in precision `T`: implicit and (up to
/// `naive_max_n`) naive to [`converged_rtol`], then, on a singular system, the
/// naive method at five times its convergence count as well.
fn conditioning_scene<T: Real>(
    spec: ProblemSpec,
    naive_max_n: usize,
    exact: Option<&Array2<f64>>,
    bar: &ProgressBar,
    rows: &mut Vec<StabilityRow>,
) -> Result<()> {
    let problem = Problem::<T>::new(spec)?;
    let stop = Stop::Tolerance {
        rtol: converged_rtol::<T>(),
        max_iters: TOLERANCE_CAP,
    };
    let singular = spec.operator.null_space() != diffphys_ops::cg::NullSpace::None;
    let mut push = |m: &dyn GradientMethod<T>, stop: Stop| {
        let (row, out) = measure(m, &problem, Some(stop), None, exact);
        let mut r = stability_row("conditioning", row);
        if singular {
            r.null_space_fraction = out.and_then(|o| null_space_fraction(&o.gradient));
        }
        rows.push(r);
    };
    bar.set_message(format!(
        "conditioning: {} {} n={}",
        spec.operator.label(),
        T::NAME,
        spec.n
    ));
    push(&ImplicitSolve, stop);
    if spec.n <= naive_max_n {
        push(&NaiveUnrolled::default(), stop);
        if singular {
            if let Ok(k) = convergence_iterations(&problem) {
                push(&NaiveUnrolled::default(), Stop::Iterations(5 * k.max(1)));
            }
        }
    }
    bar.inc(1);
    Ok(())
}

/// Study 4: the plain Laplacian at growing sizes, anisotropic operators and the
/// singular all-Neumann system, both precisions.
///
/// # Errors
/// As [`iteration_study`].
pub fn conditioning_study(
    config: &StabilityConfig,
    cache: &mut ExactCache,
    bar: &ProgressBar,
) -> Result<(Vec<StabilityRow>, Vec<ConvergenceCount>)> {
    let mut specs: Vec<ProblemSpec> = config
        .laplacian_sizes
        .iter()
        .map(|&n| ProblemSpec::laplacian(n))
        .collect();
    specs.extend(config.anisotropic.iter().map(|&(n, ratio)| {
        ProblemSpec::laplacian(n).with_operator(OperatorKind::Anisotropic { ratio })
    }));
    specs.extend(
        config
            .neumann_sizes
            .iter()
            .map(|&n| ProblemSpec::laplacian(n).with_operator(OperatorKind::Neumann)),
    );
    let mut rows = Vec::new();
    let mut counts = Vec::new();
    for spec in specs {
        let exact = exact_reference(cache, spec);
        counts.push(convergence_row(&Problem::<f64>::new(spec)?));
        counts.push(convergence_row(&Problem::<f32>::new(spec)?));
        conditioning_scene::<f64>(spec, config.naive_max_n, exact.as_ref(), bar, &mut rows)?;
        conditioning_scene::<f32>(spec, config.naive_max_n, exact.as_ref(), bar, &mut rows)?;
    }
    Ok((rows, counts))
}

/// Study 5: `∂L/∂x0` of both methods, started from a non-zero initial guess, at
/// fixed iteration counts and converged, with a central difference of each
/// method's own loss along a fixed direction of `x0`.
///
/// # Errors
/// As [`iteration_study`].
pub fn initial_guess_study(
    n: usize,
    counts: &[usize],
    bar: &ProgressBar,
) -> Result<Vec<InitialGuessRow>> {
    let problem = Problem::<f64>::new(ProblemSpec::laplacian(n))?;
    let to2 = |a: ndarray::ArrayD<f64>| {
        a.into_dimensionality::<ndarray::Ix2>()
            .map_err(|e| CompareError::invalid(format!("x0 study: {e}")))
    };
    // A rough initial guess of the solution's size, and a direction to perturb it.
    let x0 = to2(diffphys_tape::test_array::<f64>(&[n, n], 0x0b5e))? * 0.05;
    let direction = to2(diffphys_tape::test_array::<f64>(&[n, n], 0xd1ec))?;
    let h = 1e-4;
    let mut stops: Vec<Stop> = counts.iter().map(|&k| Stop::Iterations(k)).collect();
    stops.push(Stop::Tolerance {
        rtol: 1e-10,
        max_iters: TOLERANCE_CAP,
    });
    let mut rows = Vec::new();
    for stop in stops {
        for method in ["naive", "implicit"] {
            bar.set_message(format!("initial guess: {method} {stop:?}"));
            let run = |x: &Array2<f64>| -> Result<(f64, Array2<f64>, Array2<f64>)> {
                if method == "naive" {
                    let (out, g0) = NaiveUnrolled::default().run_from(&problem, stop, Some(x))?;
                    let g0 = g0.ok_or_else(|| CompareError::invalid("naive: no x0 gradient"))?;
                    Ok((out.loss, out.gradient, g0))
                } else {
                    implicit_initial_guess_gradient(&problem, stop, x)
                }
            };
            let mut row = InitialGuessRow {
                method: method.to_string(),
                n,
                iterations: match stop {
                    Stop::Iterations(k) => Some(k),
                    Stop::Tolerance { .. } => None,
                },
                rtol: stop.rtol(),
                x0_grad_norm: None,
                b_grad_norm: None,
                x0_grad_exactly_zero: None,
                x0_finite_difference: None,
                x0_directional: None,
                error: None,
            };
            match run(&x0) {
                Ok((_, gb, g0)) => {
                    row.x0_grad_norm = Some(norm(g0.iter().copied()));
                    row.b_grad_norm = Some(norm(gb.iter().copied()));
                    row.x0_grad_exactly_zero = Some(g0.iter().all(|&v| v == 0.0));
                    row.x0_directional = Some((&g0 * &direction).sum());
                    let plus = run(&(&x0 + &(&direction * h)));
                    let minus = run(&(&x0 - &(&direction * h)));
                    if let (Ok(p), Ok(m)) = (plus, minus) {
                        row.x0_finite_difference = Some((p.0 - m.0) / (2.0 * h));
                    }
                }
                Err(e) => row.error = Some(e.to_string()),
            }
            rows.push(row);
            bar.inc(1);
        }
    }
    Ok(rows)
}

/// Where in an unroll a non-finite gradient began: the latest step whose input
/// received a non-finite gradient (reverse mode visits the last step first),
/// found by sweeping again with the check off.
fn locate_unroll_failure<T: Real>(
    tape: &Tape<T>,
    loss: Var<'_, T>,
    step_inputs: &[Var<'_, T>],
) -> Option<usize> {
    tape.set_check_finite(false);
    let grads = tape.backward(loss, step_inputs);
    tape.set_check_finite(true);
    let grads = grads.ok()?;
    step_inputs.iter().rposition(|&v| {
        grads
            .get(v)
            .is_some_and(|g| g.iter().any(|x| !x.is_finite()))
    })
}

/// The scene of the unroll: `n` periodic cells on `[0, 1)`, the velocity
/// `u = 1 + 0.2 sin 2πx` (so the local Courant number stays within a factor
/// 1.5 of the largest: above 1 everywhere when the largest is 1.5), a Gaussian pulse `d⁰` at `x = 0.3` and the target `d*` at
/// `x = 0.6`; the time step gives Courant number `cfl`.
fn unroll_scene(n: usize, cfl: f64) -> Result<(Grid1, AdvectionParams, [Array1<f64>; 3])> {
    let grid = Grid1::new(n, 1.0 / n as f64, 0.0, Boundary::Periodic)?;
    let x = Array1::from_shape_fn(n, |i| (i as f64 + 0.5) / n as f64);
    let u = x.mapv(|x| 1.0 + 0.2 * (2.0 * std::f64::consts::PI * x).sin());
    let pulse = |c: f64| x.mapv(|x| (-(x - c).powi(2) / 0.005).exp());
    let u_max = u.iter().fold(0.0_f64, |m, v| m.max(v.abs()));
    let mut params = AdvectionParams::new(cfl * grid.dx / u_max);
    // At exactly 1 the computed Courant number may round above 1.
    if cfl >= 1.0 {
        params = params.allowing_cfl_violation();
    }
    Ok((grid, params, [pulse(0.3), u, pulse(0.6)]))
}

/// Study 6, one run: `L = ½‖d_N − d*‖²` after `steps` upwind steps of the
/// [`unroll_scene`], recorded on the tape, and the norms of `∂L/∂d⁰` and `∂L/∂u`.
///
/// # Errors
/// [`CompareError::UnrollStep`] naming the step and the op (a non-finite value
/// in the forward or the backward of `upwind_1d`, or of the loss); setup errors.
pub fn unroll_gradient<T: Real>(n: usize, cfl: f64, steps: usize) -> Result<(f64, f64, f64)> {
    let (grid, params, [d0, u, target]) = unroll_scene(n, cfl)?;
    let tape = Tape::<T>::new();
    let d0 = tape.var(d0.mapv(T::from_f64).into_dyn());
    let u = tape.var(u.mapv(T::from_f64).into_dyn());
    let target = tape.constant(target.mapv(T::from_f64).into_dyn());
    let mut d = d0;
    let mut step_inputs = Vec::with_capacity(steps + 1);
    for step in 0..steps {
        step_inputs.push(d);
        d = upwind_1d_tape(&grid, &params, d, u)
            .map_err(|source| CompareError::UnrollStep { step, source })?;
    }
    step_inputs.push(d);
    let loss = (|| {
        let r = d.sub(target)?;
        r.dot(r)?.mul_scalar(T::from_f64(0.5))
    })()
    .map_err(|e| CompareError::UnrollStep {
        step: steps,
        source: OpsError::Tape(e),
    })?;
    let grads = match tape.backward(loss, &[d0, u]) {
        Ok(g) => g,
        Err(e @ TapeError::NonFinite { .. }) => {
            let step = locate_unroll_failure(&tape, loss, &step_inputs).unwrap_or(steps);
            return Err(CompareError::UnrollStep {
                step,
                source: OpsError::Tape(e),
            });
        }
        Err(e) => return Err(e.into()),
    };
    let g = |v| grads.get(v).map_or(0.0, |a| norm(a.iter().copied()));
    Ok((loss.item()?.as_f64(), g(d0), g(u)))
}

/// Study 6: [`unroll_gradient`] at every step count and Courant number, `f64`
/// and `f32`.
pub fn unroll_study(config: &StabilityConfig, bar: &ProgressBar) -> Vec<UnrollRow> {
    let mut rows = Vec::new();
    for &cfl in &config.cfls {
        for precision in ["f64", "f32"] {
            for &steps in &config.unroll_steps {
                bar.set_message(format!("unroll: CFL {cfl} {precision} N={steps}"));
                let result = if precision == "f64" {
                    unroll_gradient::<f64>(config.unroll_n, cfl, steps)
                } else {
                    unroll_gradient::<f32>(config.unroll_n, cfl, steps)
                };
                let mut row = UnrollRow {
                    cfl,
                    steps,
                    precision: precision.to_string(),
                    loss: None,
                    grad_d0_norm: None,
                    grad_u_norm: None,
                    finite: true,
                    error: None,
                };
                match result {
                    Ok((loss, gd, gu)) => {
                        row.finite = loss.is_finite() && gd.is_finite() && gu.is_finite();
                        row.loss = Some(loss);
                        row.grad_d0_norm = Some(gd);
                        row.grad_u_norm = Some(gu);
                    }
                    Err(e) => {
                        row.finite = !crate::harness::is_non_finite(&e);
                        row.error = Some(e.to_string());
                    }
                }
                rows.push(row);
                bar.inc(1);
            }
        }
    }
    rows
}

/// The fixed iteration counts of study 1: the small counts, then each multiple
/// of the convergence count `k_conv`, sorted and deduplicated.
pub fn iteration_counts(config: &StabilityConfig, k_conv: usize) -> Vec<usize> {
    let mut counts: Vec<usize> = config
        .few_iterations
        .iter()
        .copied()
        .chain(
            config
                .convergence_multiples
                .iter()
                .map(|m| ((m * k_conv as f64).round() as usize).max(1)),
        )
        .collect();
    counts.sort_unstable();
    counts.dedup();
    counts
}

/// Runs every study of `config`.
///
/// # Errors
/// [`CompareError::InvalidArgument`] for an invalid configuration, or if the
/// scenes' convergence counts cannot be measured; method failures are rows.
pub fn run_stability(config: &StabilityConfig) -> Result<StabilityResults> {
    config.validate()?;
    let mut cache = ExactCache::new();
    let mut convergence = Vec::new();

    // Sizes of the studies come from what convergence needs.
    let it_spec = ProblemSpec::laplacian(config.iteration_n);
    let k_conv = convergence_iterations(&Problem::<f64>::new(it_spec)?)?;
    convergence.push(convergence_row(&Problem::<f64>::new(it_spec)?));
    convergence.push(convergence_row(&Problem::<f32>::new(it_spec)?));
    let counts = iteration_counts(config, k_conv);
    let floor_spec = ProblemSpec::laplacian(config.floor_n);
    let floor_from = convergence_iterations(&Problem::<f32>::new(floor_spec)?)?;
    convergence.push(convergence_row(&Problem::<f64>::new(floor_spec)?));
    convergence.push(convergence_row(&Problem::<f32>::new(floor_spec)?));
    let floor_to = config.floor_max_iters.max(floor_from);
    let floor_caps = (floor_to - floor_from) / config.floor_stride.max(1) + 2;
    let un_spec = ProblemSpec::laplacian(config.unconverged_n);
    let un_k = convergence_iterations(&Problem::<f64>::new(un_spec)?)?;
    let naive_counts: Vec<usize> = counts.iter().copied().filter(|&k| k <= un_k).collect();

    let conditioning_scenes =
        config.laplacian_sizes.len() + config.anisotropic.len() + config.neumann_sizes.len();
    let total = 4 * counts.len()
        + floor_caps
        + 2 * config.forward_rtols.len()
        + naive_counts.len()
        + 2 * conditioning_scenes
        + 2 * (config.x0_iterations.len() + 1)
        + 2 * config.cfls.len() * config.unroll_steps.len();
    let bar = progress_bar(total, "stability");

    let mut rows = Vec::new();
    let exact = exact_reference(&mut cache, it_spec);
    rows.extend(iteration_study::<f32>(
        it_spec,
        &counts,
        exact.as_ref(),
        &bar,
    )?);
    rows.extend(iteration_study::<f64>(
        it_spec,
        &counts,
        exact.as_ref(),
        &bar,
    )?);

    let exact = exact_reference(&mut cache, floor_spec);
    rows.extend(floor_study(
        config.floor_n,
        floor_from,
        floor_to,
        config.floor_stride,
        exact.as_ref(),
        &bar,
    )?);

    let exact = exact_reference(&mut cache, un_spec);
    rows.extend(unconverged_study(
        config.unconverged_n,
        &config.forward_rtols,
        &naive_counts,
        exact.as_ref(),
        &bar,
    )?);

    let (cond_rows, cond_counts) = conditioning_study(config, &mut cache, &bar)?;
    rows.extend(cond_rows);
    convergence.extend(cond_counts);

    let initial_guess = initial_guess_study(config.x0_n, &config.x0_iterations, &bar)?;
    let unroll = unroll_study(config, &bar);
    bar.finish_and_clear();

    let floors = vec![f32_floor(&rows, config.floor_n, floor_from, floor_to)];
    let mut results = StabilityResults {
        config: config.clone(),
        convergence,
        rows,
        initial_guess,
        unroll,
        floors,
        findings: Vec::new(),
    };
    results.findings = findings(&results);
    Ok(results)
}

fn study<'a>(rows: &'a [StabilityRow], name: &'a str) -> impl Iterator<Item = &'a ResultRow> {
    rows.iter().filter(move |r| r.study == name).map(|r| &r.row)
}

/// The first fixed iteration count at which `method` in `precision` failed or
/// went non-finite in the iteration study, with its error.
pub fn first_failure(
    rows: &[StabilityRow],
    method: &str,
    precision: &str,
) -> Option<(usize, String)> {
    study(rows, "iterations")
        .filter(|r| r.method == method && r.precision == precision)
        .filter(|r| !r.finite || r.error.is_some())
        .filter_map(|r| Some((r.max_iters?, r.error.clone().unwrap_or_default())))
        .min_by_key(|(k, _)| *k)
}

fn worst_error_from(
    rows: &[StabilityRow],
    method: &str,
    precision: &str,
    from: usize,
) -> Option<f64> {
    study(rows, "iterations")
        .filter(|r| r.method == method && r.precision == precision)
        .filter(|r| r.max_iters.is_some_and(|k| k >= from))
        .map(|r| r.grad_rel_err.unwrap_or(f64::INFINITY))
        .reduce(f64::max)
}

fn fmt(v: Option<f64>) -> String {
    v.map_or_else(|| "n/a".to_string(), |v| format!("{v:.2e}"))
}

/// One sentence per failure mode with the figures of this run.
pub fn findings(r: &StabilityResults) -> Vec<String> {
    let mut out = Vec::new();
    let n = r.config.iteration_n;
    let k_conv = r
        .convergence
        .iter()
        .find(|c| c.n == n && c.precision == "f64" && c.operator == "laplacian")
        .and_then(|c| c.iterations)
        .unwrap_or(0);
    for p in ["f32", "f64"] {
        let fail = first_failure(&r.rows, "naive", p);
        out.push(format!(
            "iterations ({n}², {p}): CG converges in {k_conv} iterations (f64 to 1e-10); naive {}; \
             implicit worst error from {k_conv} iterations on: {} (all finite: {})",
            match &fail {
                Some((k, e)) => format!("first fails at {k} iterations: {e}"),
                None => format!(
                    "stays finite, worst error from {k_conv} iterations on {}",
                    fmt(worst_error_from(&r.rows, "naive", p, k_conv))
                ),
            },
            fmt(worst_error_from(&r.rows, "implicit", p, k_conv)),
            study(&r.rows, "iterations")
                .filter(|x| x.method == "implicit" && x.precision == p)
                .all(|x| x.finite && x.error.is_none()),
        ));
    }
    for f in &r.floors {
        out.push(format!(
            "floor: {} = {} (≤ {}: {}; {})",
            f.description,
            fmt(f.measured),
            f.limit,
            match f.holds() {
                Some(true) => "holds",
                Some(false) => "FAILS",
                None => "not measured",
            },
            f.note
        ));
    }
    // Unconverged: ratio of gradient error to forward residual.
    let ratios: Vec<f64> = r
        .rows
        .iter()
        .filter(|x| x.study == "unconverged" && x.variant.as_deref() == Some("adjoint tight"))
        .filter_map(|x| Some(x.row.grad_rel_err? / x.row.reached_relative_residual?))
        .filter(|v| v.is_finite())
        .collect();
    if !ratios.is_empty() {
        let lo = ratios.iter().copied().fold(f64::INFINITY, f64::min);
        let hi = ratios.iter().copied().fold(0.0, f64::max);
        out.push(format!(
            "unconverged forward ({}², f64, adjoint tight): implicit gradient error / forward \
             relative residual between {lo:.2} and {hi:.2} over forward tolerances {:?}",
            r.config.unconverged_n, r.config.forward_rtols
        ));
    }
    for (c, nsf) in r
        .rows
        .iter()
        .filter(|x| x.study == "conditioning" && x.row.operator == "neumann")
        .map(|x| (&x.row, &x.null_space_fraction))
    {
        if c.method == "naive" {
            out.push(format!(
                "singular all-Neumann ({}², {}, naive, {}): {}",
                c.n,
                c.precision,
                match c.rtol {
                    Some(t) => format!("rtol {t:e}"),
                    None => format!("{} fixed iterations", c.max_iters.unwrap_or(0)),
                },
                match (&c.error, c.grad_rel_err) {
                    (Some(e), _) => format!("fails with a typed error: {e}"),
                    (None, Some(e)) => format!(
                        "finite, no drift along the kernel (share of the gradient along the \
                         constants {}); error {e:.2e} vs exact",
                        fmt(*nsf)
                    ),
                    (None, None) => "non-finite gradient".to_string(),
                }
            ));
        }
    }
    for x in &r.initial_guess {
        out.push(format!(
            "initial guess ({}, {}): ‖∂L/∂x0‖ = {} (exactly zero: {}), loss moves by {} per unit \
             of x0 along a fixed direction",
            x.method,
            x.iterations.map_or_else(
                || format!("rtol {:e}", x.rtol.unwrap_or(0.0)),
                |k| format!("{k} iterations")
            ),
            fmt(x.x0_grad_norm),
            x.x0_grad_exactly_zero
                .map_or("n/a", |z| if z { "yes" } else { "no" }),
            fmt(x.x0_finite_difference),
        ));
    }
    for &cfl in &r.config.cfls {
        for p in ["f64", "f32"] {
            let rows: Vec<&UnrollRow> = r
                .unroll
                .iter()
                .filter(|u| u.cfl == cfl && u.precision == p)
                .collect();
            let last_finite = rows.iter().rev().find(|u| u.error.is_none());
            let first_fail = rows.iter().find(|u| u.error.is_some());
            out.push(format!(
                "unroll (CFL {cfl}, {p}): ‖∂L/∂d⁰‖ {} at N=1, {} at N={}{}",
                fmt(rows.first().and_then(|u| u.grad_d0_norm)),
                fmt(last_finite.and_then(|u| u.grad_d0_norm)),
                last_finite.map_or(0, |u| u.steps),
                first_fail.map_or_else(String::new, |u| format!(
                    "; N={} fails: {}",
                    u.steps,
                    u.error.as_deref().unwrap_or("")
                ))
            ));
        }
    }
    out
}

/// The rows of the CG studies, for the table and `report.md`.
pub fn result_rows(results: &StabilityResults, study_name: &str) -> Vec<ResultRow> {
    results
        .rows
        .iter()
        .filter(|r| r.study == study_name)
        .map(|r| {
            let mut row = r.row.clone();
            if let Some(v) = &r.variant {
                row.method = format!("{} ({v})", row.method);
            }
            row
        })
        .collect()
}

/// Draws the stability charts into `out_dir`; returns the charts drawn (file,
/// caption) and notes on those that could not be.
pub fn write_stability_charts(
    out_dir: &Path,
    results: &StabilityResults,
) -> (Vec<(String, String)>, Vec<String>) {
    let mut charts = Vec::new();
    let mut notes = Vec::new();
    let n = results.config.iteration_n;

    let caption = format!(
        "Stability: gradient error vs fixed CG iterations ({n}², laplacian; × = non-finite)"
    );
    let series = series_by_method(study(&results.rows, "iterations"), |r| {
        let shown = if r.finite && r.error.is_none() {
            r.grad_rel_err?
        } else {
            f64::NAN
        };
        Some((r.max_iters? as f64, shown))
    });
    write_chart(
        out_dir,
        "stability_iterations.svg",
        &caption,
        LineChart {
            title: &caption,
            x_label: "CG iterations",
            y_label: "relative gradient error vs f64 exact",
            log_x: true,
            log_y: true,
            series: &series,
        },
        &mut charts,
        &mut notes,
    );

    let caption = format!(
        "Gradient error vs forward relative residual ({}², f64)",
        results.config.unconverged_n
    );
    let mut series = Vec::new();
    for variant in ["adjoint tight", "adjoint alike"] {
        let pts = results
            .rows
            .iter()
            .filter(|r| r.study == "unconverged" && r.variant.as_deref() == Some(variant))
            .filter_map(|r| Some((r.row.reached_relative_residual?, r.row.grad_rel_err?)))
            .collect();
        series.push(Series::new(format!("implicit, {variant}"), sorted(pts)));
    }
    let pts = study(&results.rows, "unconverged")
        .filter(|r| r.method == "naive")
        .filter_map(|r| Some((r.reached_relative_residual?, r.grad_rel_err?)))
        .collect();
    series.push(Series::new("naive (fixed iterations)", sorted(pts)));
    series.push(Series::new(
        "error = residual",
        vec![(1e-12, 1e-12), (1.0, 1.0)],
    ));
    write_chart(
        out_dir,
        "stability_residual.svg",
        &caption,
        LineChart {
            title: &caption,
            x_label: "forward relative residual ‖b − A p‖/‖b‖",
            y_label: "relative gradient error vs exact",
            log_x: true,
            log_y: true,
            series: &series,
        },
        &mut charts,
        &mut notes,
    );

    let floor_n = results.config.floor_n;
    let caption = format!("f32 floor: implicit f32 gradient error vs CG cap ({floor_n}²)");
    let pts: Vec<(f64, f64)> = study(&results.rows, "floor")
        .filter_map(|r| {
            let e = if r.finite && r.error.is_none() {
                r.grad_rel_err?
            } else {
                f64::NAN
            };
            Some((r.max_iters? as f64, e))
        })
        .collect();
    let (lo, hi) = pts.iter().fold((f64::INFINITY, 0.0_f64), |(lo, hi), p| {
        (lo.min(p.0), hi.max(p.0))
    });
    let series = vec![
        Series::new("implicit f32", pts),
        Series::new(
            "floor 1e-4",
            vec![(lo, F32_FLOOR_LIMIT), (hi, F32_FLOOR_LIMIT)],
        ),
    ];
    write_chart(
        out_dir,
        "stability_floor.svg",
        &caption,
        LineChart {
            title: &caption,
            x_label: "fixed CG iterations (forward and adjoint)",
            y_label: "relative gradient error vs f64 exact",
            log_x: false,
            log_y: true,
            series: &series,
        },
        &mut charts,
        &mut notes,
    );

    let caption = format!(
        "Gradient norm vs upwind advection steps ({} periodic cells; × = non-finite)",
        results.config.unroll_n
    );
    let mut series = Vec::new();
    for &cfl in &results.config.cfls {
        for p in ["f64", "f32"] {
            let pts = results
                .unroll
                .iter()
                .filter(|u| u.cfl == cfl && u.precision == p)
                .map(|u| (u.steps as f64, u.grad_d0_norm.unwrap_or(f64::NAN)))
                .collect();
            series.push(Series::new(format!("‖∂L/∂d⁰‖ CFL {cfl} {p}"), pts));
        }
    }
    write_chart(
        out_dir,
        "stability_unroll.svg",
        &caption,
        LineChart {
            title: &caption,
            x_label: "advection steps N",
            y_label: "‖∂L/∂d⁰‖₂",
            log_x: true,
            log_y: true,
            series: &series,
        },
        &mut charts,
        &mut notes,
    );

    let caption = "Conditioning: CG iterations to convergence vs grid size".to_string();
    let mut series = Vec::new();
    for p in ["f64", "f32"] {
        for op in ["laplacian", "neumann"] {
            let pts = results
                .convergence
                .iter()
                .filter(|c| c.precision == p && c.operator == op)
                .filter_map(|c| Some((c.n as f64, c.iterations? as f64)))
                .collect();
            series.push(Series::new(format!("{op} {p}"), sorted(pts)));
        }
    }
    write_chart(
        out_dir,
        "stability_conditioning.svg",
        &caption,
        LineChart {
            title: &caption,
            x_label: "grid size n (n × n cells)",
            y_label: "CG iterations (f64 to 1e-10, f32 to 1e-5)",
            log_x: true,
            log_y: true,
            series: &series,
        },
        &mut charts,
        &mut notes,
    );
    (charts, notes)
}

fn sorted(mut pts: Vec<(f64, f64)>) -> Vec<(f64, f64)> {
    pts.sort_by(|a, b| a.0.total_cmp(&b.0));
    pts.dedup_by(|a, b| a.0 == b.0);
    pts
}

/// Writes `stability.json`: the whole [`StabilityResults`].
///
/// # Errors
/// [`CompareError::Json`] or [`CompareError::Io`].
pub fn write_stability_json(path: &Path, results: &StabilityResults) -> Result<()> {
    let text = serde_json::to_string_pretty(results)?;
    std::fs::write(path, text + "\n").map_err(|e| CompareError::io(path, e))
}

const STUDIES: [(&str, &str); 4] = [
    ("iterations", "Precision and iteration counts"),
    ("unconverged", "Forward solve stopped before convergence"),
    ("conditioning", "Conditioning"),
    ("floor", "The f32 floor"),
];

/// Most rows a study's table in `stability.md` shows (the f32 floor study has
/// one run per iteration cap, hundreds of them).
const MAX_TABLE_ROWS: usize = 100;

/// At most about `max` of `rows`, evenly spaced, always keeping the row of the
/// largest gradient error and every row that failed or went non-finite.
fn table_sample(rows: &[ResultRow], max: usize) -> Vec<ResultRow> {
    if rows.len() <= max {
        return rows.to_vec();
    }
    let stride = rows.len().div_ceil(max);
    let worst = rows
        .iter()
        .enumerate()
        .filter_map(|(i, r)| r.grad_rel_err.filter(|e| e.is_finite()).map(|e| (i, e)))
        .max_by(|a, b| a.1.total_cmp(&b.1))
        .map(|(i, _)| i);
    rows.iter()
        .enumerate()
        .filter(|(i, r)| {
            i % stride == 0
                || *i + 1 == rows.len()
                || Some(*i) == worst
                || r.error.is_some()
                || !r.finite
        })
        .map(|(_, r)| r.clone())
        .collect()
}

/// `stability.md`: configuration, floors, findings, charts, and a table per
/// study (the sweep's [`crate::report::render_report`] for the CG studies).
pub fn render_stability_md(
    results: &StabilityResults,
    configuration: Vec<String>,
    charts: Vec<(String, String)>,
    notes: Vec<String>,
) -> String {
    use std::fmt::Write as _;
    let all: Vec<ResultRow> = STUDIES
        .iter()
        .flat_map(|(s, _)| result_rows(results, s))
        .collect();
    let mut report_notes = results.findings.clone();
    report_notes.extend(notes);
    let head = crate::report::render_report(&crate::report::Report {
        title: "diffphys-compare stability: where gradient methods fail",
        configuration,
        rows: &[],
        floors: &results.floors,
        charts,
        notes: report_notes,
    });
    let mut out = head;
    let _ = writeln!(out, "\n## Studies\n\n{} CG runs in all.\n", all.len());
    for (key, title) in STUDIES {
        let rows = result_rows(results, key);
        let _ = writeln!(out, "### {title}\n");
        let shown = table_sample(&rows, MAX_TABLE_ROWS);
        if shown.len() < rows.len() {
            let _ = writeln!(
                out,
                "{} of {} runs: evenly spaced, plus the worst error and every failure; \
                 all of them are in `stability.json` and the chart.\n",
                shown.len(),
                rows.len()
            );
        }
        out.push_str(&crate::report::markdown_table(&shown));
        out.push('\n');
    }
    out.push_str("### Gradient with respect to the initial guess x0\n\n");
    out.push_str("| method | iterations | ‖∂L/∂x0‖ | exactly zero | FD of loss along d | <∂L/∂x0, d> | ‖∂L/∂b‖ | error |\n|---|---:|---:|---|---:|---:|---:|---|\n");
    for x in &results.initial_guess {
        let _ = writeln!(
            out,
            "| {} | {} | {} | {} | {} | {} | {} | {} |",
            x.method,
            x.iterations.map_or_else(
                || format!("rtol {:e}", x.rtol.unwrap_or(0.0)),
                |k| k.to_string()
            ),
            fmt(x.x0_grad_norm),
            x.x0_grad_exactly_zero
                .map_or("-", |z| if z { "yes" } else { "no" }),
            fmt(x.x0_finite_difference),
            fmt(x.x0_directional),
            fmt(x.b_grad_norm),
            x.error.as_deref().unwrap_or("")
        );
    }
    out.push_str("\n### Long unrolls: upwind advection\n\n");
    out.push_str(&unroll_table(&results.unroll, true));
    out
}

/// The unroll rows as a table (Markdown or plain text).
pub fn unroll_table(rows: &[UnrollRow], markdown: bool) -> String {
    use std::fmt::Write as _;
    let mut out = String::new();
    if markdown {
        out.push_str("| CFL | prec | steps | loss | ‖∂L/∂d⁰‖ | ‖∂L/∂u‖ | finite | error |\n|---:|---|---:|---:|---:|---:|---|---|\n");
    } else {
        let _ = writeln!(
            out,
            "{:>5}  {:<4}  {:>6}  {:>10}  {:>10}  {:>10}  {:<6}  error",
            "CFL", "prec", "steps", "loss", "|dL/dd0|", "|dL/du|", "finite"
        );
    }
    for u in rows {
        let cells = [
            format!("{}", u.cfl),
            u.precision.clone(),
            u.steps.to_string(),
            fmt(u.loss),
            fmt(u.grad_d0_norm),
            fmt(u.grad_u_norm),
            if u.finite { "yes" } else { "NO" }.to_string(),
            u.error.clone().unwrap_or_default(),
        ];
        if markdown {
            let _ = writeln!(
                out,
                "| {} |",
                cells.map(|c| c.replace('|', "\\|")).join(" | ")
            );
        } else {
            let _ = writeln!(
                out,
                "{:>5}  {:<4}  {:>6}  {:>10}  {:>10}  {:>10}  {:<6}  {}",
                cells[0], cells[1], cells[2], cells[3], cells[4], cells[5], cells[6], cells[7]
            );
        }
    }
    out
}

/// The key figures of a stability run as one JSON object: the sweep's counts
/// and floors ([`crate::report::key_figures_value`]) plus each failure mode's
/// headline figure.
pub fn stability_key_figures(
    results: &StabilityResults,
    out_dir: &Path,
    elapsed_s: f64,
) -> serde_json::Value {
    let rows: Vec<ResultRow> = results.rows.iter().map(|r| r.row.clone()).collect();
    let mut v = crate::report::key_figures_value(&rows, &results.floors, out_dir, elapsed_s);
    let first = |m: &str, p: &str| first_failure(&results.rows, m, p).map(|(k, _)| k);
    let x0 = |m: &str| {
        results
            .initial_guess
            .iter()
            .filter(|x| x.method == m)
            .filter_map(|x| x.x0_grad_norm)
            .fold(None, |acc: Option<f64>, v| {
                Some(acc.map_or(v, |a| a.max(v)))
            })
    };
    let unroll_fail = |cfl: f64, p: &str| {
        results
            .unroll
            .iter()
            .find(|u| u.cfl == cfl && u.precision == p && u.error.is_some())
            .map(|u| u.steps)
    };
    let unroll_last = |cfl: f64| {
        results
            .unroll
            .iter()
            .filter(|u| u.cfl == cfl && u.precision == "f64")
            .filter_map(|u| u.grad_d0_norm)
            .next_back()
    };
    let ratios: Vec<f64> = results
        .rows
        .iter()
        .filter(|x| x.study == "unconverged" && x.variant.as_deref() == Some("adjoint tight"))
        .filter_map(|x| Some(x.row.grad_rel_err? / x.row.reached_relative_residual?))
        .collect();
    if let Some(o) = v.as_object_mut() {
        o.insert("mode".into(), "stability".into());
        o.insert("ok".into(), true.into());
        o.insert(
            "naive_first_non_finite_iters".into(),
            serde_json::json!({ "f32": first("naive", "f32"), "f64": first("naive", "f64") }),
        );
        o.insert(
            "implicit_first_non_finite_iters".into(),
            serde_json::json!({ "f32": first("implicit", "f32"), "f64": first("implicit", "f64") }),
        );
        o.insert(
            "x0_grad_norm_max".into(),
            serde_json::json!({ "implicit": x0("implicit"), "naive": x0("naive") }),
        );
        o.insert(
            "unconverged_err_over_residual".into(),
            serde_json::json!({
                "min": ratios.iter().copied().reduce(f64::min),
                "max": ratios.iter().copied().reduce(f64::max),
            }),
        );
        let mut unroll = serde_json::Map::new();
        for &cfl in &results.config.cfls {
            unroll.insert(
                format!("cfl_{cfl}"),
                serde_json::json!({
                    "grad_d0_norm_last_f64": unroll_last(cfl),
                    "first_failing_steps_f64": unroll_fail(cfl, "f64"),
                    "first_failing_steps_f32": unroll_fail(cfl, "f32"),
                }),
            );
        }
        o.insert("unroll".into(), unroll.into());
    }
    v
}
