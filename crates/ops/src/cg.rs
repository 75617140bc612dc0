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

use diffphys_tape::Real;
use ndarray::{ArrayD, ArrayViewD, ArrayViewMutD, IxDyn};
use thiserror::Error;

use crate::linear::wide;
use crate::{CellMask, LinearOperator};

/// The preconditioner `M ≈ A` that CG applies as `z = M⁻¹ r`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[non_exhaustive]
pub enum Preconditioner {
    /// None (`M = I`).
    #[default]
    None,
    /// Jacobi: `M = diag(A)`, from [`LinearOperator::diagonal`].
    Jacobi,
}

/// The null space of a singular symmetric positive semidefinite operator, which
/// CG projects out of the right-hand side, the preconditioned residuals and the
/// solution.
///
/// For an operator with `A k = 0` (all-Neumann or periodic Laplacians: `k` the
/// constants), `A x = b` is solvable only for `b ⟂ k`; CG solves
/// `A x = Π b` with `Π = I − k kᵀ / (kᵀ k)` and returns the solution with
/// `kᵀ x = 0` (for constants, zero mean).
#[derive(Debug, Clone, PartialEq, Eq, Default)]
#[non_exhaustive]
pub enum NullSpace {
    /// `A` is positive definite.
    #[default]
    None,
    /// The constants: the mean is removed.
    Constant,
    /// The constants on the active cells of a mask (zero on the others, where
    /// the operator is typically the identity): the mean over the active cells
    /// is removed from them.
    ConstantOn(CellMask),
}

/// How [`conjugate_gradient`] runs.
///
/// The stopping test is `‖b − A x‖ ≤ max(rel_tol·‖b‖, abs_tol)`, with `b`
/// projected onto the range when a [`NullSpace`] is given.
#[derive(Debug, Clone, PartialEq)]
pub struct CgParams {
    /// Relative tolerance on the residual (default `1e-8`).
    pub rel_tol: f64,
    /// Absolute tolerance on the residual (default `0`).
    pub abs_tol: f64,
    /// Iteration cap; `None` (the default) means twice the number of unknowns
    /// plus 10 (CG is exact after `n` steps in exact arithmetic).
    pub max_iters: Option<usize>,
    /// The preconditioner (default none).
    pub preconditioner: Preconditioner,
    /// The operator's null space (default none: `A` is positive definite).
    pub null_space: NullSpace,
    /// Keep the residual norm of every iteration in [`CgInfo::history`].
    pub record_history: bool,
    /// If true (the default), reaching the cap without meeting the tolerance is
    /// [`CgError::NoConvergence`], and a tolerance below the rounding floor is
    /// [`CgError::BelowRoundingFloor`]; if false both return the last iterate
    /// with [`CgInfo::converged`] false (and [`CgInfo::rounding_floor`] set for
    /// the floor), for fixed iteration counts and measurements.
    pub require_convergence: bool,
    /// Restarts from the recomputed residual allowed when the recurrence has
    /// drifted from the true residual (default 1).
    pub max_restarts: usize,
}

impl Default for CgParams {
    fn default() -> Self {
        CgParams {
            rel_tol: 1e-8,
            abs_tol: 0.0,
            max_iters: None,
            preconditioner: Preconditioner::None,
            null_space: NullSpace::None,
            record_history: false,
            require_convergence: true,
            max_restarts: 1,
        }
    }
}

impl CgParams {
    /// The defaults with relative tolerance `rel_tol`.
    pub fn with_rel_tol(mut self, rel_tol: f64) -> Self {
        self.rel_tol = rel_tol;
        self
    }

    /// With absolute tolerance `abs_tol`.
    pub fn with_abs_tol(mut self, abs_tol: f64) -> Self {
        self.abs_tol = abs_tol;
        self
    }

    /// With an iteration cap.
    pub fn with_max_iters(mut self, max_iters: usize) -> Self {
        self.max_iters = Some(max_iters);
        self
    }

    /// With a preconditioner.
    pub fn with_preconditioner(mut self, preconditioner: Preconditioner) -> Self {
        self.preconditioner = preconditioner;
        self
    }

    /// With a null space.
    pub fn with_null_space(mut self, null_space: NullSpace) -> Self {
        self.null_space = null_space;
        self
    }

    /// With [`CgParams::require_convergence`] set to `require`.
    pub fn with_require_convergence(mut self, require: bool) -> Self {
        self.require_convergence = require;
        self
    }

    /// Recording the residual history.
    pub fn with_history(mut self) -> Self {
        self.record_history = true;
        self
    }

    /// Exactly `iterations` iterations (fewer only if the residual becomes exactly
    /// zero, or falls so far below the precision's rounding floor that further
    /// iterations cannot change the solution), without a tolerance and without
    /// error at the cap: what unrolled solvers are compared with.
    pub fn fixed_iterations(mut self, iterations: usize) -> Self {
        self.rel_tol = 0.0;
        self.abs_tol = 0.0;
        self.max_iters = Some(iterations);
        self.require_convergence = false;
        self.max_restarts = 0;
        self
    }
}

