//! Advection of a cell-centred field by a cell-centred velocity, with hand-written
//! adjoints with respect to both: first-order upwind ([`upwind`]) and
//! semi-Lagrangian ([`semi_lagrangian`]), in 1D and 2D.
//!
//! Each scheme is a pair of plain functions on ndarray views (the forward and its
//! vector–Jacobian product, which computes only the gradients asked for in a
//! [`Wants`]), bundled as an [`AdvectionScheme`] ([`Upwind1`], [`Upwind2`],
//! [`SemiLagrangian1`], [`SemiLagrangian2`]). Each scheme value is also a tape
//! op with inputs `[d, u]`: `tape.apply(Upwind1::new(grid, params), &[d, u])`
//! (a scheme of your own records through [`AdvectionOp`]). In 2D the velocity
//! has shape `[2, nx, ny]` with components `[u_x, u_y]` on the same cells as
//! the field.
//!
//! ```
//! use diffphys_ops::advection::{upwind1, AdvectionParams};
//! use diffphys_ops::{Boundary, Grid1};
//! use ndarray::Array1;
//!
//! let grid = Grid1::new(8, 0.1, 0.0, Boundary::Periodic)?;
//! let d = Array1::from_shape_fn(8, |i| if i == 2 { 1.0 } else { 0.0 });
//! let u = Array1::from_elem(8, 0.5); // Courant number 0.5·0.2/0.1 = 1
//! let d1 = upwind1(&grid, &AdvectionParams::new(0.2), d.view(), u.view())?;
//! assert_eq!(d1[3], 1.0); // at Courant number 1, upwind moves the pulse one cell
//! # Ok::<(), diffphys_ops::OpsError>(())
//! ```
//!
//! On the tape, the same step with gradients for the field and the velocity:
//!
//! ```
//! use diffphys_ops::advection::{AdvectionParams, Upwind1};
//! use diffphys_ops::{Boundary, Grid1};
//! use diffphys_tape::{arr_dyn, Tape};
//!
//! let grid = Grid1::new(4, 0.1, 0.0, Boundary::Periodic)?;
//! let tape = Tape::<f64>::new();
//! let d = tape.var(arr_dyn(&[0.0, 1.0, 0.0, 0.0]));
//! let u = tape.var(arr_dyn(&[0.5; 4]));
//! let d1 = tape.apply(Upwind1::new(grid, AdvectionParams::new(0.1)), &[d, u])?; // Courant number 0.5
//! assert_eq!(d1.to_array(), arr_dyn(&[0.0, 0.5, 0.5, 0.0]));
//! let grads = tape.backward(d1.sum()?, &[d, u])?;
//! assert!(grads.get(u).is_some());
//! # Ok::<(), diffphys_ops::OpsError>(())
//! ```

pub mod semi_lagrangian;
pub mod upwind;

pub use semi_lagrangian::{
    semi_lagrangian1, semi_lagrangian1_vjp, semi_lagrangian2, semi_lagrangian2_vjp,
    SemiLagrangian1, SemiLagrangian2,
};
pub use upwind::{upwind1, upwind1_vjp, upwind2, upwind2_vjp, Upwind1, Upwind2};

use diffphys_tape::{ArrayD, BackwardArgs, Op, Real, TapeError};
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

/// A tape op's dynamic-rank input as a view of rank `D`.
fn tape_view<'a, T: Real, D: Dimension>(
    op: &str,
    a: &ArrayViewD<'a, T>,
) -> diffphys_tape::Result<ArrayView<'a, T, D>> {
    a.clone().into_dimensionality::<D>().map_err(|_| {
        diffphys_tape::TapeError::invalid(op, format!("input of wrong rank: shape {:?}", a.shape()))
    })
}

/// The plain vector–Jacobian product of an advection scheme: the gradients of
/// `d` and `u` that a [`Wants`] asks for.
pub type AdvectionVjp<T, D, U> = Result<AdvectionGrads<Array<T, D>, Array<T, U>>>;

/// One advection step `d' = step(d, u)` of a field `d` by a velocity `u`, as the
/// pair of plain functions every scheme is: its forward and its vector–Jacobian
/// product. [`AdvectionOp`] turns any scheme into a tape op.
pub trait AdvectionScheme<T: Real> {
    /// The field's dimension (`Ix1` in 1D, `Ix2` in 2D).
    type Field: Dimension;
    /// The velocity's dimension (`Ix1` in 1D, `Ix3` for `[2, nx, ny]` in 2D).
    type Velocity: Dimension;

