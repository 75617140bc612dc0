//! The exact reference gradient: two solves with one sparse Cholesky
//! factorisation of `A` ([`diffphys_ops::reference::SparseCholesky`]), always
//! in `f64`: `p = A⁻¹ b`, then `grad_b = A⁻¹ ∂L/∂p` (`A` symmetric).
//!
//! Its accuracy (about `ε·κ(A)`) does not depend on any iteration count or
//! tolerance, which is what makes it the yardstick of the other methods. For an
//! `f32` problem it solves the `f32` data in `f64` and rounds the gradient to
//! `f32`: the best an `f32` result can be.

use std::time::Instant;

use diffphys_ops::reference::SparseCholesky;
use diffphys_ops::OpsError;
use diffphys_tape::Real;
use ndarray::{Array2, Ix2};

use super::{relative_residual, GradientMethod, RunOutcome, Stop};
use crate::model::Method;
use crate::problem::Problem;
use crate::{CompareError, Result};

/// Sparse Cholesky in `f64`; ignores the stopping rule.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ExactCholesky;

fn to_2d(a: ndarray::ArrayD<f64>) -> Result<Array2<f64>> {
    a.into_dimensionality::<Ix2>()
        .map_err(|e| CompareError::invalid(format!("exact: shape: {e}")))
}

impl<T: Real> GradientMethod<T> for ExactCholesky {
    fn method(&self) -> Method {
        Method::Exact
    }

    fn run(&self, problem: &Problem<T>, _stop: Stop) -> Result<RunOutcome<T>> {
        let start = Instant::now();
        // A singular (all-Neumann) operator: the zero-mean solution and gradient.
        let null_space = problem.spec.operator.null_space();
        let chol = SparseCholesky::new(&problem.operator, null_space).map_err(OpsError::from)?;
        let b = problem.b.mapv(|v| v.as_f64());
        let p = to_2d(chol.solve(b.view().into_dyn()).map_err(OpsError::from)?)?;
        let p_t = p.mapv(T::from_f64);
        let loss = problem.loss(&p_t);
        let forward_s = start.elapsed().as_secs_f64();

        let start = Instant::now();
        // ∂L/∂p in f64 from the f64 solution (the target rounded to T is the data).
        let dl_dp = match problem.spec.loss {
            crate::problem::LossKind::Tracking => &p - &problem.target.mapv(|v| v.as_f64()),
            crate::problem::LossKind::Weighted => problem.target.mapv(|v| v.as_f64()),
        };
        let g = to_2d(
            chol.solve(dl_dp.view().into_dyn())
                .map_err(OpsError::from)?,
        )?;
        let backward_s = start.elapsed().as_secs_f64();
        Ok(RunOutcome {
            loss,
            gradient: g.mapv(T::from_f64),
            forward_s,
            backward_s: Some(backward_s),
            tape_bytes: 0,
            iterations: None,
            adjoint_iterations: None,
            forward_residual: Some(relative_residual(problem, &p_t)?),
        })
    }
}
