//! Staggered (MAC) grids: velocity components on cell faces, pressure at cell
//! centres, and the face gradient and divergence that pressure projection needs.
//!
//! A [`MacGrid`] uses the one staggered layout of diffphys ([`crate::staggered`]):
//! on a [`Grid2`] of `nx × ny` cells, x-velocities live on the faces normal to
//! x (shape `[nx + 1, ny]`, `[nx, ny]` on a periodic axis) and y-velocities on
//! the faces normal to y (`[nx, ny + 1]` or `[nx, ny]`); face `f` lies between
//! cells `f − 1` and `f`, at `f·h`. Each side's pressure condition
//! ([`Boundary`]) says whether its boundary faces are open:
//!
//! | side condition | its boundary faces |
//! | --- | --- |
//! | [`Boundary::Closed`] (a wall, an inflow) | closed: weight 0, zero normal velocity, zero normal pressure gradient |
//! | [`Boundary::ZeroDirichlet`] (an outflow) | open: the pressure is zero outside |
//! | [`Boundary::Periodic`] | none: the axis wraps |
//!
//! So 80 × 64 cells with closed walls have x-faces `81 × 64` and y-faces
//! `80 × 65`, the first and last of each closed. An optional [`CellMask`] marks obstacle cells: a face touching an
//! inactive cell is closed (weight 0, zero normal velocity).
//!
//! With the face weights `W` (1 on open faces, 0 on closed ones):
//!
//! ```text
//! gradient    (G p)_f = w_f (p_high(f) − p_low(f)) / h      cells → faces
//! divergence  (D u)_c = Σ_faces of c ± w_f u_f / h = −(Gᵀ u)_c  faces → cells
//! pressure    A = −D G = Gᵀ G   (+ identity on inactive cells)
//! ```
//!
//! `D = −Gᵀ` holds exactly (the discrete `∫ q ∇·u = −∫ u·∇q`), so `A` is
//! symmetric positive semidefinite: `pᵀ A p = ‖G p‖²`. Its kernel is the
//! constants on the active cells unless an open face touches the outside
//! ([`MacGrid::null_space`]). Without a mask and with closed or periodic
//! boundaries, `A` is exactly [`Laplacian2::negative`]; [`MacGrid::pressure_operator`]
//! then uses that stencil.
//!
//! # References
//! - F. H. Harlow and J. E. Welch, *Numerical calculation of time-dependent
//!   viscous incompressible flow of fluid with free surface*, Phys. Fluids 8
//!   (1965) 2182–2189 (the MAC grid).
//! - R. Bridson, *Fluid Simulation for Computer Graphics*, 2nd ed., CRC Press
//!   2015, ch. 5 (pressure projection with solid faces).

use diffphys_tape::Real;
use ndarray::{ArrayD, ArrayViewD, ArrayViewMutD, IxDyn};

use crate::linear::NullSpace;
use crate::staggered::{face_cells, face_count};
use crate::stencil::Laplacian2;
use crate::{Boundary, CellMask, Grid2, OpsError, Result};

mod poisson;

pub use poisson::{MacPoisson, PressureOperator};

/// The faces along one axis.
#[derive(Debug, Clone, Copy, PartialEq)]
struct AxisFaces {
    periodic: bool,
    /// Cells along the axis.
    n: usize,
    /// Spacing.
    h: f64,
}

impl AxisFaces {
    fn new(boundary: Boundary, n: usize, h: f64) -> Self {
        AxisFaces {
            periodic: boundary == Boundary::Periodic,
            n,
            h,
        }
    }

    fn count(&self) -> usize {
        face_count(self.n, self.periodic)
    }

    /// The cells on the low and high side of face `f` (`None`: outside the
    /// domain).
    #[inline]
    fn sides(&self, f: usize) -> (Option<usize>, Option<usize>) {
        face_cells(f, self.n, self.periodic)
    }

    /// The face's distance from the grid origin along the axis.
    fn position(&self, f: usize) -> f64 {
        f as f64 * self.h
    }
}

