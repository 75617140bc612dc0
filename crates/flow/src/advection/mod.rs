//! Advection: semi-Lagrangian and MacCormack transport of the staggered
//! velocity by itself, and of passive scalars by the velocity.
//!
//! **Semi-Lagrangian.** Each free entry `q_k` of a field at `x_k` (a face of
//! its component, or a cell centre for a scalar) is traced back along the
//! velocity at `x_k` and the field interpolated there (bilinear on its own
//! lattice, with the side conditions' ghost values beyond the walls):
//!
//! ```text
//! q'_k = I_q(x_k − dt v(x_k)),     v = (I_ux, I_uy)
//! ```
//!
//! **MacCormack** (Selle et al. 2008) corrects the semi-Lagrangian step `A` by
//! the error of a round trip: `q̂ = A q`, `q̃ = A⁻ q̂` (the same step with `−dt`),
//! `q' = q̂ + (q − q̃)/2`, second order in space and time for smooth fields.
//! The limiter clamps `q'` into the range of the four values the forward step
//! interpolated from, which keeps it free of new extrema (and lowers the order
//! where it acts).
//!
//! **Adjoint.** The interpolation is linear in the field and (through the
//! ghosts) in the wall speeds, and piecewise bilinear in the departure point:
//! `∂L/∂q` scatters `g_k` to the four corners with the interpolation weights,
//! and `∂L/∂u` is `g_k ∇I_q(x_dep) · (−dt) ∂v(x_k)/∂u`, scattered with the
//! weights that interpolated `v(x_k)`. A departure point clamped at a boundary
//! does not move with `u` along that axis. MacCormack's adjoint chains those of
//! its two semi-Lagrangian steps; where the limiter clamps, the gradient goes
//! to the corner that was chosen. Fixed faces (walls, inflow, obstacle) are
//! passed through unchanged.
//!
//! # References
//! - J. Stam, *Stable fluids*, SIGGRAPH 1999 (semi-Lagrangian self-advection).
//! - A. Selle, R. Fedkiw, B. Kim, Y. Liu, J. Rossignac, *An unconditionally
//!   stable MacCormack method*, J. Sci. Comput. 35 (2008) 350–371.

use diffphys_tape::{ArrayD, ArrayViewD, BackwardArgs, Op, Real, TapeError};
use ndarray::{Array1, Array2, ArrayView1, ArrayView2};

use std::sync::Arc;

use crate::boundaries::{view1, view2, Faces};
use crate::buffers::{give_back, join, narrow, walls_of, wide};
use crate::grid::{FlowGrid, Lattice};
use crate::Result;

mod lanes;
mod maccormack;
mod maccormack_vjp;
mod sampling;
mod tracer;

pub(crate) use tracer::PARALLEL_FROM;
use tracer::{field_of, tracer, Grads};

/// An advection scheme.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Advection {
    /// First order, unconditionally stable.
    SemiLagrangian,
    /// Second order; `limiter` clamps to the interpolated range.
    MacCormack {
        /// Clamp to the range of the interpolated values.
        limiter: bool,
    },
}

/// The gradients of [`advect_velocity`].
#[derive(Debug, Clone, PartialEq)]
pub struct VelocityAdvectionGrads<T> {
    /// `∂L/∂q_x`.
    pub field_x: Array2<T>,
    /// `∂L/∂q_y`.
    pub field_y: Array2<T>,
    /// `∂L/∂u_x`.
    pub ux: Array2<T>,
    /// `∂L/∂u_y`.
    pub uy: Array2<T>,
    /// `∂L/∂U` of the four wall speeds.
    pub wall_speed: Array1<T>,
}

/// The gradients of [`advect_scalar`].
#[derive(Debug, Clone, PartialEq)]
pub struct ScalarAdvectionGrads<T> {
    /// `∂L/∂s`.
    pub scalar: Array2<T>,
    /// `∂L/∂u_x`.
    pub ux: Array2<T>,
    /// `∂L/∂u_y`.
    pub uy: Array2<T>,
    /// `∂L/∂U` of the four wall speeds.
    pub wall_speed: Array1<T>,
}

