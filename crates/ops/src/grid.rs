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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn grid_over_interval_has_right_centres() {
        let g = Grid1::over(-1.0, 1.0, 4, Boundary::Periodic).unwrap();
        assert_eq!(g.dx, 0.5);
        assert_eq!(g.centers(), vec![-0.75, -0.25, 0.25, 0.75]);
    }

    #[test]
    fn bad_grids_are_errors() {
        assert!(Grid1::new(0, 1.0, 0.0, Boundary::Periodic).is_err());
        assert!(Grid1::new(3, f64::NAN, 0.0, Boundary::Periodic).is_err());
        assert!(Grid2::new(3, 3, 1.0, -1.0, Boundary::Closed).is_err());
        assert!(Grid1::over(1.0, 1.0, 3, Boundary::Closed).is_err());
    }
}
