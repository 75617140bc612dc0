//! The implicit gradient: the Poisson solve as one tape op
//! ([`diffphys_ops::poisson::PoissonSolve`]), whose backward is one adjoint CG
//! solve with the same operator, `grad_b = A⁻¹ grad_p` (`A` symmetric).
//!
//! The tape holds `b`, `p` and the loss's few arrays, whatever the iteration
//! count; the gradient is that of the exact solution `A⁻¹ b`, evaluated at the
//! computed `p` and solved to the same tolerance (or the same fixed iteration
//! count) as the forward solve.
//!
//! # References
//! M. B. Giles and N. A. Pierce, *An introduction to the adjoint approach to
//! design*, Flow, Turbulence and Combustion 65 (2000) 393–415.

use std::sync::Arc;
use std::time::Instant;

use diffphys_ops::cg::{conjugate_gradient, CgParams, Preconditioning};
use diffphys_ops::poisson::{poisson_solve_vjp, PoissonSolve, SolveLog};
use diffphys_ops::stencil::Laplacian2;
use diffphys_tape::{ArrayD, ArrayViewD, BackwardArgs, Op, Real, Tape, TapeError};
use ndarray::{Array2, Ix2};

use super::{relative_residual, GradientMethod, RunOutcome, Stop};
use crate::model::Method;
use crate::problem::Problem;
use crate::{CompareError, Result};

/// The CG parameters of a stopping rule: a fixed count runs exactly that many
/// iterations without error at the cap; a tolerance runs until it is met, the
/// cap, or the rounding floor of the precision. Convergence is not required of
/// the solver, so that a tolerance below the floor gives a measured (flagged)
/// solve instead of an error; [`check_solves`] turns a solve that hit the cap
/// into an error.
pub fn cg_params(stop: Stop) -> CgParams {
    match stop {
        Stop::Iterations(k) => CgParams::default().fixed_iterations(k),
        Stop::Tolerance { rtol, max_iters } => CgParams::default()
            .with_rel_tol(rtol)
            .with_max_iters(max_iters)
            .with_require_convergence(false),
    }
}

/// Fails, as CG with [`CgParams::require_convergence`] would, if the last
/// forward or adjoint solve of `log` was a tolerance solve (by `forward`,
/// `adjoint`) that ran into its iteration cap; a solve that stopped at the
/// rounding floor passes (its row reports the residual it reached).
///
/// # Errors
/// [`CompareError::Ops`] holding the [`diffphys_ops::cg::CgError::NoConvergence`].
pub fn check_solves<T: Real>(forward: Stop, adjoint: Stop, log: &SolveLog<T>) -> Result<()> {
    let solves = [(forward, log.last_forward()), (adjoint, log.last_adjoint())];
    for (stop, info) in solves {
        let Some(info) = info.filter(|_| stop.rtol().is_some()) else {
            continue;
        };
        if info.reached_cap() {
            if let Some(e) = info.failure(T::NAME) {
                return Err(CompareError::Ops(e.into()));
            }
        }
    }
    Ok(())
}

/// The Poisson op with its implicit adjoint; forward and adjoint solves use the
/// same stopping rule.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ImplicitSolve;

impl<T: Real> GradientMethod<T> for ImplicitSolve {
    fn method(&self) -> Method {
        Method::Implicit
    }

    fn run(&self, problem: &Problem<T>, stop: Stop) -> Result<RunOutcome<T>> {
        run_implicit(problem, stop, stop)
    }
}

/// The Poisson op with its implicit adjoint, the adjoint solve stopped by its own
/// rule: with a forward solve stopped early and a tight adjoint, the gradient's
/// error is that of the unconverged forward solution alone (the stability study).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ImplicitSeparateAdjoint {
    /// The stopping rule of the adjoint solve.
    pub adjoint: Stop,
}

impl<T: Real> GradientMethod<T> for ImplicitSeparateAdjoint {
    fn method(&self) -> Method {
        Method::Implicit
    }

    fn run(&self, problem: &Problem<T>, stop: Stop) -> Result<RunOutcome<T>> {
        run_implicit(problem, stop, self.adjoint)
    }
}

/// The CG parameters of `stop` for `problem`'s operator (its null space, if
/// singular).
fn problem_params<T: Real>(problem: &Problem<T>, stop: Stop) -> CgParams {
    cg_params(stop).with_null_space(problem.spec.operator.null_space())
}

/// [`ImplicitSolve`] with the forward solve stopped by `forward` and the adjoint
/// solve by `adjoint`.
///
/// # Errors
/// A failed solve (the [`diffphys_ops::cg::CgError`] inside an op error named
/// `poisson_solve`), a non-finite value caught by the tape.
pub fn run_implicit<T: Real>(
    problem: &Problem<T>,
    forward: Stop,
    adjoint: Stop,
) -> Result<RunOutcome<T>> {
    run_implicit_preconditioned(problem, forward, adjoint, Preconditioning::None)
}

