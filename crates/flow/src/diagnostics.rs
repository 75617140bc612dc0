//! What a flow reports: divergence, vorticity, and the force of the flow on
//! the obstacle (drag and lift) as differentiable scalars.
//!
//! - **Divergence** `D u` per cell over all faces (`(u_x[i+1,j] − u_x[i,j])/dx +
//!   (u_y[i,j+1] − u_y[i,j])/dy`). Linear; adjoint `Dᵀ g = −G g`.
//! - **Vorticity** `ω = ∂u_y/∂x − ∂u_x/∂y` at the grid nodes `(i dx, j dy)`
//!   inside the domain (all nodes along a periodic axis): shape
//!   `[nx − 1, ny − 1]` in a closed box. Linear; the adjoint scatters back.
//! - **Force on the obstacle** `F = (F_x, F_y)` (drag and lift for a flow
//!   along x), by the surface integral over the staircase boundary of the
//!   pressure and the wall shear, density 1:
//!
//!   ```text
//!   F = Σ_faces fluid|solid  P_fluid · n · A_f          (n: into the solid)
//!     + Σ_faces fluid|solid  ν · ū_t / (h_n/2) · A_f     (ū_t: tangential velocity of the fluid cell)
//!   ```
//!
//!   `P` is the pressure of the state ([`crate::FlowState::pressure`]); `ū_t`
//!   the mean of the fluid cell's two tangential faces, the wall at half a
//!   cell. Linear in `(u, P)` for a given `ν`; adjoint the same weights, and
//!   `∂F/∂ν` the shear term over `ν`. A staircase body converges at first
//!   order in `h`.
//!
//!   [`ForceWeights::momentum_exchange`] gives the same op the momentum the
//!   step itself takes out of the fluid at the body: the same pressure term,
//!   and for the viscous term `ν u_f A / d` on every link of the five-point
//!   Laplacian from a free face `f` to an obstacle face, tangential and
//!   normal links alike. On the DFG 2D-1 cylinder the wall-shear model above
//!   misses the normal links' lift, which does not fall with `h`
//!   (docs/10-flow.md, "What the step exchanges with the body").
//!
//! Divergence and vorticity read only the grid: they take a [`FlowGrid`] or
//! anything that holds one (`AsRef<FlowGrid>`, such as a [`crate::Scene`]).

use std::sync::Arc;

use diffphys_tape::{ArrayD, ArrayViewD, BackwardArgs, Op, Real, TapeError};
use ndarray::{Array1, Array2, ArrayView2, IxDyn};

use crate::boundaries::{scalar_of, view2};
use crate::buffers::{narrow, wide};
use crate::grid::{FlowGrid, Lattice};
use crate::staggered::{divergence_wide, gradient_wide};
use crate::Result;

/// `D u` on the cells.
///
/// # Errors
/// [`crate::FlowError::Shape`] for wrong shapes.
pub fn divergence<T: Real, G: AsRef<FlowGrid> + ?Sized>(
    grid: &G,
    ux: ArrayView2<'_, T>,
    uy: ArrayView2<'_, T>,
) -> Result<Array2<T>> {
    let grid = grid.as_ref();
    grid.check_velocity("divergence", ux, uy)?;
    let d = divergence_wide(grid, None, &wide(ux), &wide(uy));
    Ok(narrow(grid.cell_shape(), d))
}

/// The vector–Jacobian product of [`divergence`]: `Dᵀ g = −G g`.
///
/// # Errors
/// [`crate::FlowError::Shape`] for wrong shapes.
pub fn divergence_vjp<T: Real, G: AsRef<FlowGrid> + ?Sized>(
    grid: &G,
    grad: ArrayView2<'_, T>,
) -> Result<(Array2<T>, Array2<T>)> {
    let g = grid.as_ref();
    g.check_cells("divergence", "gradient", grad)?;
    let (gx, gy) = gradient_wide(g, None, &wide(grad));
    let neg = |v: Vec<f64>| v.into_iter().map(|x| -x).collect::<Vec<_>>();
    Ok((narrow(g.shape_x(), neg(gx)), narrow(g.shape_y(), neg(gy))))
}

