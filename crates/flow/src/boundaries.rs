//! Side conditions, obstacles, and which faces they fix.
//!
//! Each of the four sides carries one [`Boundary`], a handle on a
//! [`crate::sides::SideCondition`]. On the faces of a side the normal velocity
//! is fixed (walls: zero; inflow: the inflow profile) or free (outflow,
//! periodic); the tangential velocity enters through ghost values beyond the
//! side, used by advection and diffusion. The conditions diffphys ships:
//!
//! | condition | normal velocity on its faces | tangential ghost `u_g` (inner value `u_i`) | pressure |
//! | --- | --- | --- | --- |
//! | [`NoSlip`](crate::sides::NoSlip) | 0 | `−u_i` (zero at the wall) | zero normal gradient |
//! | [`FreeSlip`](crate::sides::FreeSlip) | 0 | `u_i` (zero shear) | zero normal gradient |
//! | [`MovingWall`](crate::sides::MovingWall) | 0 | `2 U − u_i` (`U` at the wall) | zero normal gradient |
//! | [`Inflow`](crate::sides::Inflow) | the profile | `−u_i` (no tangential inflow) | zero normal gradient |
//! | [`Outflow`](crate::sides::Outflow) | free (projected) | `u_i` (zero gradient) | `p = 0` one cell outside |
//! | [`Periodic`](crate::sides::Periodic) | free, wraps | wraps | wraps |
//!
//! A condition of one's own answers the same three questions
//! ([`crate::sides`]); the operators read only the answers.
//!
//! An obstacle is a mask of solid cells; every face touching a solid cell has
//! zero velocity (a staircase no-slip body). [`Obstacle::cylinder`] and
//! [`Obstacle::rectangle`] rasterise shapes by their cell centres.
//!
//! The wall speeds `U` of the four sides and the inflow profile are
//! differentiable inputs of the step ([`crate::FlowParams`]); the fixed faces
//! are set from them by [`enforce_boundaries`], whose adjoint hands the
//! gradient of the fixed faces to the profile.

use std::sync::Arc;

use diffphys_tape::{ArrayD, ArrayViewD, BackwardArgs, Op, Real, TapeError};
use ndarray::{Array1, Array2, ArrayView1, ArrayView2};

use crate::grid::{FlowGrid, Lattice};
pub use crate::sides::{Boundary, NormalVelocity, Side, Sides};
use crate::{FlowError, Result};

/// A solid body in the flow: a mask of solid cells.
#[derive(Debug, Clone, PartialEq)]
pub enum Obstacle {
    /// No obstacle.
    None,
    /// A disc: the cells whose centre lies within `radius` of `center`.
    Cylinder {
        /// Centre `[x, y]`.
        center: [f64; 2],
        /// Radius.
        radius: f64,
    },
    /// An axis-aligned box: the cells whose centre lies in `[lo, hi]`.
    Rectangle {
        /// Lower-left corner.
        lo: [f64; 2],
        /// Upper-right corner.
        hi: [f64; 2],
    },
    /// Any mask of shape `[nx, ny]`, `true` for solid cells.
    Mask(Array2<bool>),
}

impl Obstacle {
    /// A cylinder of `radius` at `center`.
    pub fn cylinder(center: [f64; 2], radius: f64) -> Self {
        Obstacle::Cylinder { center, radius }
    }

    /// A box from `lo` to `hi`.
    pub fn rectangle(lo: [f64; 2], hi: [f64; 2]) -> Self {
        Obstacle::Rectangle { lo, hi }
    }

