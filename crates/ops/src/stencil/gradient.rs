//! The cell-centred gradient by central differences.

use diffphys_tape::Real;
use ndarray::{ArrayViewD, ArrayViewMutD};

use super::{central_difference, central_difference_entries, push_row, with_slices, Ghost};
use crate::{Grid1, Grid2, LinearOperator};

/// The 1D gradient of a cell-centred scalar by central differences:
/// `(G x)_i = (x_{i+1} − x_{i−1}) / (2 dx)`.
///
/// Ghost cells as for [`super::Laplacian1`]: periodic wraps, zero Dirichlet reads
/// `−x` (zero on the wall), closed walls `+x` (zero normal derivative).
///
/// Adjoint: a central difference with the opposite ghost sign, negated,
/// `Gₛᵀ = −G₋ₛ`, so with closed walls `Gᵀ = −D` for the
/// [`super::Divergence1`] of the same grid (no flow through the wall), and with
/// periodic boundaries `Gᵀ = −G`.
///
/// # References
/// R. J. LeVeque, *Finite Difference Methods for Ordinary and Partial Differential
/// Equations*, SIAM 2007, §1.1.
#[derive(Debug, Clone, PartialEq)]
pub struct Gradient1 {
    grid: Grid1,
    shape: [usize; 1],
}

impl Gradient1 {
    /// The gradient on `grid`.
    pub fn new(grid: Grid1) -> Self {
        Gradient1 {
            grid,
            shape: grid.shape(),
        }
    }

    /// The grid.
    pub fn grid(&self) -> &Grid1 {
        &self.grid
    }

    fn c(&self) -> f64 {
        0.5 / self.grid.dx
    }
}

impl<T: Real> LinearOperator<T> for Gradient1 {
    fn name(&self) -> &str {
        "gradient_1d"
    }
    fn input_shape(&self) -> &[usize] {
        &self.shape
    }
    fn output_shape(&self) -> &[usize] {
        &self.shape
    }
    fn apply_into(&self, x: ArrayViewD<'_, T>, out: ArrayViewMutD<'_, T>) {
        let (n, g) = (self.grid.n, Ghost::scalar(self.grid.boundary));
        with_slices(x, out, |x, o| {
            central_difference::<T, false>(x, o, 1, n, 1, self.c(), g);
        });
    }
    fn apply_transpose_into(&self, y: ArrayViewD<'_, T>, out: ArrayViewMutD<'_, T>) {
        let (n, g) = (self.grid.n, Ghost::scalar(self.grid.boundary).flipped());
        with_slices(y, out, |y, o| {
            central_difference::<T, false>(y, o, 1, n, 1, -self.c(), g);
        });
    }
    fn triplets(&self) -> Option<Vec<(usize, usize, T)>> {
        let mut t = Vec::new();
        let g = Ghost::scalar(self.grid.boundary);
        central_difference_entries(1, self.grid.n, 1, self.c(), g, 0, 0, |row, mut e| {
            push_row(&mut t, row, &mut e)
        });
        Some(t)
    }
}

/// The 2D gradient of a cell-centred scalar of shape `[nx, ny]` by central
/// differences, as a vector field of shape `[2, nx, ny]` (components `[∂ₓ, ∂ᵧ]`):
/// `(G x)_{0,ij} = (x_{i+1,j} − x_{i−1,j})/(2dx)`,
/// `(G x)_{1,ij} = (x_{i,j+1} − x_{i,j−1})/(2dy)`.
///
/// Ghost cells per axis as in [`Gradient1`]. Adjoint: `Gᵀ y = −D₋ₛ,ₓ y₀ − D₋ₛ,ᵧ y₁`,
/// the central differences with flipped ghost signs, which is `−D` for the
/// [`super::Divergence2`] of a periodic or closed grid.
///
/// # References
/// R. J. LeVeque, *Finite Difference Methods for Ordinary and Partial Differential
/// Equations*, SIAM 2007, §1.1.
#[derive(Debug, Clone, PartialEq)]
pub struct Gradient2 {
    grid: Grid2,
    input: [usize; 2],
    output: [usize; 3],
}

impl Gradient2 {
    /// The gradient on `grid`.
    pub fn new(grid: Grid2) -> Self {
        Gradient2 {
            grid,
            input: grid.shape(),
            output: [2, grid.nx, grid.ny],
        }
    }

    /// The grid.
    pub fn grid(&self) -> &Grid2 {
        &self.grid
    }

    fn axes(&self) -> [(f64, Ghost); 2] {
        [
            (0.5 / self.grid.dx, Ghost::scalar(self.grid.boundary_x)),
            (0.5 / self.grid.dy, Ghost::scalar(self.grid.boundary_y)),
        ]
    }
}

impl<T: Real> LinearOperator<T> for Gradient2 {
    fn name(&self) -> &str {
        "gradient_2d"
    }
    fn input_shape(&self) -> &[usize] {
        &self.input
    }
    fn output_shape(&self) -> &[usize] {
        &self.output
    }
    fn apply_into(&self, x: ArrayViewD<'_, T>, out: ArrayViewMutD<'_, T>) {
        let (nx, ny) = (self.grid.nx, self.grid.ny);
        with_slices(x, out, |x, o| {
            let (ox, oy) = o.split_at_mut(nx * ny);
            let [(cx, gx), (cy, gy)] = self.axes();
            central_difference::<T, false>(x, ox, nx, ny, 0, cx, gx);
            central_difference::<T, false>(x, oy, nx, ny, 1, cy, gy);
        });
    }
    fn apply_transpose_into(&self, y: ArrayViewD<'_, T>, out: ArrayViewMutD<'_, T>) {
        let (nx, ny) = (self.grid.nx, self.grid.ny);
        with_slices(y, out, |y, o| {
            let (yx, yy) = y.split_at(nx * ny);
            let [(cx, gx), (cy, gy)] = self.axes();
            central_difference::<T, false>(yx, o, nx, ny, 0, -cx, gx.flipped());
            central_difference::<T, true>(yy, o, nx, ny, 1, -cy, gy.flipped());
        });
    }
    fn triplets(&self) -> Option<Vec<(usize, usize, T)>> {
        let (nx, ny) = (self.grid.nx, self.grid.ny);
        let mut t = Vec::new();
        for (axis, (c, g)) in self.axes().into_iter().enumerate() {
            central_difference_entries(nx, ny, axis, c, g, axis * nx * ny, 0, |row, mut e| {
                push_row(&mut t, row, &mut e)
            });
        }
        Some(t)
    }
}
