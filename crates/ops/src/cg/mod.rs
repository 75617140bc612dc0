//! Conjugate gradient for symmetric positive (semi)definite operators: the solver
//! of the forward Poisson solve and of its adjoint.
//!
//! A params / info / error triad over the matrix-free [`LinearOperator`] trait:
//! [`conjugate_gradient`] takes [`CgParams`], returns [`CgInfo`] or a [`CgError`],
//! and knows nothing of the tape.
//!
//! ```
//! use diffphys_ops::cg::{conjugate_gradient, CgParams};
//! use diffphys_ops::dense::DenseOperator;
//! use ndarray::{arr1, arr2};
//!
//! let a = DenseOperator::new(arr2(&[[4.0, 1.0], [1.0, 3.0]]));
//! let b = arr1(&[1.0, 2.0]).into_dyn();
//! let mut x = ndarray::ArrayD::<f64>::zeros(vec![2]); // the initial guess, then the solution
//! let info = conjugate_gradient(&a, b.view(), x.view_mut(), &CgParams::default())?;
//! // A⁻¹ b = (1/11)·[1, 7]; CG is exact after n = 2 steps
//! assert!((x[0] - 1.0 / 11.0).abs() < 1e-12 && (x[1] - 7.0 / 11.0).abs() < 1e-12);
//! assert!(info.iterations <= 2 && info.relative_residual < 1e-8);
//! # Ok::<(), diffphys_ops::cg::CgError>(())
//! ```
//!
//! # Implementation
//!
//! One iteration makes three passes over memory: `q = A p` fused with `<p, q>`
//! ([`LinearOperator::apply_into_dot`]); `r −= α q` fused with `<r, r>` (and the
//! preconditioned residual and the null-space sums); `x += α p` fused with
//! `p = z + β p`. Every dot product accumulates in `f64`: the solver's own
//! over four lanes, the curvature inside the operator's kernel
//! ([`LinearOperator::apply_into_dot`] returns it as `f64`). All vectors
//! are allocated before the first iteration; the loop allocates nothing.
//!
//! The system is solved in normalised form, `A x̂ = b / ‖b‖`, and scaled back,
//! so that `f32` neither overflows nor underflows whatever the magnitude of `b`.
//! When the recurrence residual meets the tolerance, the true residual
//! `b − A x` is recomputed; if it has drifted above the tolerance, CG restarts
//! from it (up to [`CgParams::max_restarts`] times, while restarts still gain at
//! least a factor 2). [`CgInfo`] reports the true residual, and
//! [`CgInfo::converged`] says whether that true residual met the tolerance.
//!
//! A tolerance below the rounding floor of the precision (about `ε·κ(A)`
//! relative) cannot be met: the true residual stalls near the floor while the
//! recurrence keeps falling. Such a solve ends in
//! [`CgError::BelowRoundingFloor`] when convergence is required, and otherwise
//! returns with [`CgInfo::converged`] false and [`CgInfo::rounding_floor`] set;
//! both name the requested tolerance, the reached residual and the estimated
//! floor.
//!
//! # References
//! - M. R. Hestenes and E. Stiefel, *Methods of conjugate gradients for solving
//!   linear systems*, J. Res. Nat. Bur. Standards 49 (1952) 409–436.
//! - J. R. Shewchuk, *An Introduction to the Conjugate Gradient Method Without the
//!   Agonizing Pain*, Carnegie Mellon University, 1994 (preconditioning, §12;
//!   restarting from the true residual, §B2).
//! - E. F. Kaasschieter, *Preconditioned conjugate gradients for solving singular
//!   systems*, J. Comput. Appl. Math. 24 (1988) 265–275 (the null space).

use diffphys_tape::{parallel, Real};
use ndarray::{ArrayD, ArrayViewD, ArrayViewMutD, IxDyn};

use crate::LinearOperator;

mod kernels;
mod params;
mod preconditioner;
mod solver;

pub use crate::linear::NullSpace;
pub use params::{CgError, CgInfo, CgParams};
pub use preconditioner::{
    Identity, Jacobi, Preconditioner, Preconditioning, SharedPreconditioner, Structure,
};
use solver::Solver;