/// What [`conjugate_gradient`] did.
#[derive(Debug, Clone, PartialEq)]
pub struct CgInfo {
    /// Iterations performed (operator applications in the loop), over all restarts.
    pub iterations: usize,
    /// The true residual `‖b − A x‖` of the returned `x`, recomputed at the end
    /// (`b` projected onto the range for a singular operator).
    pub residual_norm: f64,
    /// `‖b − A x‖ / ‖b‖` (`0` for `b = 0`): the relative residual reached.
    pub relative_residual: f64,
    /// The relative tolerance that applied, `max(rel_tol, abs_tol/‖b‖)`: the
    /// relative residual that was asked for.
    pub tolerance: f64,
    /// Whether the true residual met the tolerance,
    /// `relative_residual ≤ tolerance` (always true unless
    /// [`CgParams::require_convergence`] is false).
    pub converged: bool,
    /// Set when the solve stopped short of the tolerance because the true
    /// residual stalled near the rounding floor of the precision (the recurrence
    /// met the tolerance, the recomputed residual did not, and restarting could
    /// not help): the estimated floor, relative to `‖b‖`. `None` when the
    /// tolerance was met or the iteration cap was reached.
    pub rounding_floor: Option<f64>,
    /// Restarts from the recomputed residual.
    pub restarts: usize,
    /// The recurrence residual `‖r_k‖` for `k = 0..=iterations`, if asked for.
    pub history: Option<Vec<f64>>,
}

impl CgInfo {
    /// True if the solve ran into the iteration cap: neither converged nor
    /// stopped at the rounding floor.
    pub fn reached_cap(&self) -> bool {
        !self.converged && self.rounding_floor.is_none()
    }

    /// The error a solve with [`CgParams::require_convergence`] would have
    /// returned ([`CgError::NoConvergence`] or [`CgError::BelowRoundingFloor`]),
    /// for a caller that ran without it to inspect the outcome; `None` if the
    /// solve converged. `precision` names the scalar type in the message.
    pub fn failure(&self, precision: &str) -> Option<CgError> {
        if self.converged {
            return None;
        }
        // Not converged: relative_residual > tolerance ≥ 0, so ‖b‖ is recoverable.
        let b_norm = self.residual_norm / self.relative_residual;
        Some(match self.rounding_floor {
            None => CgError::NoConvergence {
                iterations: self.iterations,
                residual: self.residual_norm,
                relative_residual: self.relative_residual,
                target: self.tolerance * b_norm,
            },
            Some(floor) => CgError::BelowRoundingFloor {
                precision: precision.to_string(),
                requested: self.tolerance,
                reached: self.relative_residual,
                floor,
                iterations: self.iterations,
                restarts: self.restarts,
            },
        })
    }
}

/// Why [`conjugate_gradient`] failed. Every failure is detected and named; CG
/// never returns NaN silently.
#[derive(Debug, Clone, PartialEq, Error)]
#[non_exhaustive]
pub enum CgError {
    /// The tolerance was not met within the iteration cap. The solution array
    /// holds the last iterate.
    #[error(
        "conjugate gradient did not converge in {iterations} iterations: residual \
         {residual:.3e} (relative {relative_residual:.3e}) above the target {target:.3e}"
    )]
    NoConvergence {
        /// Iterations performed.
        iterations: usize,
        /// The true residual `‖b − A x‖` of the last iterate.
        residual: f64,
        /// `residual / ‖b‖`.
        relative_residual: f64,
        /// The residual that was asked for, `max(rel_tol·‖b‖, abs_tol)`.
        target: f64,
    },
    /// The tolerance lies below what the precision can reach on this system:
    /// the recurrence residual met it, but the true residual `‖b − A x‖`,
    /// recomputed, stalled above it near the rounding floor, where restarting
    /// no longer gains. The solution array holds the last iterate, which is
    /// converged to working precision. Returned only with
    /// [`CgParams::require_convergence`]; otherwise [`CgInfo::rounding_floor`]
    /// flags the same outcome.
    #[error(
        "conjugate gradient cannot reach the relative residual {requested:.1e} in {precision}: \
         the true residual stalled at {reached:.3e} after {iterations} iterations ({restarts} \
         restarts), near the estimated rounding floor {floor:.1e}; ask for a tolerance above \
         the floor, or solve in higher precision"
    )]
    BelowRoundingFloor {
        /// `f32` or `f64`.
        precision: String,
        /// The relative tolerance asked for, `max(rel_tol, abs_tol/‖b‖)`.
        requested: f64,
        /// The true relative residual `‖b − A x‖/‖b‖` reached.
        reached: f64,
        /// The estimated rounding floor of the relative residual,
        /// `ε·‖diag(A) ⊙ x‖/‖b‖`.
        floor: f64,
        /// Iterations performed.
        iterations: usize,
        /// Restarts from the recomputed residual.
        restarts: usize,
    },
    /// A direction `p` with `<p, A p> ≤ 0` (or a non-positive diagonal entry for
    /// Jacobi): the operator is not positive definite, or it is singular and no
    /// [`NullSpace`] was given.
    #[error(
        "operator is not positive definite: curvature <p, A p> = {curvature:e} at iteration \
         {iteration} (a singular operator needs CgParams::null_space)"
    )]
    NotPositiveDefinite {
        /// The iteration (0 for the diagonal check).
        iteration: usize,
        /// `<p, A p>` of the normalised system (or the diagonal entry).
        curvature: f64,
    },
    /// NaN or infinity in an input or in the recurrences.
    #[error("non-finite value in {what} at iteration {iteration}")]
    NonFinite {
        /// The iteration (0 for the inputs).
        iteration: usize,
        /// Which quantity.
        what: String,
    },
    /// An array does not have the operator's shape.
    #[error("shape mismatch in conjugate_gradient: {what} has shape {found:?}, the operator needs {expected:?}")]
    ShapeMismatch {
        /// Which array.
        what: String,
        /// The operator's shape.
        expected: Vec<usize>,
        /// The array's shape.
        found: Vec<usize>,
    },
    /// The recurrence cannot continue although the residual is not small: a step
    /// length overflows the precision (a curvature that underflows), or the
    /// preconditioned residual `<r, M⁻¹ r>` became non-positive.
    #[error("conjugate gradient broke down at iteration {iteration}: {reason}")]
    Breakdown {
        /// The iteration.
        iteration: usize,
        /// What happened.
        reason: String,
    },
    /// The operator or the parameters cannot be used (not square, not symmetric,
    /// no diagonal for Jacobi, a negative tolerance, an empty null space).
    #[error("invalid argument to conjugate_gradient: {message}")]
    InvalidArgument {
        /// What was wrong.
        message: String,
    },
}