/// `max |D u|` over the fluid cells (`solid`: the solid cells, `[nx, ny]`).
///
/// # Errors
/// [`crate::FlowError::Shape`] for wrong shapes.
pub fn max_divergence<T: Real>(
    grid: &FlowGrid,
    solid: &Array2<bool>,
    ux: ArrayView2<'_, T>,
    uy: ArrayView2<'_, T>,
) -> Result<f64> {
    grid.check_component("divergence", "solid cells", grid.cell_shape(), solid.view())?;
    let d = divergence(grid, ux, uy)?;
    Ok(d.iter()
        .zip(solid.iter())
        .filter(|(_, &s)| !s)
        .fold(0.0, |m, (v, _)| m.max(v.as_f64().abs())))
}

/// `(node, component, face, coefficient)`: one term of a linear diagnostic.
type Term = (usize, usize, usize, f64);

/// The terms of the vorticity and its shape.
fn vorticity_terms(g: &FlowGrid) -> ([usize; 2], Vec<Term>) {
    let (nx, ny) = (g.nx, g.ny);
    let is: Vec<usize> = if g.periodic_x() {
        (0..nx).collect()
    } else {
        (1..nx).collect()
    };
    let js: Vec<usize> = if g.periodic_y() {
        (0..ny).collect()
    } else {
        (1..ny).collect()
    };
    let [_, nfy] = g.shape_y();
    let mut t = Vec::new();
    for (a, &i) in is.iter().enumerate() {
        for (b, &j) in js.iter().enumerate() {
            let node = a * js.len() + b;
            // ∂u_y/∂x: the y-faces of columns i − 1 and i on row-face j
            let (il, ir) = ((i + nx - 1) % nx, i % nx);
            t.push((node, 1, il * nfy + j, -1.0 / g.dx));
            t.push((node, 1, ir * nfy + j, 1.0 / g.dx));
            // −∂u_x/∂y: the x-faces i on rows j − 1 and j
            let (jb, jt) = ((j + ny - 1) % ny, j % ny);
            t.push((node, 0, i * ny + jb, 1.0 / g.dy));
            t.push((node, 0, i * ny + jt, -1.0 / g.dy));
        }
    }
    ([is.len(), js.len()], t)
}

/// The vorticity at the inner grid nodes (see the [module docs](self)).
///
/// # Errors
/// [`crate::FlowError::Shape`] for wrong shapes.
pub fn vorticity<T: Real, G: AsRef<FlowGrid> + ?Sized>(
    grid: &G,
    ux: ArrayView2<'_, T>,
    uy: ArrayView2<'_, T>,
) -> Result<Array2<T>> {
    let grid = grid.as_ref();
    grid.check_velocity("vorticity", ux, uy)?;
    let (shape, terms) = vorticity_terms(grid);
    let u = [wide(ux), wide(uy)];
    let mut w = vec![0.0; shape[0] * shape[1]];
    for (n, c, f, k) in terms {
        w[n] += k * u[c][f];
    }
    Ok(narrow(shape, w))
}

/// The vector–Jacobian product of [`vorticity`]: `(∂L/∂u_x, ∂L/∂u_y)`.
///
/// # Errors
/// [`crate::FlowError::Shape`] for a gradient of the wrong shape.
pub fn vorticity_vjp<T: Real, G: AsRef<FlowGrid> + ?Sized>(
    grid: &G,
    grad: ArrayView2<'_, T>,
) -> Result<(Array2<T>, Array2<T>)> {
    let grid = grid.as_ref();
    let (shape, terms) = vorticity_terms(grid);
    grid.check_component("vorticity", "gradient", shape, grad)?;
    let g = wide(grad);
    let mut out = [
        vec![0.0; grid.shape_x().iter().product()],
        vec![0.0; grid.shape_y().iter().product()],
    ];
    for (n, c, f, k) in terms {
        out[c][f] += k * g[n];
    }
    let [ox, oy] = out;
    Ok((narrow(grid.shape_x(), ox), narrow(grid.shape_y(), oy)))
}

/// The staircase surface of an obstacle as the weights of its force,
/// `F_d = Σ P_c wp + ν Σ u_f wu` (see the [module docs](self)): what
/// [`obstacle_force`] sums. Built once per grid and obstacle.
#[derive(Debug, Clone, PartialEq)]
pub struct ForceWeights {
    grid: FlowGrid,
    /// `(cell, direction, weight)`.
    pressure: Vec<(usize, usize, f64)>,
    /// `(component, face, direction, weight)`.
    shear: Vec<(usize, usize, usize, f64)>,
}