const VELOCITY: &str = "velocity advection";
const SCALAR: &str = "scalar advection";

/// Advection of the staggered field `(q_x, q_y)` by `scheme` over `dt`,
/// traced by the velocity `(u_x, u_y)`: each component becomes `A q` (see the
/// [module docs](self)); `wall_speed` holds the four wall speeds `U`.
/// Self-advection passes the velocity as both; the incremental splitting
/// advects `u − (dt/2)∇P` traced by `u`.
///
/// # Errors
/// [`crate::FlowError::Shape`] for arrays of the wrong shapes.
pub fn advect_velocity<T: Real>(
    grid: &FlowGrid,
    faces: &Faces,
    scheme: Advection,
    dt: f64,
    field: (ArrayView2<'_, T>, ArrayView2<'_, T>),
    velocity: (ArrayView2<'_, T>, ArrayView2<'_, T>),
    wall_speed: ArrayView1<'_, T>,
) -> Result<(Array2<T>, Array2<T>)> {
    grid.check_velocity(VELOCITY, field.0, field.1)?;
    grid.check_velocity(VELOCITY, velocity.0, velocity.1)?;
    grid.check_walls(VELOCITY, wall_speed)?;
    let (ux, uy) = (wide(velocity.0), wide(velocity.1));
    let tr = tracer(grid, &ux, &uy, walls_of(wall_speed));
    let g = grid;
    // the two components are independent: on two threads when there are
    let (ox, oy) = join(
        || {
            tr.step(
                &field_of(grid, faces, Lattice::FaceX),
                &wide(field.0),
                dt,
                scheme,
            )
        },
        || {
            tr.step(
                &field_of(grid, faces, Lattice::FaceY),
                &wide(field.1),
                dt,
                scheme,
            )
        },
    );
    Ok((narrow(g.shape_x(), ox), narrow(g.shape_y(), oy)))
}

/// The vector–Jacobian product of [`advect_velocity`] with the gradients
/// `grad_x`, `grad_y` of its outputs.
///
/// # Errors
/// As [`advect_velocity`].
#[allow(clippy::too_many_arguments)]
pub fn advect_velocity_vjp<T: Real>(
    grid: &FlowGrid,
    faces: &Faces,
    scheme: Advection,
    dt: f64,
    field: (ArrayView2<'_, T>, ArrayView2<'_, T>),
    velocity: (ArrayView2<'_, T>, ArrayView2<'_, T>),
    wall_speed: ArrayView1<'_, T>,
    grad: (ArrayView2<'_, T>, ArrayView2<'_, T>),
) -> Result<VelocityAdvectionGrads<T>> {
    grid.check_velocity(VELOCITY, field.0, field.1)?;
    grid.check_velocity(VELOCITY, velocity.0, velocity.1)?;
    grid.check_velocity(VELOCITY, grad.0, grad.1)?;
    grid.check_walls(VELOCITY, wall_speed)?;
    let (ux, uy) = (wide(velocity.0), wide(velocity.1));
    let tr = tracer(grid, &ux, &uy, walls_of(wall_speed));
    let (nx, ny) = (ux.len(), uy.len());
    // each component's products land in gradients of its own, added after
    // in a fixed order: on two threads, the same bits as on one
    let component = |lattice: Lattice, q: ArrayView2<'_, T>, g: ArrayView2<'_, T>, nq: usize| {
        let mut grads = Grads::zeros(nq, nx, ny);
        tr.step_vjp(
            &field_of(grid, faces, lattice),
            &wide(q),
            dt,
            scheme,
            &wide(g),
            &mut grads,
        );
        grads
    };
    let (mut gx, gy) = join(
        || component(Lattice::FaceX, field.0, grad.0, nx),
        || component(Lattice::FaceY, field.1, grad.1, ny),
    );
    // the velocity traces both components
    for (a, b) in [(&mut gx.ux, &gy.ux), (&mut gx.uy, &gy.uy)] {
        a.iter_mut().zip(b.iter()).for_each(|(x, y)| *x += y);
    }
    give_back(gy.ux);
    give_back(gy.uy);
    let g = grid;
    Ok(VelocityAdvectionGrads {
        field_x: narrow(g.shape_x(), gx.q),
        field_y: narrow(g.shape_y(), gy.q),
        ux: narrow(g.shape_x(), gx.ux),
        uy: narrow(g.shape_y(), gx.uy),
        wall_speed: (0..4)
            .map(|s| T::from_f64(gx.walls[s] + gy.walls[s]))
            .collect(),
    })
}