impl CgError {
    fn invalid(message: impl Into<String>) -> Self {
        CgError::InvalidArgument {
            message: message.into(),
        }
    }

    fn non_finite(iteration: usize, what: &str) -> Self {
        CgError::NonFinite {
            iteration,
            what: what.to_string(),
        }
    }
}

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
    if let Some(xs) = x.as_slice_mut() {
        return Solver::new(op, shape, params)?.solve(b, xs);
    }
    let mut buf: Vec<T> = x.iter().copied().collect();
    let result = Solver::new(op, shape, params).and_then(|mut s| s.solve(b, &mut buf));
    for (o, &v) in x.iter_mut().zip(&buf) {
        *o = v;
    }
    result
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

const LANES: usize = 4;

/// A restart needs the true residual above this multiple of its estimated
/// rounding floor. Measured on 64² Laplacians: when the recurrence converges in
/// `f32`, the true residual sits at 3–7 times the estimate, and a restart lowers
/// it to 1–2 times but leaves the error unchanged while costing 30–100% more
/// iterations; a drifting `f64` recurrence at a tolerance far above the floor
/// restarts.
const RESTART_ABOVE_FLOOR: f64 = 10.0;

fn lanes_total(acc: [f64; LANES]) -> f64 {
    (acc[0] + acc[1]) + (acc[2] + acc[3])
}

/// `Σ a_i b_i` in f64.
fn dot<T: Real>(a: &[T], b: &[T]) -> f64 {
    let mut acc = [0.0; LANES];
    let (ac, bc) = (a.chunks_exact(LANES), b.chunks_exact(LANES));
    let (ar, br) = (ac.remainder(), bc.remainder());
    for (a, b) in ac.zip(bc) {
        let (a, b) = (lanes(a), lanes(b));
        for l in 0..LANES {
            acc[l] += wide(a[l]) * wide(b[l]);
        }
    }
    for (a, b) in ar.iter().zip(br) {
        acc[0] += wide(*a) * wide(*b);
    }
    lanes_total(acc)
}

/// A chunk of `chunks_exact(LANES)` as an array, so that the lane loops compile
/// to vector instructions without bounds checks.
#[inline(always)]
fn lanes<T: Copy>(chunk: &[T]) -> &[T; LANES] {
    chunk
        .try_into()
        .expect("chunks_exact yields LANES elements")
}

#[inline(always)]
fn lanes_mut<T: Copy>(chunk: &mut [T]) -> &mut [T; LANES] {
    chunk
        .try_into()
        .expect("chunks_exact yields LANES elements")
}

/// `Σ k_i a_i` in f64, `k = 1` if `None`.
fn weighted_sum<T: Real>(a: &[T], k: Option<&[T]>) -> f64 {
    match k {
        Some(k) => dot(a, k),
        None => {
            let mut acc = [0.0; LANES];
            let ac = a.chunks_exact(LANES);
            let rest: f64 = ac.remainder().iter().map(|&v| wide(v)).sum();
            for a in ac {
                let a = lanes(a);
                for l in 0..LANES {
                    acc[l] += wide(a[l]);
                }
            }
            lanes_total(acc) + rest
        }
    }
}

/// `v −= m·k` (`k = 1` if `None`).
fn subtract_multiple<T: Real>(v: &mut [T], m: T, k: Option<&[T]>) {
    match k {
        Some(k) => v.iter_mut().zip(k).for_each(|(v, &k)| *v -= m * k),
        None => v.iter_mut().for_each(|v| *v -= m),
    }
}