impl ForceWeights {
    /// The weights of the faces between fluid and `solid` cells of `grid`.
    ///
    /// # Panics
    /// If `solid` is not `[nx, ny]`.
    pub fn new(grid: &FlowGrid, solid: &Array2<bool>) -> Self {
        assert_eq!(solid.shape(), grid.cell_shape(), "one solid flag per cell");
        let (nx, ny) = (grid.nx, grid.ny);
        let mut w = ForceWeights {
            grid: grid.clone(),
            pressure: Vec::new(),
            shear: Vec::new(),
        };
        let [nfx, _] = grid.shape_x();
        let [_, nfy] = grid.shape_y();
        // x-faces: pressure along x, shear along y from u_y.
        for f in 0..nfx {
            let (Some(lo), Some(hi)) = grid.x_face_cells(f) else {
                continue;
            };
            for j in 0..ny {
                let (sl, sh) = (solid[[lo, j]], solid[[hi, j]]);
                if sl == sh {
                    continue;
                }
                let (fluid, sign) = if sh { (lo, 1.0) } else { (hi, -1.0) };
                w.pressure.push((fluid * ny + j, 0, sign * grid.dy));
                let (jb, jt) = (
                    j,
                    if grid.periodic_y() {
                        (j + 1) % ny
                    } else {
                        j + 1
                    },
                );
                let c = grid.dy / grid.dx;
                w.shear.push((1, fluid * nfy + jb, 1, c));
                w.shear.push((1, fluid * nfy + jt, 1, c));
            }
        }
        // y-faces: pressure along y, shear along x from u_x.
        for f in 0..nfy {
            let (Some(lo), Some(hi)) = grid.y_face_cells(f) else {
                continue;
            };
            for i in 0..nx {
                let (sl, sh) = (solid[[i, lo]], solid[[i, hi]]);
                if sl == sh {
                    continue;
                }
                let (fluid, sign) = if sh { (lo, 1.0) } else { (hi, -1.0) };
                w.pressure.push((i * ny + fluid, 1, sign * grid.dx));
                let (il, ir) = (
                    i,
                    if grid.periodic_x() {
                        (i + 1) % nx
                    } else {
                        i + 1
                    },
                );
                let c = grid.dx / grid.dy;
                w.shear.push((0, il * ny + fluid, 0, c));
                w.shear.push((0, ir * ny + fluid, 0, c));
            }
        }
        w
    }
}

impl ForceWeights {
    /// The obstacle's surface as the step's momentum balance sees it: the
    /// pressure weights of [`ForceWeights::new`] (the momentum the projection
    /// takes from the fluid at the body is exactly `Σ P_fluid n A_f`), and for
    /// the viscous part one link per free face `f` and neighbouring obstacle
    /// face `s` of the five-point Laplacian that the viscosity step applies,
    ///
    /// ```text
    /// F_visc = Σ_links ν (u_f − u_s) A / d = Σ_links ν u_f A / d   (u_s = 0)
    /// ```
    ///
    /// (`A / d` = `dy/dx` for a link along x, `dx/dy` along y, per unit
    /// depth), in both directions: a face beside a tread and one before a
    /// riser alike. This
    /// is the momentum the discrete viscosity takes out of the fluid at the
    /// body (with explicit viscosity, the momentum change of one viscosity
    /// step over `dt`, exactly), where [`ForceWeights::new`] models a
    /// continuous wall's shear, `ν ū_t / (h/2)` on each face, tangential
    /// links only. Linear in `u` like it; adjoint the same weights.
    ///
    /// # Panics
    /// If `solid` is not `[nx, ny]`.
    pub fn momentum_exchange(grid: &FlowGrid, solid: &Array2<bool>) -> Self {
        let mut w = ForceWeights::new(grid, solid);
        w.shear.clear();
        let lattices = [(0, Lattice::FaceX), (1, Lattice::FaceY)];
        for (d, lattice) in lattices {
            let [na, nb] = grid.shape(lattice);
            // a face of the obstacle: one of its cells is solid
            let body = |a: usize, b: usize| match lattice {
                Lattice::FaceX => {
                    let (lo, hi) = grid.x_face_cells(a);
                    [lo, hi].into_iter().flatten().any(|c| solid[[c, b]])
                }
                _ => {
                    let (lo, hi) = grid.y_face_cells(b);
                    [lo, hi].into_iter().flatten().any(|c| solid[[a, c]])
                }
            };
            let normal_index = |a: usize, b: usize| if d == 0 { a } else { b };
            let axes = [
                (na, grid.periodic_x(), grid.dy / grid.dx, true),
                (nb, grid.periodic_y(), grid.dx / grid.dy, false),
            ];
            for a in 0..na {
                for b in 0..nb {
                    let on_side = grid.boundary_side(lattice, normal_index(a, b)).is_some();
                    if on_side || body(a, b) {
                        continue;
                    }
                    for (n, periodic, weight, along_a) in axes {
                        let i = if along_a { a } else { b };
                        for step in [-1i64, 1] {
                            let j = i as i64 + step;
                            let j = if periodic {
                                j.rem_euclid(n as i64) as usize
                            } else if (0..n as i64).contains(&j) {
                                j as usize
                            } else {
                                continue;
                            };
                            let (sa, sb) = if along_a { (j, b) } else { (a, j) };
                            if body(sa, sb) {
                                w.shear.push((d, a * nb + b, d, weight));
                            }
                        }
                    }
                }
            }
        }
        w
    }
}

