//! Where gradient methods fail: the studies of `diffphys-compare stability`.
//!
//! Each study provokes one failure mode and measures its outcome with the same
//! methods ([`NaiveUnrolled`], [`ImplicitSolve`], [`ExactCholesky`](crate::methods::exact::ExactCholesky)) and the same
//! measurement ([`measure`](crate::harness::measure), [`crate::harness::relative_error`]) as the main sweep:
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

use diffphys_ops::cg::{cg_solve, CgInfo, CgParams};
use diffphys_ops::OpsError;
use diffphys_tape::Real;
use ndarray::Array2;
use serde::{Deserialize, Serialize};

use crate::harness::{exact_reference, ExactCache};
use crate::methods::{implicit::ImplicitSolve, naive::NaiveUnrolled, GradientMethod};
use crate::model::{Floor, Method, Precision, ResultRow};
use crate::problem::{OperatorKind, Problem, ProblemSpec};
use crate::progress::Progress;
use crate::{CompareError, Result};

mod conditioning;
mod findings;
mod initial_guess;
mod iterations;
mod output;
mod unconverged;
mod unroll;

pub use conditioning::conditioning_study;
pub use findings::{findings, first_failure};
pub use initial_guess::initial_guess_study;
pub use iterations::{f32_floor, floor_study, iteration_counts, iteration_study};
pub use output::{
    render_stability_md, result_rows, stability_key_figures, unroll_table, write_stability_charts,
    write_stability_json,
};
pub use unconverged::unconverged_study;
pub use unroll::{unroll_gradient, unroll_study};

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

/// The CG studies of a stability run.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Study {
    /// Precision and fixed iteration counts.
    Iterations,
    /// The f32 rounding floor.
    Floor,
    /// The forward solve stopped before convergence.
    Unconverged,
    /// Conditioning (operators and grid sizes).
    Conditioning,
}

impl Study {
    /// The name in `stability.json`: `iterations`, `floor`, `unconverged`,
    /// `conditioning`.
    pub fn name(self) -> &'static str {
        match self {
            Study::Iterations => "iterations",
            Study::Floor => "floor",
            Study::Unconverged => "unconverged",
            Study::Conditioning => "conditioning",
        }
    }
}

/// One measured run of a CG study: the sweep's row with the study it belongs
/// to and, for singular systems, how much of the gradient lies in the kernel.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StabilityRow {
    /// `iterations`, `floor`, `unconverged`, `conditioning`.
    pub study: Study,
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
    pub operator: OperatorKind,
    /// `f32` or `f64`.
    pub precision: Precision,
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
    pub method: Method,
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
    pub precision: Precision,
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
        operator: problem.spec.operator,
        precision: Precision::of::<T>(),
        rtol: converged_rtol::<T>(),
        iterations: result.as_ref().ok().map(|i| i.iterations),
        reached_relative_residual: result.as_ref().ok().map(|i| i.relative_residual),
        error: result.err().map(|e| e.to_string()),
    }
}

fn stability_row(study: Study, row: ResultRow) -> StabilityRow {
    StabilityRow {
        study,
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

fn methods<T: Real>() -> [Box<dyn GradientMethod<T>>; 2] {
    [Box::new(NaiveUnrolled::default()), Box::new(ImplicitSolve)]
}

/// Runs every study of `config`.
///
/// # Errors
/// [`CompareError::InvalidArgument`] for an invalid configuration, or if the
/// scenes' convergence counts cannot be measured; method failures are rows.
pub fn run_stability(config: &StabilityConfig, bar: &dyn Progress) -> Result<StabilityResults> {
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
    bar.begin(total, "stability");

    let mut rows = Vec::new();
    let exact = exact_reference(&mut cache, it_spec);
    rows.extend(iteration_study::<f32>(
        it_spec,
        &counts,
        exact.as_ref(),
        bar,
    )?);
    rows.extend(iteration_study::<f64>(
        it_spec,
        &counts,
        exact.as_ref(),
        bar,
    )?);

    let exact = exact_reference(&mut cache, floor_spec);
    rows.extend(floor_study(
        config.floor_n,
        floor_from,
        floor_to,
        config.floor_stride,
        exact.as_ref(),
        bar,
    )?);

    let exact = exact_reference(&mut cache, un_spec);
    rows.extend(unconverged_study(
        config.unconverged_n,
        &config.forward_rtols,
        &naive_counts,
        exact.as_ref(),
        bar,
    )?);

    let (cond_rows, cond_counts) = conditioning_study(config, &mut cache, bar)?;
    rows.extend(cond_rows);
    convergence.extend(cond_counts);

    let initial_guess = initial_guess_study(config.x0_n, &config.x0_iterations, bar)?;
    let unroll = unroll_study(config, bar);
    bar.finish();

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