/// Advection of a cell-centred scalar `s` by the velocity over `dt`
/// (zero-gradient beyond non-periodic sides).
///
/// # Errors
/// [`crate::FlowError::Shape`] for arrays of the wrong shapes.
#[allow(clippy::too_many_arguments)]
pub fn advect_scalar<T: Real>(
    grid: &FlowGrid,
    faces: &Faces,
    scheme: Advection,
    dt: f64,
    s: ArrayView2<'_, T>,
    ux: ArrayView2<'_, T>,
    uy: ArrayView2<'_, T>,
    wall_speed: ArrayView1<'_, T>,
) -> Result<Array2<T>> {
    grid.check_velocity(SCALAR, ux, uy)?;
    grid.check_cells(SCALAR, "scalar", s)?;
    grid.check_walls(SCALAR, wall_speed)?;
    let (ux, uy) = (wide(ux), wide(uy));
    let tr = tracer(grid, &ux, &uy, walls_of(wall_speed));
    let out = tr.step(&field_of(grid, faces, Lattice::Cell), &wide(s), dt, scheme);
    Ok(narrow(grid.cell_shape(), out))
}

/// The vector–Jacobian product of [`advect_scalar`] with the gradient `grad`
/// of its output.
///
/// # Errors
/// As [`advect_scalar`].
#[allow(clippy::too_many_arguments)]
pub fn advect_scalar_vjp<T: Real>(
    grid: &FlowGrid,
    faces: &Faces,
    scheme: Advection,
    dt: f64,
    s: ArrayView2<'_, T>,
    ux: ArrayView2<'_, T>,
    uy: ArrayView2<'_, T>,
    wall_speed: ArrayView1<'_, T>,
    grad: ArrayView2<'_, T>,
) -> Result<ScalarAdvectionGrads<T>> {
    grid.check_velocity(SCALAR, ux, uy)?;
    grid.check_cells(SCALAR, "scalar", s)?;
    grid.check_cells(SCALAR, "gradient", grad)?;
    grid.check_walls(SCALAR, wall_speed)?;
    let (uxw, uyw) = (wide(ux), wide(uy));
    let tr = tracer(grid, &uxw, &uyw, walls_of(wall_speed));
    let sw = wide(s);
    let mut g = Grads::zeros(sw.len(), uxw.len(), uyw.len());
    tr.step_vjp(
        &field_of(grid, faces, Lattice::Cell),
        &sw,
        dt,
        scheme,
        &wide(grad),
        &mut g,
    );
    Ok(ScalarAdvectionGrads {
        scalar: narrow(grid.cell_shape(), g.q),
        ux: narrow(grid.shape_x(), g.ux),
        uy: narrow(grid.shape_y(), g.uy),
        wall_speed: (0..4).map(|s| T::from_f64(g.walls[s])).collect(),
    })
}