/// The gradients of [`obstacle_force`].
#[derive(Debug, Clone, PartialEq)]
pub struct ForceGrads<T> {
    /// `∂L/∂u_x`.
    pub ux: Array2<T>,
    /// `∂L/∂u_y`.
    pub uy: Array2<T>,
    /// `∂L/∂P`.
    pub pressure: Array2<T>,
    /// `∂L/∂ν`.
    pub viscosity: T,
}

const FORCE: &str = "obstacle force";

/// The force `[F_x, F_y]` of the flow on the obstacle (see the
/// [module docs](self)); zero without an obstacle.
///
/// # Errors
/// [`crate::FlowError::Shape`] for wrong shapes.
pub fn obstacle_force<T: Real>(
    w: &ForceWeights,
    ux: ArrayView2<'_, T>,
    uy: ArrayView2<'_, T>,
    pressure: ArrayView2<'_, T>,
    nu: T,
) -> Result<Array1<T>> {
    w.grid.check_velocity(FORCE, ux, uy)?;
    w.grid.check_cells(FORCE, "pressure", pressure)?;
    let (u, p) = ([wide(ux), wide(uy)], wide(pressure));
    let mut f = [0.0; 2];
    for &(c, d, k) in &w.pressure {
        f[d] += k * p[c];
    }
    for &(c, face, d, k) in &w.shear {
        f[d] += nu.as_f64() * k * u[c][face];
    }
    Ok(f.iter().map(|&v| T::from_f64(v)).collect())
}

/// The vector–Jacobian product of [`obstacle_force`] with the gradient `grad`
/// (`[2]`) of its output.
///
/// # Errors
/// [`crate::FlowError::Shape`] for wrong shapes.
pub fn obstacle_force_vjp<T: Real>(
    w: &ForceWeights,
    ux: ArrayView2<'_, T>,
    uy: ArrayView2<'_, T>,
    nu: T,
    grad: [T; 2],
) -> Result<ForceGrads<T>> {
    let grid = &w.grid;
    grid.check_velocity(FORCE, ux, uy)?;
    let g = [grad[0].as_f64(), grad[1].as_f64()];
    let u = [wide(ux), wide(uy)];
    let mut gu = [vec![0.0; u[0].len()], vec![0.0; u[1].len()]];
    let mut gp = vec![0.0; grid.nx * grid.ny];
    let mut gnu = 0.0;
    for &(c, d, k) in &w.pressure {
        gp[c] += k * g[d];
    }
    for &(c, face, d, k) in &w.shear {
        gu[c][face] += nu.as_f64() * k * g[d];
        gnu += k * u[c][face] * g[d];
    }
    let [gx, gy] = gu;
    Ok(ForceGrads {
        ux: narrow(grid.shape_x(), gx),
        uy: narrow(grid.shape_y(), gy),
        pressure: narrow(grid.cell_shape(), gp),
        viscosity: T::from_f64(gnu),
    })
}

