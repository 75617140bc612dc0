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

use diffphys_ops::cg::CgParams;
use diffphys_ops::poisson::{poisson_solve_tape, PoissonSolve};
use diffphys_tape::{Real, Tape};
use ndarray::Ix2;

use super::naive::recorded_loss;
use super::{relative_residual, GradientMethod, RunOutcome, Stop};
use crate::problem::Problem;
use crate::{CompareError, Result};

/// The CG parameters of a stopping rule: a fixed count runs exactly that many
/// iterations without error at the cap; a tolerance must be met within the cap.
pub fn cg_params(stop: Stop) -> CgParams {
    match stop {
        Stop::Iterations(k) => CgParams::default().fixed_iterations(k),
        Stop::Tolerance { rtol, max_iters } => CgParams::default()
            .with_rel_tol(rtol)
            .with_max_iters(max_iters),
    }
}

/// The Poisson op with its implicit adjoint; forward and adjoint solves use the
/// same stopping rule.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ImplicitSolve;

impl<T: Real> GradientMethod<T> for ImplicitSolve {
    fn name(&self) -> &'static str {
        "implicit"
    }

    fn run(&self, problem: &Problem<T>, stop: Stop) -> Result<RunOutcome<T>> {
        let tape = Tape::<T>::new();
        let solve = PoissonSolve::new(Arc::new(problem.operator.clone()), cg_params(stop));
        let log = solve.log();

        let start = Instant::now();
        let b = tape.var(problem.b.clone().into_dyn());
        let p = poisson_solve_tape(solve, b)?;
        let loss = recorded_loss(problem, p)?;
        let loss_value = loss.item()?.as_f64();
        let forward_s = start.elapsed().as_secs_f64();

        let start = Instant::now();
        let grads = tape.backward(loss, &[b])?;
        let backward_s = start.elapsed().as_secs_f64();

        let gradient = grads
            .get(b)
            .cloned()
            .ok_or_else(|| CompareError::invalid("implicit: no gradient for b"))?
            .into_dimensionality::<Ix2>()
            .map_err(|e| CompareError::invalid(format!("implicit: gradient shape: {e}")))?;
        let solution = p
            .to_array()
            .into_dimensionality::<Ix2>()
            .map_err(|e| CompareError::invalid(format!("implicit: solution shape: {e}")))?;
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
}