    /// The solid cells on `grid`, checked: a shape must lie inside the domain
    /// and be at least two cells across.
    ///
    /// # Errors
    /// [`FlowError::InvalidScene`] for a shape outside the domain, one too small
    /// for the grid, or a mask of the wrong shape.
    pub fn rasterise(&self, grid: &FlowGrid) -> Result<Array2<bool>> {
        let [lx, ly] = grid.size();
        let (nx, ny) = (grid.nx, grid.ny);
        let cells = |inside: &dyn Fn(f64, f64) -> bool| {
            Array2::from_shape_fn((nx, ny), |(i, j)| {
                let [x, y] = grid.position(Lattice::Cell, i, j);
                inside(x, y)
            })
        };
        let h = grid.dx.max(grid.dy);
        let mask = match self {
            Obstacle::None => return Ok(Array2::from_elem((nx, ny), false)),
            Obstacle::Mask(m) => {
                if m.shape() != [nx, ny] {
                    return Err(FlowError::shape("obstacle", "mask", &[nx, ny], m.shape()));
                }
                return Ok(m.clone());
            }
            Obstacle::Cylinder { center, radius } => {
                let [cx, cy] = *center;
                let r = *radius;
                if !(r.is_finite() && r > 0.0 && cx.is_finite() && cy.is_finite()) {
                    return Err(FlowError::scene(
                        "obstacle",
                        format!("cylinder radius {r} at {center:?}: need a finite radius > 0"),
                    ));
                }
                if cx - r < 0.0 || cx + r > lx || cy - r < 0.0 || cy + r > ly {
                    return Err(FlowError::scene(
                        "obstacle",
                        format!("cylinder of radius {r} at {center:?} does not fit in the domain {lx} × {ly}"),
                    ));
                }
                if 2.0 * r < 2.0 * h {
                    return Err(FlowError::scene(
                        "obstacle",
                        format!(
                            "grid too small for the obstacle: the cylinder's diameter {} spans {:.2} cells, at least 2 are needed",
                            2.0 * r,
                            2.0 * r / h
                        ),
                    ));
                }
                cells(&|x, y| (x - cx).powi(2) + (y - cy).powi(2) <= r * r)
            }
            Obstacle::Rectangle { lo, hi } => {
                if !(lo[0] < hi[0] && lo[1] < hi[1]) {
                    return Err(FlowError::scene(
                        "obstacle",
                        format!("empty box from {lo:?} to {hi:?}"),
                    ));
                }
                if lo[0] < 0.0 || lo[1] < 0.0 || hi[0] > lx || hi[1] > ly {
                    return Err(FlowError::scene(
                        "obstacle",
                        format!("box from {lo:?} to {hi:?} does not fit in the domain {lx} × {ly}"),
                    ));
                }
                if hi[0] - lo[0] < 2.0 * grid.dx || hi[1] - lo[1] < 2.0 * grid.dy {
                    return Err(FlowError::scene(
                        "obstacle",
                        format!("grid too small for the obstacle: the box from {lo:?} to {hi:?} is less than two cells across (dx = {}, dy = {})", grid.dx, grid.dy),
                    ));
                }
                cells(&|x, y| x >= lo[0] && x <= hi[0] && y >= lo[1] && y <= hi[1])
            }
        };
        if !mask.iter().any(|&s| s) {
            return Err(FlowError::scene(
                "obstacle",
                "grid too small for the obstacle: no cell centre lies inside it",
            ));
        }
        Ok(mask)
    }
}

/// What holds the value of a face.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum FaceKind {
    /// An unknown of the flow (interior, outflow, periodic).
    Free,
    /// Zero (a wall, a face touching a solid cell).
    Zero,
    /// Entry `k` of the inflow profile.
    Inflow(usize),
}

/// The condition on every face of a grid, resolved from its side conditions
/// and its solid cells: which faces are unknowns of the flow, which are zero,
/// which take the inflow profile. Built once ([`Faces::classify`]); the
/// operators that treat fixed faces apart read it.
#[derive(Debug, Clone, PartialEq)]
pub struct Faces {
    /// The kinds of the x-faces, in row-major order.
    pub(crate) x: Vec<FaceKind>,
    /// The kinds of the y-faces, in row-major order.
    pub(crate) y: Vec<FaceKind>,
    /// The length of the inflow profile (0 without an inflow side).
    inflow_len: usize,
    /// Some face is fixed (a wall, an inflow, an obstacle).
    constrained: bool,
}

impl Faces {
    /// Whether every face is free (a periodic box without obstacle): then
    /// [`enforce_boundaries`] is the identity.
    pub fn all_free(&self) -> bool {
        !self.constrained
    }

    /// The length of the inflow profile: the cells along the inflow side (0
    /// without one).
    pub fn inflow_len(&self) -> usize {
        self.inflow_len
    }