/// The sums one residual pass produces (f64).
#[derive(Debug, Clone, Copy, Default)]
struct Sums {
    /// `<r, r>`.
    rr: f64,
    /// `<r, z>` (`= rr` without preconditioner).
    rz: f64,
    /// `<k, r>`.
    kr: f64,
    /// `<k, z>` (`= kr` without preconditioner).
    kz: f64,
}

/// `r −= α q`, returning `<r, r>` and `<k, r>` (`k = 1` if `None`).
fn update_residual<T: Real>(alpha: T, q: &[T], r: &mut [T], k: Option<&[T]>) -> Sums {
    let mut rr = [0.0; LANES];
    let mut kr = [0.0; LANES];
    let n = r.len();
    let split = n - n % LANES;
    let (r_main, r_rest) = r.split_at_mut(split);
    let (q_main, q_rest) = q.split_at(split);
    match k {
        None => {
            for (r, q) in r_main
                .chunks_exact_mut(LANES)
                .zip(q_main.chunks_exact(LANES))
            {
                let (r, q) = (lanes_mut(r), lanes(q));
                for l in 0..LANES {
                    let v = r[l] - alpha * q[l];
                    r[l] = v;
                    let v = wide(v);
                    rr[l] += v * v;
                    kr[l] += v;
                }
            }
        }
        Some(k) => {
            for ((r, q), k) in r_main
                .chunks_exact_mut(LANES)
                .zip(q_main.chunks_exact(LANES))
                .zip(k[..split].chunks_exact(LANES))
            {
                let (r, q, k) = (lanes_mut(r), lanes(q), lanes(k));
                for l in 0..LANES {
                    let v = r[l] - alpha * q[l];
                    r[l] = v;
                    let v = wide(v);
                    rr[l] += v * v;
                    kr[l] += v * wide(k[l]);
                }
            }
        }
    }
    for (i, (r, &q)) in r_rest.iter_mut().zip(q_rest).enumerate() {
        *r -= alpha * q;
        let v = wide(*r);
        rr[0] += v * v;
        kr[0] += v * k.map_or(1.0, |k| wide(k[split + i]));
    }
    let (rr, kr) = (lanes_total(rr), lanes_total(kr));
    Sums {
        rr,
        rz: rr,
        kr,
        kz: kr,
    }
}

/// `r −= α q; z = d⁻¹ ⊙ r`, returning all four sums.
fn update_residual_jacobi<T: Real>(
    alpha: T,
    q: &[T],
    r: &mut [T],
    inv_d: &[T],
    z: &mut [T],
    k: Option<&[T]>,
) -> Sums {
    let mut s = Sums::default();
    for (i, (((r, &q), &d), z)) in r.iter_mut().zip(q).zip(inv_d).zip(z).enumerate() {
        *r -= alpha * q;
        *z = *r * d;
        let (rv, zv) = (wide(*r), wide(*z));
        let kv = k.map_or(1.0, |k| wide(k[i]));
        s.rr += rv * rv;
        s.rz += rv * zv;
        s.kr += kv * rv;
        s.kz += kv * zv;
    }
    s
}

/// `x += α p; p = (z − m k) + β p` (`k = 1` if `None`).
fn update_direction<T: Real>(
    alpha: T,
    beta: T,
    m: T,
    z: &[T],
    p: &mut [T],
    x: &mut [T],
    k: Option<&[T]>,
) {
    match k {
        None => {
            for ((p, x), &z) in p.iter_mut().zip(x.iter_mut()).zip(z) {
                *x += alpha * *p;
                *p = (z - m) + beta * *p;
            }
        }
        Some(k) => {
            for (((p, x), &z), &k) in p.iter_mut().zip(x.iter_mut()).zip(z).zip(k) {
                *x += alpha * *p;
                *p = (z - m * k) + beta * *p;
            }
        }
    }
}

/// `x += α p`.
fn axpy<T: Real>(alpha: T, p: &[T], x: &mut [T]) {
    x.iter_mut().zip(p).for_each(|(x, &p)| *x += alpha * p);
}

/// Where an iteration sequence stopped.
enum Stop {
    /// The recurrence residual met the tolerance.
    Converged,
    /// The iteration cap.
    Cap,
}

/// How a whole solve (iterations and restarts) ended.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Outcome {
    /// The true residual met the tolerance.
    Converged,
    /// The iteration cap.
    Cap,
    /// The recurrence met the tolerance, the true residual stalled above it and
    /// restarting could not help; the estimated relative rounding floor.
    Stalled(f64),
}