/// [`divergence`] as a tape op: inputs `[u_x, u_y]`, output `[D u]`.
#[derive(Debug, Clone)]
pub struct Divergence {
    /// The grid.
    pub grid: FlowGrid,
}

impl<T: Real> Op<T> for Divergence {
    fn name(&self) -> &str {
        "divergence"
    }
    fn forward(&mut self, inputs: &[ArrayViewD<'_, T>]) -> diffphys_tape::Result<Vec<ArrayD<T>>> {
        TapeError::check_arity("divergence", 2, inputs.len())?;
        Ok(vec![divergence(
            &self.grid,
            view2(&inputs[0])?,
            view2(&inputs[1])?,
        )?
        .into_dyn()])
    }
    fn backward(
        &self,
        args: &BackwardArgs<'_, T>,
    ) -> diffphys_tape::Result<Vec<Option<ArrayD<T>>>> {
        let (a, b) = divergence_vjp(&self.grid, view2(args.grad_out())?)?;
        Ok(vec![
            args.needs(0).then(|| a.into_dyn()),
            args.needs(1).then(|| b.into_dyn()),
        ])
    }
}

/// [`vorticity`] as a tape op: inputs `[u_x, u_y]`, output `[ω]`.
#[derive(Debug, Clone)]
pub struct Vorticity {
    /// The grid.
    pub grid: FlowGrid,
}

impl<T: Real> Op<T> for Vorticity {
    fn name(&self) -> &str {
        "vorticity"
    }
    fn forward(&mut self, inputs: &[ArrayViewD<'_, T>]) -> diffphys_tape::Result<Vec<ArrayD<T>>> {
        TapeError::check_arity("vorticity", 2, inputs.len())?;
        Ok(vec![vorticity(
            &self.grid,
            view2(&inputs[0])?,
            view2(&inputs[1])?,
        )?
        .into_dyn()])
    }
    fn backward(
        &self,
        args: &BackwardArgs<'_, T>,
    ) -> diffphys_tape::Result<Vec<Option<ArrayD<T>>>> {
        let (a, b) = vorticity_vjp(&self.grid, view2(args.grad_out())?)?;
        Ok(vec![
            args.needs(0).then(|| a.into_dyn()),
            args.needs(1).then(|| b.into_dyn()),
        ])
    }
}

/// [`obstacle_force`] as a tape op: inputs `[u_x, u_y, P, ν]`, output
/// `[F]` of shape `[2]` (drag, lift).
#[derive(Debug, Clone)]
pub struct ObstacleForce {
    /// The obstacle's surface.
    pub weights: Arc<ForceWeights>,
}

impl<T: Real> Op<T> for ObstacleForce {
    fn name(&self) -> &str {
        FORCE
    }
    fn forward(&mut self, inputs: &[ArrayViewD<'_, T>]) -> diffphys_tape::Result<Vec<ArrayD<T>>> {
        TapeError::check_arity(FORCE, 4, inputs.len())?;
        let f = obstacle_force(
            &self.weights,
            view2(&inputs[0])?,
            view2(&inputs[1])?,
            view2(&inputs[2])?,
            scalar_of(&inputs[3], "viscosity")?,
        )?;
        Ok(vec![f.into_dyn()])
    }
    fn backward(
        &self,
        args: &BackwardArgs<'_, T>,
    ) -> diffphys_tape::Result<Vec<Option<ArrayD<T>>>> {
        let g = args.grad_out();
        let grad = [g[[0]], g[[1]]];
        let r = obstacle_force_vjp(
            &self.weights,
            view2(args.input(0))?,
            view2(args.input(1))?,
            scalar_of(args.input(3), "viscosity")?,
            grad,
        )?;
        let nu_shape = args.input(3).shape().to_vec();
        Ok(vec![
            args.needs(0).then(|| r.ux.into_dyn()),
            args.needs(1).then(|| r.uy.into_dyn()),
            args.needs(2).then(|| r.pressure.into_dyn()),
            args.needs(3)
                .then(|| ArrayD::from_elem(IxDyn(&nu_shape), r.viscosity)),
        ])
    }
}