/// A staggered grid: the cells of a [`Grid2`], its faces with their weights
/// (open or closed), and an optional mask of active cells (see the module docs).
#[derive(Debug, Clone, PartialEq)]
pub struct MacGrid {
    grid: Grid2,
    mask: Option<CellMask>,
    ax: AxisFaces,
    ay: AxisFaces,
    /// Open x-faces, row-major `[nfx, ny]`.
    open_x: Vec<bool>,
    /// Open y-faces, row-major `[nx, nfy]`.
    open_y: Vec<bool>,
}

impl MacGrid {
    /// The faces of `grid`, all cells active.
    pub fn new(grid: Grid2) -> Self {
        Self::build(grid, None)
    }

    /// The faces of `grid` with only the cells of `mask` active.
    ///
    /// # Errors
    /// [`OpsError::ShapeMismatch`] if `mask` is not of the grid's shape.
    pub fn with_mask(grid: Grid2, mask: CellMask) -> Result<Self> {
        if mask.shape() != grid.shape().as_slice() {
            return Err(OpsError::shape("mac_grid", &grid.shape(), mask.shape()));
        }
        Ok(Self::build(grid, Some(mask)))
    }

    fn build(grid: Grid2, mask: Option<CellMask>) -> Self {
        let ax = AxisFaces::new(grid.boundary_x, grid.nx, grid.dx);
        let ay = AxisFaces::new(grid.boundary_y, grid.ny, grid.dy);
        let (nx, ny) = (grid.nx, grid.ny);
        let active = |i: usize, j: usize| mask.as_ref().is_none_or(|m| m.is_active(i * ny + j));
        // A face to the outside is open only on an open (zero Dirichlet) axis.
        let outside = |b: Boundary| b == Boundary::ZeroDirichlet;
        let (out_x, out_y) = (outside(grid.boundary_x), outside(grid.boundary_y));
        let mut open_x = Vec::with_capacity(ax.count() * ny);
        for f in 0..ax.count() {
            let (lo, hi) = ax.sides(f);
            for j in 0..ny {
                let cell = |c: Option<usize>| c.map_or(out_x, |i| active(i, j));
                open_x.push(cell(lo) && cell(hi));
            }
        }
        let mut open_y = Vec::with_capacity(nx * ay.count());
        for i in 0..nx {
            for f in 0..ay.count() {
                let (lo, hi) = ay.sides(f);
                let cell = |c: Option<usize>| c.map_or(out_y, |j| active(i, j));
                open_y.push(cell(lo) && cell(hi));
            }
        }
        MacGrid {
            grid,
            mask,
            ax,
            ay,
            open_x,
            open_y,
        }
    }

    /// The same grid with the boundary faces of one side closed: `axis` 0 (x)
    /// or 1 (y), `high` the side at the axis' end. On a
    /// [`Boundary::ZeroDirichlet`] axis this
    /// makes that side a wall for the pressure (zero Neumann, its face
    /// velocities fixed) while the other stays open: a channel with a
    /// prescribed inflow at one end and an open outflow at the other. Faces
    /// of the other sides, and an axis whose boundary faces are already
    /// closed, are unchanged.
    ///
    /// # Errors
    /// [`OpsError::InvalidArgument`] for an axis other than 0 or 1.
    pub fn with_closed_side(mut self, axis: usize, high: bool) -> Result<Self> {
        if axis > 1 {
            return Err(OpsError::invalid(
                "mac_grid",
                format!("axis {axis} of a 2-D grid (0 is x, 1 is y)"),
            ));
        }
        let (nx, ny) = (self.grid.nx, self.grid.ny);
        let edge = |ax: &AxisFaces, f: usize| {
            let (lo, hi) = ax.sides(f);
            if high {
                hi.is_none()
            } else {
                lo.is_none()
            }
        };
        if axis == 0 {
            for f in (0..self.ax.count()).filter(|&f| edge(&self.ax, f)) {
                self.open_x[f * ny..(f + 1) * ny].fill(false);
            }
        } else {
            let nfy = self.ay.count();
            for f in (0..nfy).filter(|&f| edge(&self.ay, f)) {
                for i in 0..nx {
                    self.open_y[i * nfy + f] = false;
                }
            }
        }
        Ok(self)
    }