/// [`run_implicit`] with `preconditioner` in both the forward and the adjoint
/// CG solve (a symmetric positive definite preconditioner keeps the adjoint
/// solve the same solver).
///
/// # Errors
/// As [`run_implicit`].
pub fn run_implicit_preconditioned<T: Real>(
    problem: &Problem<T>,
    forward: Stop,
    adjoint: Stop,
    preconditioner: Preconditioning,
) -> Result<RunOutcome<T>> {
    let tape = Tape::<T>::new();
    let solve = PoissonSolve::new(
        Arc::new(problem.operator.clone()),
        problem_params(problem, forward).with_preconditioner(preconditioner.clone()),
    )
    .with_adjoint_params(problem_params(problem, adjoint).with_preconditioner(preconditioner));
    let log = solve.log();

    let start = Instant::now();
    let b = tape.var(problem.b.clone().into_dyn());
    let p = tape.apply(solve, &[b])?;
    let loss = problem.recorded_loss(p)?;
    let loss_value = loss.item()?.as_f64();
    let forward_s = start.elapsed().as_secs_f64();

    let start = Instant::now();
    let grads = tape.backward(loss, &[b])?;
    let backward_s = start.elapsed().as_secs_f64();

    let gradient = to_2d(
        grads
            .get(b)
            .cloned()
            .ok_or_else(|| CompareError::invalid("implicit: no gradient for b"))?,
        "gradient",
    )?;
    check_solves(forward, adjoint, &log)?;
    let solution = to_2d(p.to_array(), "solution")?;
    Ok(RunOutcome {
        loss: loss_value,
        gradient,
        forward_s,
        backward_s: Some(backward_s),
        tape_bytes: tape.stats().peak_bytes,
        iterations: log.last_forward().map(|i| i.iterations),
        adjoint_iterations: log.last_adjoint().map(|i| i.iterations),
        forward_residual: Some(relative_residual(problem, &solution)?),
    })
}

fn to_2d<T: Real>(a: ArrayD<T>, what: &str) -> Result<Array2<T>> {
    a.into_dimensionality::<Ix2>()
        .map_err(|e| CompareError::invalid(format!("implicit: {what} shape: {e}")))
}

const WARM_NAME: &str = "poisson_solve_from";

/// `p = A⁻¹ b` by CG started from an initial guess `x0`, as a tape op with
/// inputs `[b, x0]`: the implicit Poisson solve when the initial guess is itself
/// a variable (a warm start computed from parameters, say).
///
/// Forward: CG on `A p = b` from `x0` (the same solver and parameters as
/// [`PoissonSolve`]). Backward, by the implicit function theorem applied to
/// `A p − b = 0`: `grad_b = A⁻¹ grad_p` (one adjoint CG solve,
/// [`poisson_solve_vjp`]) and `grad_x0 = 0`, because the equation that defines
/// `p` does not contain `x0`; the initial guess only decides how many iterations
/// the solver needs, not which solution it converges to.
#[derive(Debug, Clone)]
pub struct PoissonSolveFrom {
    op: Arc<Laplacian2>,
    forward: CgParams,
    adjoint: CgParams,
}

impl<T: Real> Op<T> for PoissonSolveFrom {
    fn name(&self) -> &str {
        WARM_NAME
    }

    fn forward(&mut self, inputs: &[ArrayViewD<'_, T>]) -> diffphys_tape::Result<Vec<ArrayD<T>>> {
        if inputs.len() != 2 {
            return Err(TapeError::Arity {
                op: WARM_NAME.to_string(),
                expected: 2,
                found: inputs.len(),
            });
        }
        let mut x = inputs[1].to_owned();
        conjugate_gradient(&*self.op, inputs[0].view(), x.view_mut(), &self.forward)
            .map_err(|e| TapeError::op(WARM_NAME, e))?;
        Ok(vec![x])
    }

    fn backward(
        &self,
        args: &BackwardArgs<'_, T>,
    ) -> diffphys_tape::Result<Vec<Option<ArrayD<T>>>> {
        let grad_b = if args.needs(0) {
            let (g, _) = poisson_solve_vjp(&*self.op, args.grad_out().view(), &self.adjoint, None)
                .map_err(|e| TapeError::op(WARM_NAME, e))?;
            Some(g)
        } else {
            None
        };
        // ∂p/∂x0 = 0: A p = b holds whatever x0 (see the type's docs).
        let grad_x0 = args
            .needs(1)
            .then(|| ArrayD::zeros(args.input(1).raw_dim()));
        Ok(vec![grad_b, grad_x0])
    }
}

/// The gradients of the loss with respect to `b` and to the initial guess `x0`
/// of the implicit solve started from `x0` ([`PoissonSolveFrom`], stopped by
/// `stop` forward and adjoint), with the loss.
///
/// # Errors
/// As [`run_implicit`].
pub fn implicit_initial_guess_gradient<T: Real>(
    problem: &Problem<T>,
    stop: Stop,
    x0: &Array2<T>,
) -> Result<(f64, Array2<T>, Array2<T>)> {
    let tape = Tape::<T>::new();
    // This op keeps no log to check afterwards: a tolerance must be met.
    let params = problem_params(problem, stop).with_require_convergence(stop.rtol().is_some());
    let op = PoissonSolveFrom {
        op: Arc::new(problem.operator.clone()),
        forward: params.clone(),
        adjoint: params,
    };
    let b = tape.var(problem.b.clone().into_dyn());
    let x0v = tape.var(x0.clone().into_dyn());
    let p = tape.apply(op, &[b, x0v])?;
    let loss = problem.recorded_loss(p)?;
    let grads = tape.backward(loss, &[b, x0v])?;
    let get = |v, what| {
        grads
            .get(v)
            .cloned()
            .ok_or_else(|| CompareError::invalid(format!("implicit: no gradient for {what}")))
            .and_then(|g| to_2d(g, what))
    };
    Ok((loss.item()?.as_f64(), get(b, "b")?, get(x0v, "x0")?))
}
