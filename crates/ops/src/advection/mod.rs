//! Advection of a cell-centred field by a cell-centred velocity, with hand-written
//! adjoints with respect to both: first-order upwind ([`upwind`]) and
//! semi-Lagrangian ([`semi_lagrangian`]), in 1D and 2D.
//!
//! Each scheme is a pair of plain functions on ndarray views (the forward and its
//! vector–Jacobian product, which computes only the gradients asked for in a
//! [`Wants`]) and a thin tape op over them. In 2D the velocity has shape
//! `[2, nx, ny]` with components `[u_x, u_y]` on the same cells as the field.
//!
//! ```
//! use diffphys_ops::advection::{upwind_1d, AdvectionParams};
//! use diffphys_ops::{Boundary, Grid1};
//! use ndarray::Array1;
//!
//! let grid = Grid1::new(8, 0.1, 0.0, Boundary::Periodic)?;
//! let d = Array1::from_shape_fn(8, |i| if i == 2 { 1.0 } else { 0.0 });
//! let u = Array1::from_elem(8, 0.5); // Courant number 0.5·0.2/0.1 = 1
//! let d1 = upwind_1d(&grid, &AdvectionParams::new(0.2), d.view(), u.view())?;
//! assert_eq!(d1[3], 1.0); // at Courant number 1, upwind moves the pulse one cell
//! # Ok::<(), diffphys_ops::OpsError>(())
//! ```

pub mod semi_lagrangian;
pub mod upwind;

pub use semi_lagrangian::{
    semi_lagrangian_1d, semi_lagrangian_1d_tape, semi_lagrangian_1d_vjp, semi_lagrangian_2d,
    semi_lagrangian_2d_tape, semi_lagrangian_2d_vjp, SemiLagrangian1dOp, SemiLagrangian2dOp,
};
pub use upwind::{
    upwind_1d, upwind_1d_tape, upwind_1d_vjp, upwind_2d, upwind_2d_tape, upwind_2d_vjp, Upwind1dOp,
    Upwind2dOp,
};

use diffphys_tape::{ArrayD, BackwardArgs, Real};
use ndarray::{Array, ArrayBase, ArrayView, ArrayViewD, Data, Dimension};

use crate::{OpsError, Result};

/// The time step of an explicit advection step and whether it may break the CFL
/// condition.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AdvectionParams {
    /// The time step, finite and positive.
    pub dt: f64,
    /// Step even when the Courant number exceeds 1 (the scheme is then unstable;
    /// stability studies need it). Off by default: a violation is
    /// [`OpsError::Cfl`].
    pub allow_cfl_violation: bool,
}

impl AdvectionParams {
    /// A step of `dt` that refuses CFL violations.
    pub fn new(dt: f64) -> Self {
        AdvectionParams {
            dt,
            allow_cfl_violation: false,
        }
    }

    /// The same step, allowing CFL violations.
    pub fn allowing_cfl_violation(self) -> Self {
        AdvectionParams {
            allow_cfl_violation: true,
            ..self
        }
    }

    pub(crate) fn check_dt(&self, op: &str) -> Result<()> {
        check_dt(op, self.dt)
    }
}

pub(crate) fn check_dt(op: &str, dt: f64) -> Result<()> {
    if dt.is_finite() && dt > 0.0 {
        Ok(())
    } else {
        Err(OpsError::invalid(
            op,
            format!("need a finite dt > 0, got {dt}"),
        ))
    }
}

/// Which gradients a vector–Jacobian product should compute; the others are
/// returned as `None` and cost nothing.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Wants {
    /// The gradient with respect to the advected field.
    pub field: bool,
    /// The gradient with respect to the velocity.
    pub velocity: bool,
}

impl Wants {
    /// Both gradients.
    pub const BOTH: Wants = Wants {
        field: true,
        velocity: true,
    };
}