    /// The staggered grid of `grid`'s cells whose four sides have the
    /// pressure conditions `sides` (left, right, bottom, top), with only the
    /// cells of `mask` active: the sides of an axis with an open side
    /// ([`Boundary::ZeroDirichlet`]) are open or closed one by one, so an
    /// inflow (closed) and an outflow (open) make a channel. `grid`'s own
    /// per-axis boundaries are replaced.
    ///
    /// # Errors
    /// [`OpsError::InvalidArgument`] if one side of an axis is periodic and
    /// the other not; [`OpsError::ShapeMismatch`] if `mask` is not of the
    /// grid's shape.
    pub fn with_sides(grid: Grid2, sides: [Boundary; 4], mask: Option<CellMask>) -> Result<Self> {
        let axis = |a: usize| -> Result<Boundary> {
            let (lo, hi) = (sides[2 * a], sides[2 * a + 1]);
            match (lo == Boundary::Periodic, hi == Boundary::Periodic) {
                (true, true) => Ok(Boundary::Periodic),
                (false, false)
                    if lo == Boundary::ZeroDirichlet || hi == Boundary::ZeroDirichlet =>
                {
                    Ok(Boundary::ZeroDirichlet)
                }
                (false, false) => Ok(Boundary::Closed),
                _ => Err(OpsError::invalid(
                    "mac_grid",
                    format!(
                        "axis {a} has a periodic side facing {lo:?}/{hi:?}: both or neither wrap"
                    ),
                )),
            }
        };
        let grid = grid.with_boundaries(axis(0)?, axis(1)?);
        let mut mac = match mask {
            Some(m) => Self::with_mask(grid, m)?,
            None => Self::new(grid),
        };
        for (a, axis_boundary) in [(0, grid.boundary_x), (1, grid.boundary_y)] {
            if axis_boundary != Boundary::ZeroDirichlet {
                continue;
            }
            for (high, side) in [(false, sides[2 * a]), (true, sides[2 * a + 1])] {
                if side == Boundary::Closed {
                    mac = mac.with_closed_side(a, high)?;
                }
            }
        }
        Ok(mac)
    }

    /// The cells on the low and high side of x-face `f` (`None` outside the
    /// domain; see [`crate::staggered::face_cells`]).
    pub fn face_cells_x(&self, f: usize) -> (Option<usize>, Option<usize>) {
        self.ax.sides(f)
    }

    /// The cells on the low and high side of y-face `f`.
    pub fn face_cells_y(&self, f: usize) -> (Option<usize>, Option<usize>) {
        self.ay.sides(f)
    }

    /// The cell grid.
    pub fn grid(&self) -> &Grid2 {
        &self.grid
    }

    /// The mask of active cells, if any.
    pub fn mask(&self) -> Option<&CellMask> {
        self.mask.as_ref()
    }

    /// Shape of a cell-centred field (pressure), `[nx, ny]`.
    pub fn cell_shape(&self) -> [usize; 2] {
        self.grid.shape()
    }

    /// Shape of the x-velocity, `[nfx, ny]`.
    pub fn shape_x(&self) -> [usize; 2] {
        [self.ax.count(), self.grid.ny]
    }

    /// Shape of the y-velocity, `[nx, nfy]`.
    pub fn shape_y(&self) -> [usize; 2] {
        [self.grid.nx, self.ay.count()]
    }

    /// The centre `[x, y]` of x-face `(f, j)`.
    pub fn face_center_x(&self, f: usize, j: usize) -> [f64; 2] {
        let o = self.grid.origin;
        [
            o[0] + self.ax.position(f),
            o[1] + (j as f64 + 0.5) * self.grid.dy,
        ]
    }

    /// The centre `[x, y]` of y-face `(i, f)`.
    pub fn face_center_y(&self, i: usize, f: usize) -> [f64; 2] {
        let o = self.grid.origin;
        [
            o[0] + (i as f64 + 0.5) * self.grid.dx,
            o[1] + self.ay.position(f),
        ]
    }

    /// An x-velocity sampled at the face centres: `value([x, y])`.
    pub fn sample_x<T: Real>(&self, value: impl Fn([f64; 2]) -> f64) -> ArrayD<T> {
        let [nf, ny] = self.shape_x();
        ArrayD::from_shape_fn(IxDyn(&[nf, ny]), |ix| {
            T::from_f64(value(self.face_center_x(ix[0], ix[1])))
        })
    }