/// [`advect_velocity`] as a tape op: inputs `[q_x, q_y, u_x, u_y,
/// wall_speed]`, outputs `[q_x', q_y']`.
#[derive(Debug, Clone)]
pub struct AdvectVelocity {
    /// The grid.
    pub grid: FlowGrid,
    /// Its faces: fixed ones are passed through.
    pub faces: Arc<Faces>,
    /// The scheme.
    pub scheme: Advection,
    /// The time step.
    pub dt: f64,
}

impl<T: Real> Op<T> for AdvectVelocity {
    fn name(&self) -> &str {
        VELOCITY
    }

    fn forward(&mut self, inputs: &[ArrayViewD<'_, T>]) -> diffphys_tape::Result<Vec<ArrayD<T>>> {
        TapeError::check_arity(VELOCITY, 5, inputs.len())?;
        let (a, b) = advect_velocity(
            &self.grid,
            &self.faces,
            self.scheme,
            self.dt,
            (view2(&inputs[0])?, view2(&inputs[1])?),
            (view2(&inputs[2])?, view2(&inputs[3])?),
            view1(&inputs[4])?,
        )?;
        Ok(vec![a.into_dyn(), b.into_dyn()])
    }

    fn backward(
        &self,
        args: &BackwardArgs<'_, T>,
    ) -> diffphys_tape::Result<Vec<Option<ArrayD<T>>>> {
        let gx = args.grad_output_or_zeros(0);
        let gy = args.grad_output_or_zeros(1);
        let g = advect_velocity_vjp(
            &self.grid,
            &self.faces,
            self.scheme,
            self.dt,
            (view2(args.input(0))?, view2(args.input(1))?),
            (view2(args.input(2))?, view2(args.input(3))?),
            view1(args.input(4))?,
            (view2(&gx.view())?, view2(&gy.view())?),
        )?;
        Ok(vec![
            args.needs(0).then(|| g.field_x.into_dyn()),
            args.needs(1).then(|| g.field_y.into_dyn()),
            args.needs(2).then(|| g.ux.into_dyn()),
            args.needs(3).then(|| g.uy.into_dyn()),
            args.needs(4).then(|| g.wall_speed.into_dyn()),
        ])
    }
}

/// [`advect_scalar`] as a tape op: inputs `[s, u_x, u_y, wall_speed]`,
/// output `[s']`.
#[derive(Debug, Clone)]
pub struct AdvectScalar {
    /// The grid.
    pub grid: FlowGrid,
    /// Its faces: fixed ones are passed through.
    pub faces: Arc<Faces>,
    /// The scheme.
    pub scheme: Advection,
    /// The time step.
    pub dt: f64,
}

impl<T: Real> Op<T> for AdvectScalar {
    fn name(&self) -> &str {
        SCALAR
    }

    fn forward(&mut self, inputs: &[ArrayViewD<'_, T>]) -> diffphys_tape::Result<Vec<ArrayD<T>>> {
        TapeError::check_arity(SCALAR, 4, inputs.len())?;
        let s = advect_scalar(
            &self.grid,
            &self.faces,
            self.scheme,
            self.dt,
            view2(&inputs[0])?,
            view2(&inputs[1])?,
            view2(&inputs[2])?,
            view1(&inputs[3])?,
        )?;
        Ok(vec![s.into_dyn()])
    }

    fn backward(
        &self,
        args: &BackwardArgs<'_, T>,
    ) -> diffphys_tape::Result<Vec<Option<ArrayD<T>>>> {
        let g = advect_scalar_vjp(
            &self.grid,
            &self.faces,
            self.scheme,
            self.dt,
            view2(args.input(0))?,
            view2(args.input(1))?,
            view2(args.input(2))?,
            view1(args.input(3))?,
            view2(args.grad_out())?,
        )?;
        Ok(vec![
            args.needs(0).then(|| g.scalar.into_dyn()),
            args.needs(1).then(|| g.ux.into_dyn()),
            args.needs(2).then(|| g.uy.into_dyn()),
            args.needs(3).then(|| g.wall_speed.into_dyn()),
        ])
    }
}