/// The result of an advection vector–Jacobian product: the gradients with respect
/// to the field and the velocity, each `Some` only if it was asked for.
#[derive(Debug, Clone, PartialEq)]
pub struct AdvectionGrads<F, V> {
    /// `(∂d'/∂d)ᵀ g`, the gradient with respect to the advected field.
    pub field: Option<F>,
    /// `(∂d'/∂u)ᵀ g`, the gradient with respect to the velocity.
    pub velocity: Option<V>,
}

/// Checks that `a` has shape `want`.
pub(crate) fn check_shape<S, D>(op: &str, want: &[usize], a: &ArrayBase<S, D>) -> Result<()>
where
    S: Data,
    D: Dimension,
{
    if a.shape() == want {
        Ok(())
    } else {
        Err(OpsError::shape(op, want, a.shape()))
    }
}

/// Checks that every velocity entry is finite.
pub(crate) fn check_finite_velocity<T: Real>(op: &str, u: &[T]) -> Result<()> {
    if u.iter().all(|v| v.is_finite()) {
        Ok(())
    } else {
        Err(OpsError::NonFinite {
            op: op.to_string(),
            what: "velocity".to_string(),
        })
    }
}

/// Checks the number of inputs of a tape op.
pub(crate) fn check_arity(op: &str, found: usize, expected: usize) -> diffphys_tape::Result<()> {
    if found == expected {
        Ok(())
    } else {
        Err(diffphys_tape::TapeError::Arity {
            op: op.to_string(),
            expected,
            found,
        })
    }
}

/// A tape op's dynamic-rank input as a view of rank `D`.
pub(crate) fn tape_view<'a, T: Real, D: Dimension>(
    op: &str,
    a: &ArrayViewD<'a, T>,
) -> diffphys_tape::Result<ArrayView<'a, T, D>> {
    a.clone().into_dimensionality::<D>().map_err(|_| {
        diffphys_tape::TapeError::invalid(op, format!("input of wrong rank: shape {:?}", a.shape()))
    })
}

/// The forward of a `[d, u] → d'` advection tape op: checks the arity, views the
/// inputs at the scheme's ranks and runs the plain forward `step`.
pub(crate) fn advection_forward<T: Real, D: Dimension, U: Dimension>(
    op: &str,
    inputs: &[ArrayViewD<'_, T>],
    step: impl FnOnce(ArrayView<'_, T, D>, ArrayView<'_, T, U>) -> Result<Array<T, D>>,
) -> diffphys_tape::Result<Vec<ArrayD<T>>> {
    check_arity(op, inputs.len(), 2)?;
    let d = tape_view::<T, D>(op, &inputs[0])?;
    let u = tape_view::<T, U>(op, &inputs[1])?;
    Ok(vec![step(d, u)?.into_dyn()])
}

/// The plain vector–Jacobian product of an advection scheme: `(d, u, g, wants)`
/// to the gradients of `d` and `u` that `wants` asks for.
pub(crate) type AdvectionVjp<T, D, U> = Result<AdvectionGrads<Array<T, D>, Array<T, U>>>;

/// The backward of a `[d, u] → d'` advection tape op: asks the plain `vjp` for
/// exactly the gradients the tape needs and hands them back in input order.
pub(crate) fn advection_backward<'a, T: Real, D: Dimension, U: Dimension>(
    op: &str,
    args: &BackwardArgs<'a, T>,
    vjp: impl FnOnce(
        ArrayView<'a, T, D>,
        ArrayView<'a, T, U>,
        ArrayView<'a, T, D>,
        Wants,
    ) -> AdvectionVjp<T, D, U>,
) -> diffphys_tape::Result<Vec<Option<ArrayD<T>>>> {
    let wants = Wants {
        field: args.needs(0),
        velocity: args.needs(1),
    };
    let g = vjp(
        tape_view::<T, D>(op, args.input(0))?,
        tape_view::<T, U>(op, args.input(1))?,
        tape_view::<T, D>(op, args.grad_out())?,
        wants,
    )?;
    Ok(vec![
        g.field.map(|a| a.into_dyn()),
        g.velocity.map(|a| a.into_dyn()),
    ])
}
