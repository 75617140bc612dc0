//! The naive gradient: conjugate gradient written with tape primitives, every
//! iteration recorded, the gradient by backpropagating through all of them.
//!
//! Each iteration records `A p` (the Laplacian as a tape op), two dot products,
//! two divisions and three scaled additions; the tape keeps every one of their
//! outputs, seven arrays per iteration, so memory grows linearly with the
//! iteration count. The stopping decision reads values (`‖r‖` against the
//! tolerance) and is not itself recorded. The result is the exact derivative of
//! the truncated iteration that was run, not of the solution `A⁻¹ b`.
//!
//! Backpropagating through iterations past convergence divides by the vanishing
//! residual norms (`β = ‖r_{k+1}‖²/‖r_k‖²`, `α = ‖r_k‖²/<p, A p>`); a
//! non-finite value is reported as [`CompareError::NaiveIteration`], naming the
//! op and the iteration.
//!
//! # References
//! M. R. Hestenes and E. Stiefel (1952), the CG recurrence; A. Griewank and
//! A. Walther, *Evaluating Derivatives*, SIAM 2008, ch. 15 (differentiating
//! iterative solvers: the derivative of the iterates converges, but more slowly
//! than the iterates themselves).

use std::sync::Arc;
use std::time::Instant;

use diffphys_ops::cg::NullSpace;
use diffphys_ops::stencil::Laplacian2;
use diffphys_ops::tape_ops::LinearOp;
use diffphys_tape::{Real, Tape, TapeError, Var};
use ndarray::{Array2, Ix2};

use super::{relative_residual, GradientMethod, RunOutcome, Stop};
use crate::model::Method;
use crate::problem::Problem;
use crate::{CompareError, Result};

/// CG unrolled on the tape. `check_finite` (on by default) makes the tape check
/// every op output and gradient for NaN and infinity; off, values are allowed to
/// go non-finite and the outcome shows it (the stability study's view).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct NaiveUnrolled {
    /// Check every recorded value and gradient for NaN and infinity.
    pub check_finite: bool,
}

impl Default for NaiveUnrolled {
    fn default() -> Self {
        NaiveUnrolled { check_finite: true }
    }
}

/// The recorded CG: the solution, the iterations run, and the scalars each
/// iteration created (to locate a non-finite gradient afterwards).
struct Unrolled<'t, T: Real> {
    x: Var<'t, T>,
    iterations: usize,
    per_iteration: Vec<Vec<Var<'t, T>>>,
}

/// Records CG for `A x = b` from `x0` on `b`'s tape. With `project` (a
/// singular operator whose kernel is the constants) every residual is
/// projected onto the range, `Π r = r − mean(r)`, as the solver of the
/// implicit path does: without it, rounding leaks a constant into the
/// residuals that no step can remove, and the backward pass through many
/// iterations amplifies the gradient's constant component without bound.
fn unrolled_cg<'t, T: Real>(
    a: &Arc<Laplacian2>,
    b: Var<'t, T>,
    x0: Var<'t, T>,
    b_norm: f64,
    stop: Stop,
    project: bool,
) -> Result<Unrolled<'t, T>> {
    let at = |iteration: usize| {
        move |source: TapeError| CompareError::NaiveIteration { iteration, source }
    };
    let apply = |v: Var<'t, T>| v.tape().apply(LinearOp::new(Arc::clone(a)), &[v]);
    let range = |v: Var<'t, T>| -> diffphys_tape::Result<Var<'t, T>> {
        if project {
            v.sub(v.mean()?)
        } else {
            Ok(v)
        }
    };
    let setup = || -> diffphys_tape::Result<_> {
        let r = range(b.sub(apply(x0)?)?)?;
        let rr = r.dot(r)?;
        Ok((r, rr))
    };
    let (mut r, mut rr) = setup().map_err(at(0))?;
    let (mut x, mut p) = (x0, r);
    let scale = if b_norm > 0.0 { b_norm } else { 1.0 };
    let mut per_iteration = Vec::new();
    let mut k = 0;
    while k < stop.max_iters() {
        let rr_value = rr.item().map_err(at(k))?.as_f64();
        if let Stop::Tolerance { rtol, .. } = stop {
            if rr_value.sqrt() <= rtol * scale {
                break;
            }
        }
        if rr_value == 0.0 {
            break; // exact solution: a further step would divide 0 by 0
        }
        let step = || -> diffphys_tape::Result<_> {
            let ap = apply(p)?;
            let pap = p.dot(ap)?;
            let alpha = rr.div(pap)?;
            let alpha_p = p.mul(alpha)?;
            let x_next = x.add(alpha_p)?;
            let alpha_ap = ap.mul(alpha)?;
            let r_next = range(r.sub(alpha_ap)?)?;
            let rr_next = r_next.dot(r_next)?;
            let beta = rr_next.div(rr)?;
            let beta_p = p.mul(beta)?;
            let p_next = r_next.add(beta_p)?;
            // The scalars of the iteration mark it: a non-finite gradient
            // reaching any of its arrays reaches them too, and they are cheap
            // to request in a diagnostic sweep.
            let created = vec![pap, alpha, rr_next, beta];
            Ok((x_next, r_next, rr_next, p_next, created))
        };
        let (x_next, r_next, rr_next, p_next, created) = step().map_err(at(k))?;
        (x, r, rr, p) = (x_next, r_next, rr_next, p_next);
        per_iteration.push(created);
        k += 1;
    }
    Ok(Unrolled {
        x,
        iterations: k,
        per_iteration,
    })
}

