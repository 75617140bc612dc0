//! The staggered (MAC) grid of a flow: cells, faces, and the layout of the
//! arrays a user holds.
//!
//! A domain `[0, lx] × [0, ly]` is cut into `nx × ny` cells of size `dx × dy`;
//! axis 0 is x, axis 1 is y. Pressure and passive scalars live at cell centres
//! (`[nx, ny]`, cell `(i, j)` at `((i + ½) dx, (j + ½) dy)`), the x-velocity on
//! the faces normal to x, the y-velocity on the faces normal to y:
//!
//! | array | shape, non-periodic axis | shape, periodic axis | entry `[a, b]` at |
//! | --- | --- | --- | --- |
//! | `u_x` | `[nx + 1, ny]` | `[nx, ny]` | `(a dx, (b + ½) dy)` |
//! | `u_y` | `[nx, ny + 1]` | `[nx, ny]` | `((a + ½) dx, b dy)` |
//!
//! Face `f` along an axis lies between cells `f − 1` and `f` (outside the domain
//! where that index is out of range; wrapped on a periodic axis), so a
//! non-periodic axis stores its two boundary faces (`0` and `n`), whose values
//! the side conditions fix or leave free (see [`crate::boundaries`]).

use ndarray::{ArrayView1, ArrayView2};

use crate::error::{FlowError, Result};
use crate::sides::{Side, Sides};

/// The cells and faces of a flow domain with its four side conditions.
#[derive(Debug, Clone, PartialEq)]
pub struct FlowGrid {
    /// Cells along x.
    pub nx: usize,
    /// Cells along y.
    pub ny: usize,
    /// Cell width along x.
    pub dx: f64,
    /// Cell height along y.
    pub dy: f64,
    /// The condition on each side.
    pub sides: Sides,
}

/// One of the two velocity components, or a cell-centred scalar: which lattice
/// an array lives on.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Lattice {
    /// The x-velocity on the x-faces.
    FaceX,
    /// The y-velocity on the y-faces.
    FaceY,
    /// Cell centres (pressure, scalars).
    Cell,
}

impl FlowGrid {
    /// Whether the x axis wraps (left and right periodic).
    pub fn periodic_x(&self) -> bool {
        self.sides.left.is_periodic()
    }

    /// Whether the y axis wraps (bottom and top periodic).
    pub fn periodic_y(&self) -> bool {
        self.sides.bottom.is_periodic()
    }

    /// The cell size normal to `side`: `dx` on the left and right, `dy` on
    /// the bottom and top.
    pub fn normal_size(&self, side: Side) -> f64 {
        match side {
            Side::Left | Side::Right => self.dx,
            Side::Bottom | Side::Top => self.dy,
        }
    }

    /// The domain size `[lx, ly]`.
    pub fn size(&self) -> [f64; 2] {
        [self.nx as f64 * self.dx, self.ny as f64 * self.dy]
    }

    /// Shape of a cell-centred field, `[nx, ny]`.
    pub fn cell_shape(&self) -> [usize; 2] {
        [self.nx, self.ny]
    }

    /// Shape of the x-velocity, `[nx + 1, ny]` (`[nx, ny]` if x is periodic).
    pub fn shape_x(&self) -> [usize; 2] {
        [self.nx + usize::from(!self.periodic_x()), self.ny]
    }

    /// Shape of the y-velocity, `[nx, ny + 1]` (`[nx, ny]` if y is periodic).
    pub fn shape_y(&self) -> [usize; 2] {
        [self.nx, self.ny + usize::from(!self.periodic_y())]
    }

    /// The shape of the arrays on `lattice`.
    pub fn shape(&self, lattice: Lattice) -> [usize; 2] {
        match lattice {
            Lattice::FaceX => self.shape_x(),
            Lattice::FaceY => self.shape_y(),
            Lattice::Cell => self.cell_shape(),
        }
    }

    /// The position of entry `[a, b]` of an array on `lattice`.
    pub fn position(&self, lattice: Lattice, a: usize, b: usize) -> [f64; 2] {
        let (oa, ob) = lattice.offsets();
        [(a as f64 + oa) * self.dx, (b as f64 + ob) * self.dy]
    }

    /// The cells on either side of x-face `f` (`None` outside the domain).
    pub(crate) fn x_face_cells(&self, f: usize) -> (Option<usize>, Option<usize>) {
        face_cells(f, self.nx, self.periodic_x())
    }

    /// The cells on either side of y-face `f` (`None` outside the domain).
    pub(crate) fn y_face_cells(&self, f: usize) -> (Option<usize>, Option<usize>) {
        face_cells(f, self.ny, self.periodic_y())
    }

    /// The side a boundary face `f` of an axis with `n` cells lies on, if any.
    pub(crate) fn boundary_side(&self, lattice: Lattice, f: usize) -> Option<Side> {
        match lattice {
            Lattice::FaceX if !self.periodic_x() => match f {
                0 => Some(Side::Left),
                f if f == self.nx => Some(Side::Right),
                _ => None,
            },
            Lattice::FaceY if !self.periodic_y() => match f {
                0 => Some(Side::Bottom),
                f if f == self.ny => Some(Side::Top),
                _ => None,
            },
            _ => None,
        }
    }
}

impl AsRef<FlowGrid> for FlowGrid {
    fn as_ref(&self) -> &FlowGrid {
        self
    }
}

/// Shape checks of the arrays an operator is handed, naming the operator
/// (`step`) and the quantity in the error.
impl FlowGrid {
    /// `a` has `shape`.
    pub(crate) fn check_component<T>(
        &self,
        step: &str,
        quantity: &str,
        shape: [usize; 2],
        a: ArrayView2<'_, T>,
    ) -> Result<()> {
        if a.shape() == shape {
            Ok(())
        } else {
            Err(FlowError::shape(step, quantity, &shape, a.shape()))
        }
    }

    /// `(u_x, u_y)` lie on the faces.
    pub(crate) fn check_velocity<T>(
        &self,
        step: &str,
        ux: ArrayView2<'_, T>,
        uy: ArrayView2<'_, T>,
    ) -> Result<()> {
        self.check_component(step, "x-velocity", self.shape_x(), ux)?;
        self.check_component(step, "y-velocity", self.shape_y(), uy)
    }

    /// `a` lies on the cells.
    pub(crate) fn check_cells<T>(
        &self,
        step: &str,
        quantity: &str,
        a: ArrayView2<'_, T>,
    ) -> Result<()> {
        self.check_component(step, quantity, self.cell_shape(), a)
    }

    /// `w` holds one wall speed per side.
    pub(crate) fn check_walls<T>(&self, step: &str, w: ArrayView1<'_, T>) -> Result<()> {
        if w.len() == Side::ALL.len() {
            Ok(())
        } else {
            Err(FlowError::shape(step, "wall speeds", &[4], w.shape()))
        }
    }
}

impl Lattice {
    /// The fractional offsets of entry `[0, 0]` from the origin, in cells.
    pub(crate) fn offsets(self) -> (f64, f64) {
        match self {
            Lattice::FaceX => (0.0, 0.5),
            Lattice::FaceY => (0.5, 0.0),
            Lattice::Cell => (0.5, 0.5),
        }
    }
}

#[inline]
fn face_cells(f: usize, n: usize, periodic: bool) -> (Option<usize>, Option<usize>) {
    if periodic {
        // (f − 1) mod n and f mod n, without a division in the inner loops
        let hi = if f < n { f } else { f % n };
        let lo = if hi == 0 { n - 1 } else { hi - 1 };
        (Some(lo), Some(hi))
    } else {
        (f.checked_sub(1), (f < n).then_some(f))
    }
}
