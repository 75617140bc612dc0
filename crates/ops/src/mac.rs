//! Staggered (MAC) grids: velocity components on cell faces, pressure at cell
//! centres, and the face gradient and divergence that pressure projection needs.
//!
//! On a [`Grid2`] of `nx × ny` cells, x-velocities live on the faces normal to
//! x (shape `[nfx, ny]`) and y-velocities on the faces normal to y (shape
//! `[nx, nfy]`). Which faces carry unknowns depends on each axis' [`Boundary`]:
//!
//! | boundary | faces along the axis | face `f` lies between cells | position |
//! | --- | --- | --- | --- |
//! | [`Boundary::Closed`] (walls) | `n − 1`, interior only (the wall faces have zero normal velocity) | `f` and `f + 1` | `(f + 1)·h` |
//! | [`Boundary::ZeroDirichlet`] (open) | `n + 1`, all (pressure is zero outside) | `f − 1` and `f` | `f·h` |
//! | [`Boundary::Periodic`] | `n` | `f − 1 (mod n)` and `f` | `f·h` |
//!
//! So 80 × 64 cells with closed walls have x-faces `79 × 64` and y-faces
//! `80 × 63`. An optional [`CellMask`] marks obstacle cells: a face touching an
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

use crate::linear::{wide, NullSpace};
use crate::stencil::Laplacian2;
use crate::{Boundary, CellMask, Grid2, LinearOperator, OpsError, Result};

/// The faces along one axis.
#[derive(Debug, Clone, Copy, PartialEq)]
struct AxisFaces {
    boundary: Boundary,
    /// Cells along the axis.
    n: usize,
    /// Spacing.
    h: f64,
}

impl AxisFaces {
    fn count(&self) -> usize {
        match self.boundary {
            Boundary::Closed => self.n - 1,
            Boundary::ZeroDirichlet => self.n + 1,
            Boundary::Periodic => self.n,
        }
    }

    /// The cells on the low and high side of face `f` (`None`: outside the
    /// domain, where the pressure is zero).
    fn sides(&self, f: usize) -> (Option<usize>, Option<usize>) {
        match self.boundary {
            Boundary::Closed => (Some(f), Some(f + 1)),
            Boundary::ZeroDirichlet => (f.checked_sub(1), (f < self.n).then_some(f)),
            Boundary::Periodic => (Some((f + self.n - 1) % self.n), Some(f)),
        }
    }

