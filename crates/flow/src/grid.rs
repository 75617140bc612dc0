//! The staggered (MAC) grid of a flow: its cells and faces, in the one layout
//! of [`diffphys_ops::staggered`] (the table of shapes and positions is
//! there), and the four side conditions on its boundary faces, whose values
//! they fix or leave free (see [`crate::boundaries`]). The arrays of a flow
//! are the arrays of diffphys-ops' pressure projection
//! ([`diffphys_ops::mac::MacGrid`], built by [`FlowGrid::mac`]).

use diffphys_ops::mac::MacGrid;
use diffphys_ops::{CellMask, Grid2};
use ndarray::{Array2, ArrayView1, ArrayView2};

use diffphys_ops::staggered::face_cells;
pub use diffphys_ops::staggered::Lattice;

use crate::error::{FlowError, Result};
use crate::sides::{PressureSide, Side, Sides};

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

    /// The same grid as diffphys-ops' staggered grid (the same layout and
    /// arrays), each side open or closed by its condition's pressure side
    /// ([`crate::sides::SideCondition::pressure`]), the cells where `solid`
    /// is true inactive: what its pressure projection
    /// ([`diffphys_ops::projection::PressureProjection`]) and multigrid
    /// cycle take.
    ///
    /// # Errors
    /// [`FlowError::Shape`] if `solid` is not of [`FlowGrid::cell_shape`].
    pub fn mac(&self, solid: Option<&Array2<bool>>) -> Result<MacGrid> {
        let s = &self.sides;
        let sides = [&s.left, &s.right, &s.bottom, &s.top].map(|b| b.pressure());
        let g = Grid2::new(self.nx, self.ny, self.dx, self.dy, PressureSide::Closed)?;
        let mask = match solid {
            Some(m) if m.iter().any(|&v| v) => {
                self.check_cells("mac", "solid mask", m.view())?;
                Some(CellMask::from_array(m.mapv(|v| !v).into_dyn().view()))
            }
            _ => None,
        };
        Ok(MacGrid::with_sides(g, sides, mask)?)
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