/// The working state of one solve: all vectors, allocated once.
struct Solver<'a, T: Real, A: ?Sized> {
    op: &'a A,
    shape: Vec<usize>,
    params: &'a CgParams,
    max_iters: usize,
    r: Vec<T>,
    p: Vec<T>,
    q: Vec<T>,
    /// `M⁻¹ r` (empty without preconditioner: `z = r`).
    z: Vec<T>,
    inv_d: Vec<T>,
    /// The null vector, `None` for the constants (or no null space).
    k: Option<Vec<T>>,
    /// `kᵀ k`; 0 without null space.
    kk: f64,
    iterations: usize,
    history: Option<Vec<f64>>,
    /// [`Self::rounding_floor`] of the iterate, computed once the recurrence
    /// residual has dropped below `ε` (see [`Self::stagnated`]).
    floor: Option<f64>,
}

impl<'a, T: Real, A: LinearOperator<T> + ?Sized> Solver<'a, T, A> {
    fn new(op: &'a A, shape: Vec<usize>, params: &'a CgParams) -> Result<Self, CgError> {
        let n: usize = shape.iter().product();
        let (k, kk) = match &params.null_space {
            NullSpace::None => (None, 0.0),
            NullSpace::Constant => (None, n as f64),
            NullSpace::ConstantOn(mask) => (
                Some(
                    mask.as_slice()
                        .iter()
                        .map(|&a| if a { T::one() } else { T::zero() })
                        .collect(),
                ),
                mask.active_count() as f64,
            ),
        };
        let (z, inv_d) = match params.preconditioner {
            Preconditioner::None => (Vec::new(), Vec::new()),
            Preconditioner::Jacobi => {
                let d = op.diagonal().ok_or_else(|| {
                    CgError::invalid(format!(
                        "operator {} gives no diagonal (LinearOperator::diagonal) for Jacobi",
                        op.name()
                    ))
                })?;
                let mut inv = Vec::with_capacity(n);
                for &v in d.iter() {
                    if !v.is_finite() {
                        return Err(CgError::non_finite(0, "the diagonal (Jacobi)"));
                    }
                    if v <= T::zero() {
                        return Err(CgError::NotPositiveDefinite {
                            iteration: 0,
                            curvature: v.as_f64(),
                        });
                    }
                    inv.push(T::one() / v);
                }
                (vec![T::zero(); n], inv)
            }
        };
        let max_iters = params.max_iters.unwrap_or(2 * n + 10);
        Ok(Solver {
            op,
            shape,
            params,
            max_iters,
            r: vec![T::zero(); n],
            p: vec![T::zero(); n],
            q: vec![T::zero(); n],
            z,
            inv_d,
            k,
            kk,
            iterations: 0,
            history: params
                .record_history
                .then(|| Vec::with_capacity(max_iters.saturating_add(1).min(1 << 16))),
            floor: None,
        })
    }

    fn projecting(&self) -> bool {
        self.kk > 0.0
    }

    /// `y = A x` on slices, returning `<x, A x>` (in f64).
    fn apply(&self, x: &[T], y: &mut [T]) -> f64 {
        let xv = ArrayViewD::from_shape(IxDyn(&self.shape), x).expect("length matches shape");
        let yv = ArrayViewMutD::from_shape(IxDyn(&self.shape), y).expect("length matches shape");
        self.op.apply_into_dot(xv, yv)
    }

    /// `<Π r, Π r>` and `<Π r, Π z>` from the raw sums.
    fn projected(&self, s: Sums) -> (f64, f64) {
        if self.projecting() {
            (s.rr - s.kr * s.kr / self.kk, s.rz - s.kr * s.kz / self.kk)
        } else {
            (s.rr, s.rz)
        }
    }

    /// The mean of `z` along `k` that `Π` removes (0 without null space).
    fn z_mean(&self, s: Sums) -> T {
        if self.projecting() {
            T::from_f64(s.kz / self.kk)
        } else {
            T::zero()
        }
    }

    /// `z = M⁻¹ r` and the sums, from the current `r`.
    fn residual_sums(&mut self) -> Sums {
        if self.inv_d.is_empty() {
            let k = self.k.as_deref();
            let rr = dot(&self.r, &self.r);
            let kr = if self.projecting() {
                weighted_sum(&self.r, k)
            } else {
                0.0
            };
            return Sums {
                rr,
                rz: rr,
                kr,
                kz: kr,
            };
        }
        for ((z, &r), &d) in self.z.iter_mut().zip(&self.r).zip(&self.inv_d) {
            *z = r * d;
        }
        let k = self.k.as_deref();
        Sums {
            rr: dot(&self.r, &self.r),
            rz: dot(&self.r, &self.z),
            kr: weighted_sum(&self.r, k),
            kz: weighted_sum(&self.z, k),
        }
    }

    /// `p = Π z` from fresh sums: the first direction (and after a restart).
    fn first_direction(&mut self, s: Sums) {
        let m = self.z_mean(s);
        let z = if self.inv_d.is_empty() {
            &self.r
        } else {
            &self.z
        };
        self.p.copy_from_slice(z);
        if self.projecting() {
            subtract_multiple(&mut self.p, m, self.k.as_deref());
        }
    }