    /// Classifies the faces of `grid` with the solid cells `solid` (`[nx, ny]`).
    ///
    /// # Panics
    /// If `solid` is not `[nx, ny]` (an [`Obstacle::rasterise`]d mask is).
    pub fn classify(grid: &FlowGrid, solid: &Array2<bool>) -> Faces {
        assert_eq!(solid.shape(), grid.cell_shape(), "one solid flag per cell");
        let (nx, ny) = (grid.nx, grid.ny);
        let [nfx, _] = grid.shape_x();
        let [_, nfy] = grid.shape_y();
        let touches_solid = |cells: (Option<usize>, Option<usize>), at: &dyn Fn(usize) -> bool| {
            cells.0.is_some_and(at) || cells.1.is_some_and(at)
        };
        let kind = |side: Option<Side>, along: usize| match side.map(|s| grid.sides.get(s).normal())
        {
            None | Some(NormalVelocity::Free | NormalVelocity::Wraps) => FaceKind::Free,
            Some(NormalVelocity::Profile) => FaceKind::Inflow(along),
            Some(NormalVelocity::Zero) => FaceKind::Zero,
        };
        let mut x = Vec::with_capacity(nfx * ny);
        for f in 0..nfx {
            let cells = grid.x_face_cells(f);
            for j in 0..ny {
                if touches_solid(cells, &|i| solid[[i, j]]) {
                    x.push(FaceKind::Zero);
                } else {
                    x.push(kind(grid.boundary_side(Lattice::FaceX, f), j));
                }
            }
        }
        let mut y = Vec::with_capacity(nx * nfy);
        for i in 0..nx {
            for f in 0..nfy {
                let cells = grid.y_face_cells(f);
                if touches_solid(cells, &|j| solid[[i, j]]) {
                    y.push(FaceKind::Zero);
                } else {
                    y.push(kind(grid.boundary_side(Lattice::FaceY, f), i));
                }
            }
        }
        let inflow_len = match inflow_side(&grid.sides) {
            Some(Side::Left | Side::Right) => ny,
            Some(Side::Bottom | Side::Top) => nx,
            None => 0,
        };
        let constrained = x.iter().chain(&y).any(|k| *k != FaceKind::Free);
        Faces {
            x,
            y,
            inflow_len,
            constrained,
        }
    }

    /// `p` holds one value per cell along the inflow side.
    pub(crate) fn check_inflow<T>(&self, step: &str, p: ArrayView1<'_, T>) -> Result<()> {
        if p.len() == self.inflow_len {
            Ok(())
        } else {
            Err(FlowError::shape(
                step,
                "inflow profile",
                &[self.inflow_len],
                p.shape(),
            ))
        }
    }

    /// The kinds of one component.
    pub(crate) fn of(&self, lattice: Lattice) -> &[FaceKind] {
        match lattice {
            Lattice::FaceX => &self.x,
            Lattice::FaceY => &self.y,
            Lattice::Cell => &[],
        }
    }
}

/// Sets the fixed faces of `u` (one component) from the profile: `u_f = 0` on
/// walls and solid faces, `u_f = inflow_k` on inflow faces, free faces kept.
fn enforce_component<T: Real>(kinds: &[FaceKind], u: &mut [T], inflow: &[T]) {
    for (v, k) in u.iter_mut().zip(kinds) {
        match k {
            FaceKind::Free => {}
            FaceKind::Zero => *v = T::zero(),
            FaceKind::Inflow(k) => *v = inflow[*k],
        }
    }
}

/// The velocity with its fixed faces set by the side conditions, the obstacle
/// and the inflow profile: `u'_f = u_f` on free faces, `0` on walls and solid
/// faces, `inflow_k` on the inflow faces.
///
/// Adjoint: `∂L/∂u_f = g_f` on free faces (0 on fixed ones),
/// `∂L/∂inflow_k = Σ_{faces of k} g_f`.
///
/// # Errors
/// [`FlowError::Shape`] for a velocity or profile of the wrong shape.
pub fn enforce_boundaries<T: Real>(
    grid: &FlowGrid,
    faces: &Faces,
    ux: ArrayView2<'_, T>,
    uy: ArrayView2<'_, T>,
    inflow: ArrayView1<'_, T>,
) -> Result<(Array2<T>, Array2<T>)> {
    const STEP: &str = "enforce_boundaries";
    grid.check_velocity(STEP, ux, uy)?;
    faces.check_inflow(STEP, inflow)?;
    let inflow = inflow.to_vec();
    let mut ux = ux.as_standard_layout().into_owned();
    let mut uy = uy.as_standard_layout().into_owned();
    enforce_component(&faces.x, ux.as_slice_mut().expect("standard"), &inflow);
    enforce_component(&faces.y, uy.as_slice_mut().expect("standard"), &inflow);
    Ok((ux, uy))
}