/// Solves `A x = b` for a symmetric positive definite (or, with a
/// [`NullSpace`], semidefinite) operator `A` by (preconditioned) conjugate
/// gradient.
///
/// `x` holds the initial guess on entry (fill it with zeros for none) and the
/// solution on exit; `b` and `x` have the operator's shape and any layout. With a
/// null space the solution is the one orthogonal to it (zero mean).
///
/// # Errors
/// [`CgError::ShapeMismatch`] and [`CgError::InvalidArgument`] before any work
/// (then `x` is untouched); [`CgError::NonFinite`] for NaN or infinity in `b`, in
/// `x`, or in the recurrences; [`CgError::NotPositiveDefinite`] for a
/// non-positive curvature; [`CgError::Breakdown`]; [`CgError::NoConvergence`]
/// when the cap is reached first and [`CgError::BelowRoundingFloor`] when the
/// tolerance lies below the precision's rounding floor (both only with
/// [`CgParams::require_convergence`]; then `x` holds the last iterate).
pub fn conjugate_gradient<T: Real, A: LinearOperator<T> + ?Sized>(
    op: &A,
    b: ArrayViewD<'_, T>,
    mut x: ArrayViewMutD<'_, T>,
    params: &CgParams,
) -> Result<CgInfo, CgError> {
    let shape = validate(op, b.shape(), x.shape(), params)?;
    let n = shape.iter().product();
    // The whole solve on one of the pool's threads: its kernels then split
    // cheaply (see `parallel::on_pool`).
    parallel::on_pool(n, move || {
        if let Some(xs) = x.as_slice_mut() {
            return Solver::new(op, shape, params)?.solve(b, xs);
        }
        let mut buf: Vec<T> = x.iter().copied().collect();
        let result = Solver::new(op, shape, params).and_then(|mut s| s.solve(b, &mut buf));
        for (o, &v) in x.iter_mut().zip(&buf) {
            *o = v;
        }
        result
    })
}

/// [`conjugate_gradient`] from the zero initial guess, returning the solution.
///
/// # Errors
/// As [`conjugate_gradient`].
pub fn cg_solve<T: Real, A: LinearOperator<T> + ?Sized>(
    op: &A,
    b: ArrayViewD<'_, T>,
    params: &CgParams,
) -> Result<(ArrayD<T>, CgInfo), CgError> {
    let mut x = ArrayD::zeros(IxDyn(op.input_shape()));
    let info = conjugate_gradient(op, b, x.view_mut(), params)?;
    Ok((x, info))
}

/// Checks shapes, symmetry and parameters; returns the operator's shape.
fn validate<T: Real, A: LinearOperator<T> + ?Sized>(
    op: &A,
    b: &[usize],
    x: &[usize],
    params: &CgParams,
) -> Result<Vec<usize>, CgError> {
    let shape = op.input_shape().to_vec();
    if op.output_shape() != shape.as_slice() {
        return Err(CgError::invalid(format!(
            "operator {} maps {:?} to {:?}; CG needs a square operator",
            op.name(),
            shape,
            op.output_shape()
        )));
    }
    if !op.is_symmetric() {
        return Err(CgError::invalid(format!(
            "operator {} does not declare itself symmetric (LinearOperator::is_symmetric); \
             CG needs A = Aᵀ",
            op.name()
        )));
    }
    for (what, found) in [("right-hand side b", b), ("solution x", x)] {
        if found != shape.as_slice() {
            return Err(CgError::ShapeMismatch {
                what: what.to_string(),
                expected: shape.clone(),
                found: found.to_vec(),
            });
        }
    }
    let tol_ok = |t: f64| t.is_finite() && t >= 0.0;
    if !tol_ok(params.rel_tol) || !tol_ok(params.abs_tol) {
        return Err(CgError::invalid(format!(
            "tolerances must be finite and non-negative, got rel_tol = {}, abs_tol = {}",
            params.rel_tol, params.abs_tol
        )));
    }
    if let NullSpace::ConstantOn(mask) = &params.null_space {
        if mask.shape() != shape.as_slice() {
            return Err(CgError::ShapeMismatch {
                what: "null-space mask".to_string(),
                expected: shape,
                found: mask.shape().to_vec(),
            });
        }
        if mask.active_count() == 0 {
            return Err(CgError::invalid("null-space mask has no active cell"));
        }
    }
    Ok(shape)
}