    /// `r = Π(b)/s − A x̂` (with `A x̂` skipped when `x̂ = 0`), then the sums.
    fn true_residual(
        &mut self,
        b: &ArrayViewD<'_, T>,
        b_mean: T,
        s: T,
        x: &[T],
        x_zero: bool,
    ) -> Sums {
        for (r, &bv) in self.r.iter_mut().zip(b.iter()) {
            *r = bv;
        }
        if self.projecting() {
            subtract_multiple(&mut self.r, b_mean, self.k.as_deref());
        }
        self.r.iter_mut().for_each(|r| *r /= s);
        if !x_zero {
            let mut q = std::mem::take(&mut self.q);
            self.apply(x, &mut q);
            self.r.iter_mut().zip(&q).for_each(|(r, &q)| *r -= q);
            self.q = q;
        }
        self.residual_sums()
    }

    /// Iterates from the direction in `p` until the recurrence residual meets
    /// `tol` or the cap. `rz` is `<Π r, Π z>` of the current residual.
    fn iterate(
        &mut self,
        x: &mut [T],
        mut rz: f64,
        tol: f64,
        b_norm: f64,
    ) -> Result<Stop, CgError> {
        let tol2 = tol * tol;
        while self.iterations < self.max_iters {
            let it = self.iterations;
            let mut q = std::mem::take(&mut self.q);
            let pq = self.apply(&self.p, &mut q);
            self.q = q;
            if !pq.is_finite() {
                return Err(CgError::non_finite(it, "the curvature <p, A p>"));
            }
            if pq <= 0.0 {
                return Err(CgError::NotPositiveDefinite {
                    iteration: it,
                    curvature: pq,
                });
            }
            let alpha = rz / pq;
            let alpha_t = T::from_f64(alpha);
            if !alpha_t.is_finite() {
                return Err(CgError::Breakdown {
                    iteration: it,
                    reason: format!(
                        "step length α = <r, z>/<p, A p> = {rz:e}/{pq:e} overflows {}",
                        T::NAME
                    ),
                });
            }
            let sums = {
                let k = self.k.as_deref();
                if self.inv_d.is_empty() {
                    update_residual(alpha_t, &self.q, &mut self.r, k)
                } else {
                    update_residual_jacobi(
                        alpha_t,
                        &self.q,
                        &mut self.r,
                        &self.inv_d,
                        &mut self.z,
                        k,
                    )
                }
            };
            self.iterations += 1;
            let (rr, rz_new) = self.projected(sums);
            if !(rr.is_finite() && rz_new.is_finite()) {
                return Err(CgError::non_finite(it, "the residual"));
            }
            let rr = rr.max(0.0);
            if let Some(h) = &mut self.history {
                h.push(rr.sqrt() * b_norm);
            }
            if rr <= tol2 || rr == 0.0 || self.stagnated(rr.sqrt(), x) {
                axpy(alpha_t, &self.p, x);
                return Ok(Stop::Converged);
            }
            if rz_new <= 0.0 {
                return Err(CgError::Breakdown {
                    iteration: it,
                    reason: format!(
                        "preconditioned residual <r, M⁻¹ r> = {rz_new:e} ≤ 0 with ‖r‖ = {:e}",
                        rr.sqrt() * b_norm
                    ),
                });
            }
            let beta = T::from_f64(rz_new / rz);
            if !beta.is_finite() {
                return Err(CgError::Breakdown {
                    iteration: it,
                    reason: format!("β = {rz_new:e}/{rz:e} overflows {}", T::NAME),
                });
            }
            let m = self.z_mean(sums);
            let k = self.k.as_deref();
            let z = if self.inv_d.is_empty() {
                &self.r
            } else {
                &self.z
            };
            update_direction(alpha_t, beta, m, z, &mut self.p, x, k);
            rz = rz_new;
        }
        Ok(Stop::Cap)
    }