/// The gradients of [`enforce_boundaries`]: `(∂L/∂u_x, ∂L/∂u_y, ∂L/∂inflow)`
/// from the gradients `g_x`, `g_y` of its outputs.
///
/// # Errors
/// [`FlowError::Shape`] for gradients of the wrong shape.
pub fn enforce_boundaries_vjp<T: Real>(
    grid: &FlowGrid,
    faces: &Faces,
    grad_x: ArrayView2<'_, T>,
    grad_y: ArrayView2<'_, T>,
) -> Result<(Array2<T>, Array2<T>, Array1<T>)> {
    const STEP: &str = "enforce_boundaries (adjoint)";
    grid.check_velocity(STEP, grad_x, grad_y)?;
    let mut g_inflow = Array1::<T>::zeros(faces.inflow_len());
    let mut split = |kinds: &[FaceKind], g: ArrayView2<'_, T>| {
        let mut g = g.as_standard_layout().into_owned();
        for (v, k) in g.iter_mut().zip(kinds) {
            match k {
                FaceKind::Free => {}
                FaceKind::Zero => *v = T::zero(),
                FaceKind::Inflow(k) => {
                    g_inflow[*k] += *v;
                    *v = T::zero();
                }
            }
        }
        g
    };
    let gx = split(&faces.x, grad_x);
    let gy = split(&faces.y, grad_y);
    Ok((gx, gy, g_inflow))
}

/// [`enforce_boundaries`] as a tape op: inputs `[u_x, u_y, inflow]`, outputs
/// `[u_x', u_y']`.
#[derive(Debug, Clone)]
pub struct EnforceBoundaries {
    /// The grid.
    pub grid: FlowGrid,
    /// Its faces, fixed and free.
    pub faces: Arc<Faces>,
}

impl<T: Real> Op<T> for EnforceBoundaries {
    fn name(&self) -> &str {
        "enforce_boundaries"
    }

    fn forward(&mut self, inputs: &[ArrayViewD<'_, T>]) -> diffphys_tape::Result<Vec<ArrayD<T>>> {
        TapeError::check_arity("enforce_boundaries", 3, inputs.len())?;
        let (ux, uy) = (view2(&inputs[0])?, view2(&inputs[1])?);
        let inflow = view1(&inputs[2])?;
        let (a, b) = enforce_boundaries(&self.grid, &self.faces, ux, uy, inflow)?;
        Ok(vec![a.into_dyn(), b.into_dyn()])
    }

    fn backward(
        &self,
        args: &BackwardArgs<'_, T>,
    ) -> diffphys_tape::Result<Vec<Option<ArrayD<T>>>> {
        let gx = args.grad_output_or_zeros(0);
        let gy = args.grad_output_or_zeros(1);
        let (gx, gy, gi) = enforce_boundaries_vjp(
            &self.grid,
            &self.faces,
            view2(&gx.view())?,
            view2(&gy.view())?,
        )?;
        Ok(vec![
            args.needs(0).then(|| gx.into_dyn()),
            args.needs(1).then(|| gy.into_dyn()),
            args.needs(2).then(|| gi.into_dyn()),
        ])
    }
}

/// The inflow side of `sides`, if any (the first; a scene allows one).
pub(crate) fn inflow_side(sides: &Sides) -> Option<Side> {
    Side::ALL.into_iter().find(|&s| sides.get(s).is_inflow())
}

/// A tape array as a 2D view.
pub(crate) fn view2<'a, T>(a: &'a ArrayViewD<'_, T>) -> Result<ArrayView2<'a, T>> {
    a.view()
        .into_dimensionality()
        .map_err(|_| FlowError::shape("tape input", "2D array", &[0, 0], a.shape()))
}

/// A tape array as a 1D view.
pub(crate) fn view1<'a, T>(a: &'a ArrayViewD<'_, T>) -> Result<ArrayView1<'a, T>> {
    a.view()
        .into_dimensionality()
        .map_err(|_| FlowError::shape("tape input", "1D array", &[0], a.shape()))
}

/// A 0-d or one-element tape array as a value.
pub(crate) fn scalar_of<T: Real>(a: &ArrayViewD<'_, T>, what: &str) -> Result<T> {
    if a.len() == 1 {
        Ok(*a.iter().next().expect("one element"))
    } else {
        Err(FlowError::shape("tape input", what, &[], a.shape()))
    }
}

/// An array of `shape` from a flat vector.
pub(crate) fn array2<T>(shape: [usize; 2], v: Vec<T>) -> Array2<T> {
    Array2::from_shape_vec((shape[0], shape[1]), v).expect("one value per entry")
}