/// After a backward failed on a non-finite gradient: the latest iteration whose
/// scalars (`<p, A p>`, `α`, `‖r‖²`, `β`) received a non-finite gradient, found
/// by sweeping again with the check off. Reverse mode visits the last iteration
/// first, so that is where the failure began.
fn locate_non_finite<T: Real>(
    tape: &Tape<T>,
    loss: Var<'_, T>,
    per_iteration: &[Vec<Var<'_, T>>],
) -> Option<usize> {
    let was = tape.checks_finite();
    tape.set_check_finite(false);
    let wrt: Vec<Var<'_, T>> = per_iteration.iter().flatten().copied().collect();
    let grads = tape.backward(loss, &wrt);
    tape.set_check_finite(was);
    let grads = grads.ok()?;
    per_iteration.iter().rposition(|vars| {
        vars.iter().any(|&v| {
            grads
                .get(v)
                .is_some_and(|g| g.iter().any(|x| !x.is_finite()))
        })
    })
}

impl<T: Real> GradientMethod<T> for NaiveUnrolled {
    fn method(&self) -> Method {
        Method::Naive
    }

    fn run(&self, problem: &Problem<T>, stop: Stop) -> Result<RunOutcome<T>> {
        self.run_from(problem, stop, None).map(|(out, _)| out)
    }
}

impl NaiveUnrolled {
    /// Runs from the initial guess `x0` (zeros if `None`); with an `x0` it is a
    /// variable of the tape and its gradient is returned too: the derivative of
    /// the truncated iteration with respect to where it started, which decays
    /// with the iterations but is not zero.
    ///
    /// # Errors
    /// As [`GradientMethod::run`]; [`CompareError::InvalidArgument`] for an `x0`
    /// of the wrong shape.
    pub fn run_from<T: Real>(
        &self,
        problem: &Problem<T>,
        stop: Stop,
        x0: Option<&Array2<T>>,
    ) -> Result<(RunOutcome<T>, Option<Array2<T>>)> {
        if let Some(x0) = x0 {
            if x0.dim() != problem.b.dim() {
                return Err(CompareError::invalid(format!(
                    "naive: initial guess of shape {:?}, b has {:?}",
                    x0.dim(),
                    problem.b.dim()
                )));
            }
        }
        let tape = Tape::<T>::new();
        tape.set_check_finite(self.check_finite);
        let a = Arc::new(problem.operator.clone());
        let b_norm = problem
            .b
            .iter()
            .map(|v| v.as_f64().powi(2))
            .sum::<f64>()
            .sqrt();

        let start = Instant::now();
        let b = tape.var(problem.b.clone().into_dyn());
        let x0 = match x0 {
            Some(x0) => tape.var(x0.clone().into_dyn()),
            None => tape.constant(Array2::<T>::zeros(problem.b.raw_dim()).into_dyn()),
        };
        let project = problem.spec.operator.null_space() != NullSpace::None;
        let cg = unrolled_cg(&a, b, x0, b_norm, stop, project)?;
        let last = cg.iterations;
        let loss = problem
            .recorded_loss(cg.x)
            .map_err(|source| CompareError::NaiveIteration {
                iteration: last,
                source,
            })?;
        let loss_value = loss.item()?.as_f64();
        let forward_s = start.elapsed().as_secs_f64();

        let start = Instant::now();
        let wrt: Vec<Var<'_, T>> = if x0.requires_grad() {
            vec![b, x0]
        } else {
            vec![b]
        };
        let grads = match tape.backward(loss, &wrt) {
            Ok(g) => g,
            Err(source @ TapeError::NonFinite { .. }) => {
                let iteration = locate_non_finite(&tape, loss, &cg.per_iteration).unwrap_or(last);
                return Err(CompareError::NaiveIteration { iteration, source });
            }
            Err(e) => return Err(e.into()),
        };
        let backward_s = start.elapsed().as_secs_f64();

        let grad_of = |v: Var<'_, T>, what: &str| -> Result<Array2<T>> {
            grads
                .get(v)
                .cloned()
                .ok_or_else(|| CompareError::invalid(format!("naive: no gradient for {what}")))?
                .into_dimensionality::<Ix2>()
                .map_err(|e| CompareError::invalid(format!("naive: gradient shape: {e}")))
        };
        let gradient = grad_of(b, "b")?;
        let x0_gradient = if !x0.requires_grad() {
            None
        } else {
            Some(grad_of(x0, "x0")?)
        };
        let solution =
            cg.x.to_array()
                .into_dimensionality::<Ix2>()
                .map_err(|e| CompareError::invalid(format!("naive: solution shape: {e}")))?;
        let outcome = RunOutcome {
            loss: loss_value,
            gradient,
            forward_s,
            backward_s: Some(backward_s),
            tape_bytes: tape.stats().peak_bytes,
            iterations: Some(cg.iterations),
            adjoint_iterations: None,
            forward_residual: Some(relative_residual(problem, &solution)?),
        };
        Ok((outcome, x0_gradient))
    }
}