    /// The whole solve on the contiguous solution `x` (initial guess on entry).
    fn solve(&mut self, b: ArrayViewD<'_, T>, x: &mut [T]) -> Result<CgInfo, CgError> {
        // Inputs: finite, and b's component along the null space.
        if b.iter().any(|v| !v.is_finite()) {
            return Err(CgError::non_finite(0, "the right-hand side b"));
        }
        let mut x_zero = true;
        for v in x.iter() {
            if !v.is_finite() {
                return Err(CgError::non_finite(0, "the initial guess x"));
            }
            x_zero &= *v == T::zero();
        }
        let k = self.k.as_deref();
        for (r, &bv) in self.r.iter_mut().zip(b.iter()) {
            *r = bv;
        }
        let b_mean = if self.projecting() {
            let m = T::from_f64(weighted_sum(&self.r, k) / self.kk);
            subtract_multiple(&mut self.r, m, k);
            if !x_zero {
                let mx = T::from_f64(weighted_sum(x, k) / self.kk);
                subtract_multiple(x, mx, k);
            }
            m
        } else {
            T::zero()
        };
        let b_norm = dot(&self.r, &self.r).sqrt();
        if !b_norm.is_finite() {
            return Err(CgError::non_finite(0, "the norm of b (overflow)"));
        }
        if b_norm == 0.0 {
            x.fill(T::zero());
            return Ok(CgInfo {
                iterations: 0,
                residual_norm: 0.0,
                relative_residual: 0.0,
                tolerance: self.params.rel_tol,
                converged: true,
                rounding_floor: None,
                restarts: 0,
                history: self.history.take().map(|mut h| {
                    h.push(0.0);
                    h
                }),
            });
        }

        // Normalise: solve A x̂ = Π b / s, x̂ = x / s.
        let s = T::from_f64(b_norm);
        if !x_zero {
            x.iter_mut().for_each(|v| *v /= s);
        }
        let tol = self.params.rel_tol.max(self.params.abs_tol / b_norm);
        let outcome = self.run(&b, b_mean, s, x, x_zero, tol, b_norm);

        // Scale back (also on error: x then holds the last iterate in original units).
        if self.projecting() {
            let k = self.k.as_deref();
            let mx = T::from_f64(weighted_sum(x, k) / self.kk);
            subtract_multiple(x, mx, k);
        }
        x.iter_mut().for_each(|v| *v *= s);
        let (true_rel, outcome, restarts) = outcome?;
        let info = CgInfo {
            iterations: self.iterations,
            residual_norm: true_rel * b_norm,
            relative_residual: true_rel,
            tolerance: tol,
            converged: outcome == Outcome::Converged,
            rounding_floor: match outcome {
                Outcome::Stalled(floor) => Some(floor),
                _ => None,
            },
            restarts,
            history: self.history.take(),
        };
        match info.failure(T::NAME) {
            Some(e) if self.params.require_convergence => Err(e),
            _ => Ok(info),
        }
    }

    /// The iterations and restarts on the normalised system; returns the true
    /// relative residual, how the solve ended, and the restarts.
    #[allow(clippy::too_many_arguments)]
    fn run(
        &mut self,
        b: &ArrayViewD<'_, T>,
        b_mean: T,
        s: T,
        x: &mut [T],
        x_zero: bool,
        tol: f64,
        b_norm: f64,
    ) -> Result<(f64, Outcome, usize), CgError> {
        let mut sums = self.true_residual(b, b_mean, s, x, x_zero);
        let (mut rr, mut rz) = self.checked(sums)?;
        if let Some(h) = &mut self.history {
            h.push(rr.sqrt() * b_norm);
        }
        if rr.sqrt() <= tol || rr == 0.0 {
            return Ok((rr.sqrt(), Outcome::Converged, 0));
        }
        let mut restarts = 0;
        let mut last_true = f64::INFINITY;
        loop {
            self.first_direction(sums);
            let stop = self.iterate(x, rz, tol, b_norm)?;
            sums = self.true_residual(b, b_mean, s, x, false);
            (rr, rz) = self.checked(sums)?;
            let true_rel = rr.sqrt();
            if true_rel <= tol || rr == 0.0 {
                return Ok((true_rel, Outcome::Converged, restarts));
            }
            match stop {
                Stop::Cap => return Ok((true_rel, Outcome::Cap, restarts)),
                Stop::Converged => {
                    // The recurrence met the tolerance, the true residual did not:
                    // restart from it while that still gains a factor 2 and either
                    // the residual lies clearly above its rounding floor or the
                    // tolerance lies above the floor (below both, restarting only
                    // recomputes rounding errors).
                    let gaining = true_rel < 0.5 * last_true;
                    let floor = self.rounding_floor(x);
                    if restarts < self.params.max_restarts
                        && self.iterations < self.max_iters
                        && gaining
                        && (true_rel > RESTART_ABOVE_FLOOR * floor || tol >= floor)
                    {
                        restarts += 1;
                        last_true = true_rel;
                    } else {
                        return Ok((true_rel, Outcome::Stalled(floor), restarts));
                    }
                }
            }
        }
    }

    /// True once the recurrence residual `‖r̂‖` (of the normalised system) has
    /// fallen a factor `ε` below the rounding floor of the true residual: the
    /// iterate is converged to working precision, the remaining corrections
    /// `α p` no longer change it in `T`, and further iterations only shrink the
    /// recurrence towards underflow, where the curvature `<p, A p>` rounds to
    /// zero and would read as a non-positive-definite operator. Measured in
    /// `f32` on the 64² Laplacian: without this stop, fixed iteration counts of
    /// a few times what convergence needs broke down that way.
    fn stagnated(&mut self, r_norm: f64, x: &[T]) -> bool {
        let eps = T::EPS.as_f64();
        if r_norm >= eps {
            return false;
        }
        let floor = match self.floor {
            Some(f) => f,
            None => *self.floor.insert(self.rounding_floor(x)),
        };
        r_norm <= eps * floor
    }

    /// The rounding error of `b̂ − A x̂` computed in `T`, estimated as
    /// `ε·‖diag(A) ⊙ x̂‖` (for diagonally dominant operators such as Laplacians
    /// `|A| |x| ≤ 2 |diag(A)| |x|`); 0 if the operator gives no diagonal.
    fn rounding_floor(&self, x: &[T]) -> f64 {
        let weighted = |d: &mut dyn Iterator<Item = f64>| {
            d.zip(x)
                .map(|(d, &x)| (d * x.as_f64()).powi(2))
                .sum::<f64>()
                .sqrt()
        };
        let norm = if self.inv_d.is_empty() {
            match self.op.diagonal() {
                Some(d) => weighted(&mut d.iter().map(|d| d.as_f64())),
                None => 0.0,
            }
        } else {
            weighted(&mut self.inv_d.iter().map(|d| 1.0 / d.as_f64()))
        };
        T::EPS.as_f64() * norm
    }

