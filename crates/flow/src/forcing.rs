//! Body forces: Boussinesq buoyancy of a passive scalar, and the forces a
//! user brings ([`Forcing`]).
//!
//! A scalar `s` (temperature or smoke density, relative to the ambient value)
//! pushes the fluid along +y: on every free y-face,
//!
//! ```text
//! u_y' = u_y + dt β s̄,     s̄ = (s_below + s_above)/2
//! ```
//!
//! (beyond a side, the cell inside). Linear in `(u_y, s)`; adjoint
//! `∂L/∂u_y = g`, `∂L/∂s_c = dt β Σ_faces of c g_f / 2`.

use diffphys_tape::{ArrayD, ArrayViewD, BackwardArgs, Op, Real, TapeError};
use ndarray::{Array2, ArrayView2};

use std::sync::Arc;

use crate::boundaries::{view2, FaceKind, Faces};
use crate::buffers::{narrow, wide};
use crate::grid::FlowGrid;
use crate::Result;

/// Buoyancy of one of the state's scalars.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Buoyancy {
    /// `β`: acceleration per unit of scalar, along +y.
    pub beta: f64,
    /// Which scalar of the state drives it.
    pub scalar: usize,
}

const NAME: &str = "buoyancy";

/// The `(face, cell, weight)` terms of `s̄` on the free y-faces.
fn terms(g: &FlowGrid, faces: &Faces) -> Vec<(usize, usize, f64)> {
    let [_, nfy] = g.shape_y();
    let mut t = Vec::new();
    for i in 0..g.nx {
        for f in 0..nfy {
            let k = i * nfy + f;
            if faces.y[k] != FaceKind::Free {
                continue;
            }
            let (lo, hi) = g.y_face_cells(f);
            let cells: Vec<usize> = [lo, hi].into_iter().flatten().collect();
            let w = 1.0 / cells.len() as f64;
            for j in cells {
                t.push((k, i * g.ny + j, w));
            }
        }
    }
    t
}

/// `u_y + dt β s̄` on the free y-faces (see the [module docs](self)).
///
/// # Errors
/// [`crate::FlowError::Shape`] for wrong shapes.
pub fn buoyancy<T: Real>(
    grid: &FlowGrid,
    faces: &Faces,
    beta: f64,
    dt: f64,
    uy: ArrayView2<'_, T>,
    s: ArrayView2<'_, T>,
) -> Result<Array2<T>> {
    grid.check_component(NAME, "y-velocity", grid.shape_y(), uy)?;
    grid.check_cells(NAME, "scalar", s)?;
    let mut u = wide(uy).into_owned();
    let s = wide(s);
    for (k, c, w) in terms(grid, faces) {
        u[k] += dt * beta * w * s[c];
    }
    Ok(narrow(grid.shape_y(), u))
}

/// The vector–Jacobian product of [`buoyancy`]: `(∂L/∂u_y, ∂L/∂s)`.
///
/// # Errors
/// [`crate::FlowError::Shape`] for wrong shapes.
pub fn buoyancy_vjp<T: Real>(
    grid: &FlowGrid,
    faces: &Faces,
    beta: f64,
    dt: f64,
    grad: ArrayView2<'_, T>,
) -> Result<(Array2<T>, Array2<T>)> {
    grid.check_component(NAME, "gradient", grid.shape_y(), grad)?;
    let g = wide(grad);
    let mut gs = vec![0.0; grid.nx * grid.ny];
    for (k, c, w) in terms(grid, faces) {
        gs[c] += dt * beta * w * g[k];
    }
    Ok((grad.to_owned(), narrow(grid.cell_shape(), gs)))
}

/// [`buoyancy`] as a tape op: inputs `[u_y, s]`, output `[u_y']`.
#[derive(Debug, Clone)]
pub struct Buoyant {
    /// The grid.
    pub grid: FlowGrid,
    /// Its faces: the force acts on the free ones.
    pub faces: Arc<Faces>,
    /// `β`.
    pub beta: f64,
    /// The time step.
    pub dt: f64,
}

impl<T: Real> Op<T> for Buoyant {
    fn name(&self) -> &str {
        NAME
    }

    fn forward(&mut self, inputs: &[ArrayViewD<'_, T>]) -> diffphys_tape::Result<Vec<ArrayD<T>>> {
        TapeError::check_arity(NAME, 2, inputs.len())?;
        let u = buoyancy(
            &self.grid,
            &self.faces,
            self.beta,
            self.dt,
            view2(&inputs[0])?,
            view2(&inputs[1])?,
        )?;
        Ok(vec![u.into_dyn()])
    }

    fn backward(
        &self,
        args: &BackwardArgs<'_, T>,
    ) -> diffphys_tape::Result<Vec<Option<ArrayD<T>>>> {
        let (gu, gs) = buoyancy_vjp(
            &self.grid,
            &self.faces,
            self.beta,
            self.dt,
            view2(args.grad_out())?,
        )?;
        Ok(vec![
            args.needs(0).then(|| gu.into_dyn()),
            args.needs(1).then(|| gs.into_dyn()),
        ])
    }
}

/// A body force a user brings to the step without editing the crate: a plain
/// forward and its vector–Jacobian product on `f64` face arrays. The step
/// ([`crate::SceneBuilder::forcing`]) applies it after advection, on the free
/// faces only:
///
/// ```text
/// u' = u + M ⊙ Δ(u),        ∂L/∂u = g + (∂Δ/∂u)ᵀ (M ⊙ g)
/// ```
///
/// with `Δ = (Δu_x, Δu_y)` = [`Forcing::increment`] over the step's `dt` and
/// `M` the mask of free faces (walls, inflow and the obstacle keep their
/// values). The adjoint is [`Forcing::increment_vjp`]; the step records one
/// op ([`Forced`]) that keeps nothing beyond its inputs.
pub trait Forcing: Send + Sync + std::fmt::Debug {
    /// Its name (the tape op's, and in errors).
    fn name(&self) -> &str;