    /// Names the op in errors and statistics.
    fn name(&self) -> &'static str;

    /// The step.
    ///
    /// # Errors
    /// The scheme's own (shapes, CFL, non-finite velocity).
    fn step(
        &self,
        d: ArrayView<'_, T, Self::Field>,
        u: ArrayView<'_, T, Self::Velocity>,
    ) -> Result<Array<T, Self::Field>>;

    /// The vector–Jacobian product of [`AdvectionScheme::step`] for the gradient
    /// `grad_out` of `d'`.
    ///
    /// # Errors
    /// The scheme's own (shapes).
    fn vjp(
        &self,
        d: ArrayView<'_, T, Self::Field>,
        u: ArrayView<'_, T, Self::Velocity>,
        grad_out: ArrayView<'_, T, Self::Field>,
        wants: Wants,
    ) -> AdvectionVjp<T, Self::Field, Self::Velocity>;
}

/// Any [`AdvectionScheme`] as a tape op: inputs `[d, u]`, output `d'`; the
/// backward asks the scheme's vector–Jacobian product for exactly the gradients
/// the tape needs. Keeps nothing beyond its inputs and output.
///
/// The built-in schemes ([`Upwind1`], [`Upwind2`], [`SemiLagrangian1`],
/// [`SemiLagrangian2`]) are tape ops themselves (`tape.apply(scheme, &[d, u])`);
/// wrap a scheme of your own in `AdvectionOp` to record it.
#[derive(Debug, Clone, Copy)]
pub struct AdvectionOp<S>(pub S);

impl<T: Real, S: AdvectionScheme<T>> Op<T> for AdvectionOp<S> {
    fn name(&self) -> &str {
        self.0.name()
    }

    fn forward(&mut self, inputs: &[ArrayViewD<'_, T>]) -> diffphys_tape::Result<Vec<ArrayD<T>>> {
        scheme_forward(&self.0, inputs)
    }

    fn backward(
        &self,
        args: &BackwardArgs<'_, T>,
    ) -> diffphys_tape::Result<Vec<Option<ArrayD<T>>>> {
        scheme_backward(&self.0, args)
    }
}

/// The forward of a scheme recorded on a tape: `[d, u]` ↦ `[d']`.
fn scheme_forward<T: Real, S: AdvectionScheme<T>>(
    scheme: &S,
    inputs: &[ArrayViewD<'_, T>],
) -> diffphys_tape::Result<Vec<ArrayD<T>>> {
    let op = scheme.name();
    TapeError::check_arity(op, 2, inputs.len())?;
    let d = tape_view::<T, S::Field>(op, &inputs[0])?;
    let u = tape_view::<T, S::Velocity>(op, &inputs[1])?;
    Ok(vec![scheme.step(d, u)?.into_dyn()])
}

/// The backward of a scheme recorded on a tape: the gradients of `d` and `u`
/// that the tape needs.
fn scheme_backward<T: Real, S: AdvectionScheme<T>>(
    scheme: &S,
    args: &BackwardArgs<'_, T>,
) -> diffphys_tape::Result<Vec<Option<ArrayD<T>>>> {
    let op = scheme.name();
    let wants = Wants {
        field: args.needs(0),
        velocity: args.needs(1),
    };
    let g = scheme.vjp(
        tape_view::<T, S::Field>(op, args.input(0))?,
        tape_view::<T, S::Velocity>(op, args.input(1))?,
        tape_view::<T, S::Field>(op, args.grad_out())?,
        wants,
    )?;
    Ok(vec![
        g.field.map(|a| a.into_dyn()),
        g.velocity.map(|a| a.into_dyn()),
    ])
}

/// The built-in schemes are tape ops: inputs `[d, u]`, output `d'`, as
/// [`AdvectionOp`] of the scheme.
macro_rules! scheme_is_an_op {
    ($($scheme:ty),*) => {$(
        impl<T: Real> Op<T> for $scheme {
            fn name(&self) -> &str {
                AdvectionScheme::<T>::name(self)
            }

            fn forward(
                &mut self,
                inputs: &[ArrayViewD<'_, T>],
            ) -> diffphys_tape::Result<Vec<ArrayD<T>>> {
                scheme_forward(self, inputs)
            }

            fn backward(
                &self,
                args: &BackwardArgs<'_, T>,
            ) -> diffphys_tape::Result<Vec<Option<ArrayD<T>>>> {
                scheme_backward(self, args)
            }
        }
    )*};
}

scheme_is_an_op!(Upwind1, Upwind2, SemiLagrangian1, SemiLagrangian2);