    /// The face's distance from the grid origin along the axis.
    fn position(&self, f: usize) -> f64 {
        match self.boundary {
            Boundary::Closed => (f + 1) as f64 * self.h,
            Boundary::ZeroDirichlet | Boundary::Periodic => f as f64 * self.h,
        }
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
        let ax = AxisFaces {
            boundary: grid.boundary_x,
            n: grid.nx,
            h: grid.dx,
        };
        let ay = AxisFaces {
            boundary: grid.boundary_y,
            n: grid.ny,
            h: grid.dy,
        };
        let (nx, ny) = (grid.nx, grid.ny);
        let active = |i: usize, j: usize| mask.as_ref().is_none_or(|m| m.is_active(i * ny + j));
        let mut open_x = Vec::with_capacity(ax.count() * ny);
        for f in 0..ax.count() {
            let (lo, hi) = ax.sides(f);
            for j in 0..ny {
                open_x.push(lo.is_none_or(|i| active(i, j)) && hi.is_none_or(|i| active(i, j)));
            }
        }
        let mut open_y = Vec::with_capacity(nx * ay.count());
        for i in 0..nx {
            for f in 0..ay.count() {
                let (lo, hi) = ay.sides(f);
                open_y.push(lo.is_none_or(|j| active(i, j)) && hi.is_none_or(|j| active(i, j)));
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

/// The face-weighted pressure operator `A = Gᵀ W G + (I − P_active)` of a
/// [`MacGrid`]: per active cell, `(A p)_c = Σ_open faces (p_c − p_other)/h²`
/// (`p_other = 0` outside an open boundary); inactive cells map to themselves.
/// Symmetric positive semidefinite (definite with an open boundary); adjoint
/// `Aᵀ = A`.
#[derive(Debug, Clone, PartialEq)]
pub struct MacPoisson {
    mac: MacGrid,
    shape: [usize; 2],
    /// `1/dx²`, `1/dy²`.
    coef: [f64; 2],
}

impl MacPoisson {
    /// The operator of `mac`.
    pub fn new(mac: MacGrid) -> Self {
        let g = mac.grid;
        MacPoisson {
            shape: g.shape(),
            coef: [1.0 / (g.dx * g.dx), 1.0 / (g.dy * g.dy)],
            mac,
        }
    }

    /// The staggered grid.
    pub fn mac(&self) -> &MacGrid {
        &self.mac
    }

    /// Every open face as `(low cell, high cell, coefficient)` with flat cell
    /// indices (`None` outside); faces whose two sides are the same cell (a
    /// periodic axis of one cell) carry no flux and are skipped.
    fn faces(&self) -> Vec<(Option<usize>, Option<usize>, f64)> {
        let m = &self.mac;
        let (nx, ny) = (m.grid.nx, m.grid.ny);
        let mut faces = Vec::new();
        for f in 0..m.ax.count() {
            let (lo, hi) = m.ax.sides(f);
            for j in 0..ny {
                if m.open_x[f * ny + j] && (lo != hi) {
                    faces.push((lo.map(|i| i * ny + j), hi.map(|i| i * ny + j), self.coef[0]));
                }
            }
        }
        let nfy = m.ay.count();
        for i in 0..nx {
            for f in 0..nfy {
                let (lo, hi) = m.ay.sides(f);
                if m.open_y[i * nfy + f] && (lo != hi) {
                    faces.push((lo.map(|j| i * ny + j), hi.map(|j| i * ny + j), self.coef[1]));
                }
            }
        }
        faces
    }

    fn inactive(&self) -> impl Iterator<Item = usize> + '_ {
        self.mac.mask.iter().flat_map(|m| {
            m.as_slice()
                .iter()
                .enumerate()
                .filter(|(_, &a)| !a)
                .map(|(c, _)| c)
        })
    }

    /// `out = A x` on row-major slices.
    fn run<T: Real>(&self, x: &[T], out: &mut [T]) {
        let m = &self.mac;
        let (nx, ny) = (m.grid.nx, m.grid.ny);
        out.fill(T::zero());
        let cx = T::from_f64(self.coef[0]);
        for f in 0..m.ax.count() {
            let (lo, hi) = m.ax.sides(f);
            if lo == hi {
                continue;
            }
            let open = &m.open_x[f * ny..(f + 1) * ny];
            for (j, _) in open.iter().enumerate().filter(|(_, &o)| o) {
                let at = |c: Option<usize>| c.map_or(T::zero(), |i| x[i * ny + j]);
                let flux = (at(hi) - at(lo)) * cx;
                if let Some(i) = lo {
                    out[i * ny + j] -= flux;
                }
                if let Some(i) = hi {
                    out[i * ny + j] += flux;
                }
            }
        }
        let cy = T::from_f64(self.coef[1]);
        let nfy = m.ay.count();
        for f in 0..nfy {
            let (lo, hi) = m.ay.sides(f);
            if lo == hi {
                continue;
            }
            for i in 0..nx {
                if m.open_y[i * nfy + f] {
                    let at = |c: Option<usize>| c.map_or(T::zero(), |j| x[i * ny + j]);
                    let flux = (at(hi) - at(lo)) * cy;
                    if let Some(j) = lo {
                        out[i * ny + j] -= flux;
                    }
                    if let Some(j) = hi {
                        out[i * ny + j] += flux;
                    }
                }
            }
        }
        for c in self.inactive() {
            out[c] = x[c];
        }
    }

    /// `out = A x`, returning `<x, A x>` accumulated in `f64`.
    fn apply_slices<T: Real>(&self, x: ArrayViewD<'_, T>, mut out: ArrayViewMutD<'_, T>) -> f64 {
        let x = x.as_standard_layout();
        let xs = x.as_slice().expect("standard layout is contiguous");
        let dot = |o: &[T]| {
            xs.iter()
                .zip(o)
                .fold(0.0, |acc, (&a, &b)| acc + wide(a) * wide(b))
        };
        if let Some(o) = out.as_slice_mut() {
            self.run(xs, o);
            return dot(o);
        }
        let mut buf = vec![T::zero(); xs.len()];
        self.run(xs, &mut buf);
        for (o, &b) in out.iter_mut().zip(&buf) {
            *o = b;
        }
        dot(&buf)
    }
}

impl<T: Real> LinearOperator<T> for MacPoisson {
    fn name(&self) -> &str {
        "mac_poisson"
    }
    fn input_shape(&self) -> &[usize] {
        &self.shape
    }
    fn output_shape(&self) -> &[usize] {
        &self.shape
    }
    fn apply_into(&self, x: ArrayViewD<'_, T>, out: ArrayViewMutD<'_, T>) {
        self.apply_slices(x, out);
    }
    fn apply_transpose_into(&self, y: ArrayViewD<'_, T>, out: ArrayViewMutD<'_, T>) {
        self.apply_slices(y, out);
    }
    fn apply_into_dot(&self, x: ArrayViewD<'_, T>, out: ArrayViewMutD<'_, T>) -> f64 {
        self.apply_slices(x, out)
    }
    fn is_symmetric(&self) -> bool {
        true
    }
    fn diagonal(&self) -> Option<ArrayD<T>> {
        let mut d = vec![0.0; self.shape[0] * self.shape[1]];
        for (lo, hi, c) in self.faces() {
            for cell in [lo, hi].into_iter().flatten() {
                d[cell] += c;
            }
        }
        for c in self.inactive() {
            d[c] = 1.0;
        }
        Some(
            ArrayD::from_shape_vec(IxDyn(&self.shape), d.into_iter().map(T::from_f64).collect())
                .expect("one per cell"),
        )
    }
    fn triplets(&self) -> Option<Vec<(usize, usize, T)>> {
        let n = self.shape[0] * self.shape[1];
        let mut t: Vec<(usize, usize, f64)> = (0..n).map(|c| (c, c, 0.0)).collect();
        for (lo, hi, c) in self.faces() {
            for cell in [lo, hi].into_iter().flatten() {
                t.push((cell, cell, c));
            }
            if let (Some(a), Some(b)) = (lo, hi) {
                t.push((a, b, -c));
                t.push((b, a, -c));
            }
        }
        for c in self.inactive() {
            t.push((c, c, 1.0));
        }
        t.sort_by_key(|e| (e.0, e.1));
        let mut merged: Vec<(usize, usize, T)> = Vec::with_capacity(t.len());
        let mut k = 0;
        while k < t.len() {
            let (r, c) = (t[k].0, t[k].1);
            let mut v = 0.0;
            while k < t.len() && (t[k].0, t[k].1) == (r, c) {
                v += t[k].2;
                k += 1;
            }
            if v != 0.0 || r == c {
                merged.push((r, c, T::from_f64(v)));
            }
        }
        Some(merged)
    }
}

/// The pressure operator of a [`MacGrid`]: H1's 5-point stencil where it is the
/// same matrix, else the face-weighted operator. Both are `A = −D G`.
#[derive(Debug, Clone, PartialEq)]
pub enum PressureOperator {
    /// [`Laplacian2::negative`] (no mask; closed or periodic boundaries).
    Stencil(Laplacian2),
    /// [`MacPoisson`] (masks, open boundaries).
    Faces(MacPoisson),
}

macro_rules! delegate {
    ($self:ident, $op:ident => $e:expr) => {
        match $self {
            PressureOperator::Stencil($op) => $e,
            PressureOperator::Faces($op) => $e,
        }
    };
}

impl<T: Real> LinearOperator<T> for PressureOperator {
    fn name(&self) -> &str {
        delegate!(self, a => LinearOperator::<T>::name(a))
    }
    fn input_shape(&self) -> &[usize] {
        delegate!(self, a => LinearOperator::<T>::input_shape(a))
    }
    fn output_shape(&self) -> &[usize] {
        delegate!(self, a => LinearOperator::<T>::output_shape(a))
    }
    fn apply_into(&self, x: ArrayViewD<'_, T>, out: ArrayViewMutD<'_, T>) {
        delegate!(self, a => a.apply_into(x, out))
    }
    fn apply_transpose_into(&self, y: ArrayViewD<'_, T>, out: ArrayViewMutD<'_, T>) {
        delegate!(self, a => a.apply_transpose_into(y, out))
    }
    fn apply_into_dot(&self, x: ArrayViewD<'_, T>, out: ArrayViewMutD<'_, T>) -> f64 {
        delegate!(self, a => a.apply_into_dot(x, out))
    }
    fn is_symmetric(&self) -> bool {
        true
    }
    fn diagonal(&self) -> Option<ArrayD<T>> {
        delegate!(self, a => a.diagonal())
    }
    fn triplets(&self) -> Option<Vec<(usize, usize, T)>> {
        delegate!(self, a => a.triplets())
    }
}