    /// A y-velocity sampled at the face centres: `value([x, y])`.
    pub fn sample_y<T: Real>(&self, value: impl Fn([f64; 2]) -> f64) -> ArrayD<T> {
        let [nx, nf] = self.shape_y();
        ArrayD::from_shape_fn(IxDyn(&[nx, nf]), |ix| {
            T::from_f64(value(self.face_center_y(ix[0], ix[1])))
        })
    }

    /// Which x-faces are open (weight 1), shape [`MacGrid::shape_x`].
    pub fn open_faces_x(&self) -> ArrayD<bool> {
        ArrayD::from_shape_vec(IxDyn(&self.shape_x()), self.open_x.clone())
            .expect("one flag per face")
    }

    /// Which y-faces are open (weight 1), shape [`MacGrid::shape_y`].
    pub fn open_faces_y(&self) -> ArrayD<bool> {
        ArrayD::from_shape_vec(IxDyn(&self.shape_y()), self.open_y.clone())
            .expect("one flag per face")
    }

    /// The null space of the pressure operator: none if an open face touches
    /// the outside (an open boundary pins the pressure), else the constants
    /// (on the active cells, with a mask).
    ///
    /// With a mask, each closed connected component of active cells adds a
    /// constant of its own to the kernel; only one is declared. CG still solves
    /// such systems (projection right-hand sides are consistent on every
    /// component), but the exact reference needs a connected active region.
    pub fn null_space(&self) -> NullSpace {
        let (nx, ny) = (self.grid.nx, self.grid.ny);
        let nfy = self.ay.count();
        let at_edge = |ax: &AxisFaces, f: usize| {
            let (lo, hi) = ax.sides(f);
            lo.is_none() || hi.is_none()
        };
        let outside_x = (0..self.ax.count())
            .filter(|&f| at_edge(&self.ax, f))
            .any(|f| self.open_x[f * ny..(f + 1) * ny].iter().any(|&o| o));
        let outside_y = (0..nfy)
            .filter(|&f| at_edge(&self.ay, f))
            .any(|f| (0..nx).any(|i| self.open_y[i * nfy + f]));
        if outside_x || outside_y {
            return NullSpace::None;
        }
        match &self.mask {
            Some(m) if m.active_count() < m.as_slice().len() => NullSpace::ConstantOn(m.clone()),
            _ => NullSpace::Constant,
        }
    }

    /// The pressure operator `A = −D G = Gᵀ G` (identity on inactive cells):
    /// [`Laplacian2::negative`] when that is the same matrix (no mask, no open
    /// boundary), else the face-weighted [`MacPoisson`].
    pub fn pressure_operator(&self) -> PressureOperator {
        let open = |b: Boundary| b == Boundary::ZeroDirichlet;
        if self.mask.is_none() && !open(self.grid.boundary_x) && !open(self.grid.boundary_y) {
            PressureOperator::Stencil(Laplacian2::negative(self.grid))
        } else {
            PressureOperator::Faces(MacPoisson::new(self.clone()))
        }
    }

    fn check(&self, what: &str, expected: &[usize], found: &[usize]) -> Result<()> {
        if expected == found {
            Ok(())
        } else {
            Err(OpsError::shape(
                &format!("mac_grid {what}"),
                expected,
                found,
            ))
        }
    }

