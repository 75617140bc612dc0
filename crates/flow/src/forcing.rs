//! Body forces: Boussinesq buoyancy of a passive scalar.
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