    /// `<Π r, Π r>` (clamped at 0) and `<Π r, Π z>`, checked for NaN.
    fn checked(&self, sums: Sums) -> Result<(f64, f64), CgError> {
        let (rr, rz) = self.projected(sums);
        if !(rr.is_finite() && rz.is_finite()) {
            return Err(CgError::non_finite(self.iterations, "the residual"));
        }
        Ok((rr.max(0.0), rz))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The fused kernels against their one-loop-per-operation definitions, for
    /// lengths that exercise the four-lane remainder.
    #[test]
    fn fused_kernels_match_plain_loops() {
        for n in 0..11 {
            let q: Vec<f64> = (0..n).map(|i| (i as f64 * 0.7).sin()).collect();
            let r0: Vec<f64> = (0..n).map(|i| (i as f64 * 0.3).cos()).collect();
            let k: Vec<f64> = (0..n).map(|i| f64::from(u8::from(i % 3 != 0))).collect();
            let alpha = 0.37;
            let expect_r: Vec<f64> = r0.iter().zip(&q).map(|(r, q)| r - alpha * q).collect();
            let rr: f64 = expect_r.iter().map(|v| v * v).sum();
            let sr: f64 = expect_r.iter().sum();
            let kr: f64 = expect_r.iter().zip(&k).map(|(r, k)| r * k).sum();
            for (kv, expect_kr) in [(None, sr), (Some(k.as_slice()), kr)] {
                let mut r = r0.clone();
                let s = update_residual(alpha, &q, &mut r, kv);
                assert_eq!(r, expect_r);
                assert!((s.rr - rr).abs() < 1e-12 && (s.kr - expect_kr).abs() < 1e-12);
                assert_eq!((s.rz, s.kz), (s.rr, s.kr));
                let inv_d: Vec<f64> = (0..n).map(|i| 1.0 / (1.0 + i as f64)).collect();
                let (mut r, mut z) = (r0.clone(), vec![0.0; n]);
                let s = update_residual_jacobi(alpha, &q, &mut r, &inv_d, &mut z, kv);
                let rz: f64 = expect_r.iter().zip(&inv_d).map(|(r, d)| r * r * d).sum();
                assert!((s.rr - rr).abs() < 1e-12 && (s.rz - rz).abs() < 1e-12);
            }
            assert!(
                (dot(&q, &r0) - q.iter().zip(&r0).map(|(a, b)| a * b).sum::<f64>()).abs() < 1e-12
            );
            assert!((weighted_sum(&q, None) - q.iter().sum::<f64>()).abs() < 1e-12);
            let (mut p, mut x) = (r0.clone(), q.clone());
            update_direction(0.5, 2.0, 0.25, &q, &mut p, &mut x, Some(&k));
            for i in 0..n {
                assert_eq!(x[i], q[i] + 0.5 * r0[i]);
                assert_eq!(p[i], (q[i] - 0.25 * k[i]) + 2.0 * r0[i]);
            }
        }
    }

    #[test]
    fn f32_fixed_iterations_far_past_convergence_stop_at_the_rounding_floor() {
        // Without the stagnation stop the recurrence shrank until the curvature
        // <p, A p> underflowed (a non-finite error at iteration 1026 here).
        use crate::stencil::Laplacian2;
        use crate::{Boundary, Grid2};
        let grid = Grid2::square(32, 32, 1.0 / 32.0, Boundary::ZeroDirichlet).unwrap();
        let a = Laplacian2::negative(grid);
        let b = diffphys_tape::test_array::<f32>(&[32, 32], 11);
        let params = CgParams::default().fixed_iterations(3000);
        let (x, info) = cg_solve(&a, b.view(), &params).unwrap();
        assert!(info.iterations < 3000, "{}", info.iterations);
        assert!(info.relative_residual < 1e-4, "{}", info.relative_residual);
        assert!(x.iter().all(|v| v.is_finite()));
        // f64 on the same system runs far longer before its floor stops it.
        let b64 = b.mapv(f64::from);
        let (_, info64) = cg_solve(&a, b64.view(), &params).unwrap();
        assert!(info64.iterations > info.iterations);
    }

    #[test]
    fn errors_display_their_context() {
        let e = CgError::NotPositiveDefinite {
            iteration: 3,
            curvature: -2.0,
        };
        assert!(e.to_string().contains("at iteration 3"));
        assert!(e.to_string().contains("null_space"));
        let e = CgError::ShapeMismatch {
            what: "right-hand side b".into(),
            expected: vec![2, 3],
            found: vec![3, 2],
        };
        assert!(e.to_string().contains("[3, 2]"));
    }
}
