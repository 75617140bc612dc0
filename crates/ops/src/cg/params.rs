//! The solver's params / info / error triad.

use super::Preconditioning;
pub use crate::error::CgError;
use crate::linear::NullSpace;

/// How [`conjugate_gradient`](super::conjugate_gradient) runs.
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
    pub preconditioner: Preconditioning,
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
            preconditioner: Preconditioning::None,
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

    /// With a preconditioner: a [`Preconditioning`], or an
    /// `Arc` of a shared one (`Arc<Multigrid>`).
    pub fn with_preconditioner(mut self, preconditioner: impl Into<Preconditioning>) -> Self {
        self.preconditioner = preconditioner.into();
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

/// What [`conjugate_gradient`](super::conjugate_gradient) did.
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
