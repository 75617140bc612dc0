//! The ways of getting `∂L/∂b` through the Poisson solve, behind one trait.
//!
//! Each method runs the whole gradient computation of a [`Problem`] (forward solve,
//! loss, backward) and reports its own timings; the harness wraps it with the heap
//! measurement and the comparison against the exact gradient.

pub mod baseline;
pub mod exact;
pub mod implicit;
pub mod mgpcg;
pub mod naive;

use diffphys_tape::Real;
use ndarray::Array2;
use serde::{Deserialize, Serialize};

use crate::model::Method;
use crate::problem::Problem;
use crate::Result;

/// When an iterative forward solve stops.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub enum Stop {
    /// Exactly this many CG iterations (fewer only if the residual is exactly zero).
    Iterations(usize),
    /// At relative residual `‖b − A x‖ ≤ rtol·‖b‖`, giving up after `max_iters`.
    Tolerance {
        /// The relative residual to reach.
        rtol: f64,
        /// The iteration cap.
        max_iters: usize,
    },
}

impl Stop {
    /// The relative tolerance, if any.
    pub fn rtol(&self) -> Option<f64> {
        match *self {
            Stop::Iterations(_) => None,
            Stop::Tolerance { rtol, .. } => Some(rtol),
        }
    }

    /// The most iterations the solve may take.
    pub fn max_iters(&self) -> usize {
        match *self {
            Stop::Iterations(k) => k,
            Stop::Tolerance { max_iters, .. } => max_iters,
        }
    }
}

/// What one gradient computation produced and cost.
#[derive(Debug, Clone)]
pub struct RunOutcome<T: Real> {
    /// The loss at the computed solution.
    pub loss: f64,
    /// `∂L/∂b`.
    pub gradient: Array2<T>,
    /// Seconds for the forward solve and the loss.
    pub forward_s: f64,
    /// Seconds for the gradient once the loss is known (`None` for a method that
    /// has no separate backward).
    pub backward_s: Option<f64>,
    /// Peak bytes held by the tape (0 for methods that use no tape).
    pub tape_bytes: usize,
    /// CG iterations of the forward solve (`None` for a direct solve).
    pub iterations: Option<usize>,
    /// CG iterations of the adjoint solve, if there is one.
    pub adjoint_iterations: Option<usize>,
    /// Relative residual `‖b − A p‖/‖b‖` of the forward solution, in `f64`.
    pub forward_residual: Option<f64>,
}

/// A way of computing `∂L/∂b` for a [`Problem`] in precision `T`.
pub trait GradientMethod<T: Real> {
    /// The method, as results name it.
    fn method(&self) -> Method;

    /// The method's name in results: `naive`, `implicit`, `exact`.
    fn name(&self) -> &'static str {
        self.method().name()
    }

    /// Computes the loss and its gradient, stopping iterative solves by `stop`
    /// (a direct method ignores it).
    ///
    /// # Errors
    /// Whatever the method fails with: a solver that does not converge, a
    /// non-finite value (naming the op and, for naive CG, the iteration), …
    fn run(&self, problem: &Problem<T>, stop: Stop) -> Result<RunOutcome<T>>;
}

/// The gradient method `method` names, with its default settings, in
/// precision `T`; `None` for [`Method::BaselineCg`] (forward only) and
/// [`Method::Setup`].
pub fn gradient_method<T: Real>(method: Method) -> Option<Box<dyn GradientMethod<T>>> {
    Some(match method {
        Method::Naive => Box::new(naive::NaiveUnrolled::default()),
        Method::Implicit => Box::new(implicit::ImplicitSolve),
        Method::ImplicitMgpcg => Box::new(mgpcg::ImplicitMgpcg::default()),
        Method::Exact => Box::new(exact::ExactCholesky),
        Method::BaselineCg | Method::Setup => return None,
    })
}

/// `‖b − A x‖ / ‖b‖` in `f64` (`‖b − A x‖` if `b = 0`).
pub fn relative_residual<T: Real>(problem: &Problem<T>, x: &Array2<T>) -> Result<f64> {
    use diffphys_ops::LinearOperator;
    let ax = problem.operator.apply(x.view().into_dyn())?;
    let (mut num, mut den) = (0.0, 0.0);
    for (&a, &b) in ax.iter().zip(&problem.b) {
        num += (b.as_f64() - a.as_f64()).powi(2);
        den += b.as_f64().powi(2);
    }
    Ok(if den > 0.0 {
        (num / den).sqrt()
    } else {
        num.sqrt()
    })
}