    /// The face gradient `G p`: `(G p)_f = w_f (p_high − p_low)/h` (zero pressure
    /// outside an open boundary, zero on closed faces). Adjoint: `Gᵀ = −D`.
    ///
    /// # Errors
    /// [`OpsError::ShapeMismatch`] if `p` is not of [`MacGrid::cell_shape`].
    pub fn gradient<T: Real>(&self, p: ArrayViewD<'_, T>) -> Result<(ArrayD<T>, ArrayD<T>)> {
        self.check("gradient input", &self.cell_shape(), p.shape())?;
        let p = p.as_standard_layout();
        let p = p.as_slice().expect("standard layout is contiguous");
        let (nx, ny) = (self.grid.nx, self.grid.ny);
        let mut gx = vec![T::zero(); self.ax.count() * ny];
        let cx = T::from_f64(1.0 / self.grid.dx);
        for f in 0..self.ax.count() {
            let (lo, hi) = self.ax.sides(f);
            for j in 0..ny {
                if self.open_x[f * ny + j] {
                    let at = |c: Option<usize>| c.map_or(T::zero(), |i| p[i * ny + j]);
                    gx[f * ny + j] = (at(hi) - at(lo)) * cx;
                }
            }
        }
        let nfy = self.ay.count();
        let mut gy = vec![T::zero(); nx * nfy];
        let cy = T::from_f64(1.0 / self.grid.dy);
        for i in 0..nx {
            for f in 0..nfy {
                if self.open_y[i * nfy + f] {
                    let (lo, hi) = self.ay.sides(f);
                    let at = |c: Option<usize>| c.map_or(T::zero(), |j| p[i * ny + j]);
                    gy[i * nfy + f] = (at(hi) - at(lo)) * cy;
                }
            }
        }
        Ok((
            ArrayD::from_shape_vec(IxDyn(&self.shape_x()), gx).expect("one per face"),
            ArrayD::from_shape_vec(IxDyn(&self.shape_y()), gy).expect("one per face"),
        ))
    }

    /// The divergence `D u = −Gᵀ W u`: per cell, the net outflow through its
    /// open faces, `(u_right − u_left)/dx + (u_top − u_bottom)/dy` (closed faces
    /// and walls carry no flow). Adjoint: `Dᵀ = −G`.
    ///
    /// # Errors
    /// [`OpsError::ShapeMismatch`] if `ux`, `uy` are not of
    /// [`MacGrid::shape_x`], [`MacGrid::shape_y`].
    pub fn divergence<T: Real>(
        &self,
        ux: ArrayViewD<'_, T>,
        uy: ArrayViewD<'_, T>,
    ) -> Result<ArrayD<T>> {
        self.check("divergence x-velocity", &self.shape_x(), ux.shape())?;
        self.check("divergence y-velocity", &self.shape_y(), uy.shape())?;
        let (ux, uy) = (ux.as_standard_layout(), uy.as_standard_layout());
        let ux = ux.as_slice().expect("standard layout is contiguous");
        let uy = uy.as_slice().expect("standard layout is contiguous");
        let (nx, ny) = (self.grid.nx, self.grid.ny);
        let mut div = vec![T::zero(); nx * ny];
        let cx = T::from_f64(1.0 / self.grid.dx);
        for f in 0..self.ax.count() {
            let (lo, hi) = self.ax.sides(f);
            for j in 0..ny {
                if self.open_x[f * ny + j] {
                    let flow = ux[f * ny + j] * cx;
                    // out of the low cell through its right face, into the high cell
                    if let Some(i) = lo {
                        div[i * ny + j] += flow;
                    }
                    if let Some(i) = hi {
                        div[i * ny + j] -= flow;
                    }
                }
            }
        }
        let nfy = self.ay.count();
        let cy = T::from_f64(1.0 / self.grid.dy);
        for i in 0..nx {
            for f in 0..nfy {
                if self.open_y[i * nfy + f] {
                    let (lo, hi) = self.ay.sides(f);
                    let flow = uy[i * nfy + f] * cy;
                    if let Some(j) = lo {
                        div[i * ny + j] += flow;
                    }
                    if let Some(j) = hi {
                        div[i * ny + j] -= flow;
                    }
                }
            }
        }
        Ok(ArrayD::from_shape_vec(IxDyn(&self.cell_shape()), div).expect("one per cell"))
    }

    /// Sets the velocity on closed faces to zero (`u ← W u`).
    ///
    /// # Errors
    /// [`OpsError::ShapeMismatch`] for arrays of the wrong shapes.
    pub fn zero_closed_faces<T: Real>(
        &self,
        mut ux: ArrayViewMutD<'_, T>,
        mut uy: ArrayViewMutD<'_, T>,
    ) -> Result<()> {
        self.check("x-velocity", &self.shape_x(), ux.shape())?;
        self.check("y-velocity", &self.shape_y(), uy.shape())?;
        for (v, &o) in ux.iter_mut().zip(&self.open_x) {
            if !o {
                *v = T::zero();
            }
        }
        for (v, &o) in uy.iter_mut().zip(&self.open_y) {
            if !o {
                *v = T::zero();
            }
        }
        Ok(())
    }
}
