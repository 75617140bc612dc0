//! Uniform grids and their boundaries.
//!
//! Conventions used throughout the crate: a 1D cell-centred field on [`Grid1`] has
//! shape `[n]`, cell `i` centred at `x0 + (i + ½)·dx`; a 2D cell-centred field on
//! [`Grid2`] has shape `[nx, ny]`, axis 0 is x and axis 1 is y, cell `(i, j)` centred
//! at `(x0 + (i + ½)·dx, y0 + (j + ½)·dy)`.

use crate::{OpsError, Result};

/// What lies beyond the edge of a grid.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Boundary {
    /// The domain wraps around: the cell after the last is the first.
    Periodic,
    /// The field is zero on the boundary (for cell-centred fields the ghost cell
    /// mirrors the value with opposite sign, so the wall value is zero).
    ZeroDirichlet,
    /// Closed walls: zero normal flow, zero normal derivative (Neumann) for
    /// cell-centred scalars such as pressure.
    Closed,
}

/// A uniform 1D grid of `n` cells of width `dx` starting at `x0`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Grid1 {
    /// Number of cells.
    pub n: usize,
    /// Cell width.
    pub dx: f64,
    /// Left edge of the domain.
    pub x0: f64,
    /// Boundary at both ends.
    pub boundary: Boundary,
}

impl Grid1 {
    /// `n` cells of width `dx` from `x0`.
    ///
    /// # Errors
    /// [`OpsError::InvalidArgument`] if `n == 0` or `dx` is not finite and positive.
    pub fn new(n: usize, dx: f64, x0: f64, boundary: Boundary) -> Result<Self> {
        if n == 0 || !(dx.is_finite() && dx > 0.0) || !x0.is_finite() {
            return Err(OpsError::invalid(
                "Grid1",
                format!("need n > 0 and finite dx > 0, got n = {n}, dx = {dx}, x0 = {x0}"),
            ));
        }
        Ok(Grid1 {
            n,
            dx,
            x0,
            boundary,
        })
    }

    /// The grid that divides `[lo, hi]` into `n` cells.
    ///
    /// # Errors
    /// As [`Grid1::new`], and if `hi <= lo`.
    pub fn over(lo: f64, hi: f64, n: usize, boundary: Boundary) -> Result<Self> {
        if hi.partial_cmp(&lo) != Some(std::cmp::Ordering::Greater) {
            return Err(OpsError::invalid(
                "Grid1",
                format!("empty domain [{lo}, {hi}]"),
            ));
        }
        Self::new(n, (hi - lo) / n as f64, lo, boundary)
    }

    /// The centre of cell `i`.
    pub fn center(&self, i: usize) -> f64 {
        self.x0 + (i as f64 + 0.5) * self.dx
    }

    /// The centres of all cells.
    pub fn centers(&self) -> Vec<f64> {
        (0..self.n).map(|i| self.center(i)).collect()
    }

    /// The shape of a cell-centred field.
    pub fn shape(&self) -> [usize; 1] {
        [self.n]
    }
}

/// A uniform 2D grid of `nx × ny` cells of size `dx × dy`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Grid2 {
    /// Cells along x (axis 0).
    pub nx: usize,
    /// Cells along y (axis 1).
    pub ny: usize,
    /// Cell width along x.
    pub dx: f64,
    /// Cell width along y.
    pub dy: f64,
    /// Lower-left corner `(x0, y0)`.
    pub origin: [f64; 2],
    /// Boundary along x (the two faces `x = x0` and `x = x0 + nx·dx`).
    pub boundary_x: Boundary,
    /// Boundary along y.
    pub boundary_y: Boundary,
}

impl Grid2 {
    /// `nx × ny` cells of size `dx × dy` from the origin, one boundary kind on all sides.
    ///
    /// # Errors
    /// [`OpsError::InvalidArgument`] if a size is zero or a spacing is not finite
    /// and positive.
    pub fn new(nx: usize, ny: usize, dx: f64, dy: f64, boundary: Boundary) -> Result<Self> {
        if nx == 0 || ny == 0 || !(dx.is_finite() && dx > 0.0) || !(dy.is_finite() && dy > 0.0) {
            return Err(OpsError::invalid(
                "Grid2",
                format!(
                    "need nx, ny > 0 and finite spacings > 0, got {nx}×{ny}, dx = {dx}, dy = {dy}"
                ),
            ));
        }
        Ok(Grid2 {
            nx,
            ny,
            dx,
            dy,
            origin: [0.0, 0.0],
            boundary_x: boundary,
            boundary_y: boundary,
        })
    }