    /// The velocity increments `(Δu_x, Δu_y)` over a step of `dt` at the
    /// velocity `(u_x, u_y)` (shapes [`FlowGrid::shape_x`], [`FlowGrid::shape_y`]).
    fn increment(
        &self,
        grid: &FlowGrid,
        dt: f64,
        ux: ArrayView2<'_, f64>,
        uy: ArrayView2<'_, f64>,
    ) -> (Array2<f64>, Array2<f64>);

    /// `(∂Δ/∂u)ᵀ (g_x, g_y)` at `(u_x, u_y)`: the gradients with respect to
    /// the velocity, given `(g_x, g_y)` with respect to the increments.
    fn increment_vjp(
        &self,
        grid: &FlowGrid,
        dt: f64,
        ux: ArrayView2<'_, f64>,
        uy: ArrayView2<'_, f64>,
        gx: ArrayView2<'_, f64>,
        gy: ArrayView2<'_, f64>,
    ) -> (Array2<f64>, Array2<f64>);
}

/// `(M_x, M_y)`: 1 on the free faces, 0 on the fixed ones.
fn free_mask(grid: &FlowGrid, faces: &Faces) -> (Array2<f64>, Array2<f64>) {
    let mask = |shape: [usize; 2], kinds: &[FaceKind]| {
        let values = kinds
            .iter()
            .map(|k| if *k == FaceKind::Free { 1.0 } else { 0.0 })
            .collect();
        Array2::from_shape_vec(shape, values).expect("one kind per face")
    };
    (
        mask(grid.shape_x(), &faces.x),
        mask(grid.shape_y(), &faces.y),
    )
}

/// A user's [`Forcing`] as a tape op: inputs `[u_x, u_y]`, outputs
/// `[u_x', u_y']` (see [`Forcing`] for the formula and its adjoint).
#[derive(Debug, Clone)]
pub struct Forced {
    /// The grid.
    pub grid: FlowGrid,
    /// Its faces: the force acts on the free ones.
    pub faces: Arc<Faces>,
    /// The force.
    pub forcing: Arc<dyn Forcing>,
    /// The time step.
    pub dt: f64,
}

impl Forced {
    fn velocity<T: Real>(
        &self,
        inputs: &[ArrayViewD<'_, T>],
    ) -> diffphys_tape::Result<(Array2<f64>, Array2<f64>)> {
        TapeError::check_arity(self.forcing.name(), 2, inputs.len())?;
        let (ux, uy) = (view2(&inputs[0])?, view2(&inputs[1])?);
        let name = self.forcing.name();
        self.grid
            .check_component(name, "x-velocity", self.grid.shape_x(), ux)?;
        self.grid
            .check_component(name, "y-velocity", self.grid.shape_y(), uy)?;
        Ok((as_f64(ux), as_f64(uy)))
    }
}

/// `a` in `f64`, as an array of its shape.
fn as_f64<T: Real>(a: ArrayView2<'_, T>) -> Array2<f64> {
    Array2::from_shape_vec(a.raw_dim(), wide(a).into_owned()).expect("one value per entry")
}

/// `a` as a `T` array of `shape`.
fn as_t<T: Real>(shape: [usize; 2], a: Array2<f64>) -> ArrayD<T> {
    narrow::<T>(shape, a.iter().copied().collect()).into_dyn()
}

impl<T: Real> Op<T> for Forced {
    fn name(&self) -> &str {
        self.forcing.name()
    }

    fn forward(&mut self, inputs: &[ArrayViewD<'_, T>]) -> diffphys_tape::Result<Vec<ArrayD<T>>> {
        let (ux, uy) = self.velocity(inputs)?;
        let (dx, dy) = self
            .forcing
            .increment(&self.grid, self.dt, ux.view(), uy.view());
        let (mx, my) = free_mask(&self.grid, &self.faces);
        Ok(vec![
            as_t(self.grid.shape_x(), ux + dx * mx),
            as_t(self.grid.shape_y(), uy + dy * my),
        ])
    }

    fn backward(
        &self,
        args: &BackwardArgs<'_, T>,
    ) -> diffphys_tape::Result<Vec<Option<ArrayD<T>>>> {
        let inputs = [args.input(0).clone(), args.input(1).clone()];
        let (ux, uy) = self.velocity(&inputs)?;
        let (mx, my) = free_mask(&self.grid, &self.faces);
        let g = |i: usize| -> diffphys_tape::Result<Array2<f64>> {
            Ok(as_f64(view2(&args.grad_output_or_zeros(i).view())?))
        };
        let (gx, gy) = (g(0)?, g(1)?);
        let (jx, jy) = self.forcing.increment_vjp(
            &self.grid,
            self.dt,
            ux.view(),
            uy.view(),
            (&gx * &mx).view(),
            (&gy * &my).view(),
        );
        Ok(vec![
            args.needs(0).then(|| as_t(self.grid.shape_x(), gx + jx)),
            args.needs(1).then(|| as_t(self.grid.shape_y(), gy + jy)),
        ])
    }
}