    /// A square-celled grid (`dx = dy = h`).
    ///
    /// # Errors
    /// As [`Grid2::new`].
    pub fn square(nx: usize, ny: usize, h: f64, boundary: Boundary) -> Result<Self> {
        Self::new(nx, ny, h, h, boundary)
    }

    /// The same grid with different boundaries along x and y.
    pub fn with_boundaries(mut self, boundary_x: Boundary, boundary_y: Boundary) -> Self {
        self.boundary_x = boundary_x;
        self.boundary_y = boundary_y;
        self
    }

    /// The shape of a cell-centred field, `[nx, ny]`.
    pub fn shape(&self) -> [usize; 2] {
        [self.nx, self.ny]
    }

    /// Number of cells.
    pub fn cells(&self) -> usize {
        self.nx * self.ny
    }

    /// The centre of cell `(i, j)`.
    pub fn center(&self, i: usize, j: usize) -> [f64; 2] {
        [
            self.origin[0] + (i as f64 + 0.5) * self.dx,
            self.origin[1] + (j as f64 + 0.5) * self.dy,
        ]
    }
}

/// Which cells of a grid take part in a computation (the others are obstacles or
/// lie outside the domain): one flag per cell, in the row-major order of a
/// cell-centred field.
///
/// [`crate::stencil::Masked`] restricts a linear operator to the active cells.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct CellMask {
    shape: Vec<usize>,
    active: Vec<bool>,
}

impl CellMask {
    /// Every cell of a field of `shape` active.
    pub fn all_active(shape: &[usize]) -> Self {
        CellMask {
            shape: shape.to_vec(),
            active: vec![true; shape.iter().product()],
        }
    }

    /// The cells of a 1D grid whose centre `x` satisfies `active(x)`.
    pub fn from_fn1(grid: &Grid1, active: impl Fn(f64) -> bool) -> Self {
        CellMask {
            shape: grid.shape().to_vec(),
            active: (0..grid.n).map(|i| active(grid.center(i))).collect(),
        }
    }

    /// The cells of a 2D grid whose centre `[x, y]` satisfies `active`.
    pub fn from_fn2(grid: &Grid2, active: impl Fn([f64; 2]) -> bool) -> Self {
        let mut flags = Vec::with_capacity(grid.cells());
        for i in 0..grid.nx {
            for j in 0..grid.ny {
                flags.push(active(grid.center(i, j)));
            }
        }
        CellMask {
            shape: grid.shape().to_vec(),
            active: flags,
        }
    }

    /// A mask from an array of flags (any layout).
    pub fn from_array(flags: ndarray::ArrayViewD<'_, bool>) -> Self {
        CellMask {
            shape: flags.shape().to_vec(),
            active: flags.iter().copied().collect(),
        }
    }

    /// The shape of the fields it applies to.
    pub fn shape(&self) -> &[usize] {
        &self.shape
    }

    /// The flags in row-major order.
    pub fn as_slice(&self) -> &[bool] {
        &self.active
    }

    /// Whether the cell at row-major index `flat` is active.
    ///
    /// # Panics
    /// If `flat` is out of range.
    pub fn is_active(&self, flat: usize) -> bool {
        self.active[flat]
    }

    /// How many cells are active.
    pub fn active_count(&self) -> usize {
        self.active.iter().filter(|&&a| a).count()
    }

    /// Sets the inactive cells of `field` to zero.
    ///
    /// # Errors
    /// [`OpsError::ShapeMismatch`] if `field` does not have the mask's shape.
    pub fn zero_inactive<T: diffphys_tape::Real>(
        &self,
        mut field: ndarray::ArrayViewMutD<'_, T>,
    ) -> Result<()> {
        if field.shape() != self.shape.as_slice() {
            return Err(OpsError::shape("CellMask", &self.shape, field.shape()));
        }
        // Row-major iteration order matches the flags whatever the layout.
        for (v, &a) in field.iter_mut().zip(&self.active) {
            if !a {
                *v = T::zero();
            }
        }
        Ok(())
    }
}
