//! The divergence of a cell-centred vector field by central differences.

use diffphys_tape::Real;
use ndarray::{ArrayViewD, ArrayViewMutD};

use super::{central_difference, central_difference_entries, push_row, with_slices, Ghost};
use crate::{Boundary, Grid1, Grid2, LinearOperator};

/// The ghost of a velocity component normal to a wall: periodic wraps; zero
/// Dirichlet and closed walls both mean no flow through the wall, so the ghost
/// mirrors with `−1` (the normal component is zero on the wall).
fn normal_ghost(b: Boundary) -> Ghost {
    match b {
        Boundary::Periodic => Ghost::Wrap,
        Boundary::ZeroDirichlet | Boundary::Closed => Ghost::Mirror(-1.0),
    }
}

/// The 1D divergence of a cell-centred velocity by central differences:
/// `(D v)_i = (v_{i+1} − v_{i−1}) / (2 dx)`, with the ghost `v_{−1} = −v_0` at a
/// wall (zero Dirichlet or closed: no flow through it) and wrapping when periodic.
///
/// Adjoint: `Dᵀ = −G₊` where `G₊` is the central difference with ghost `+v`, which
/// is the [`super::Gradient1`] of a closed grid: `Dᵀ = −G` for periodic and closed
/// grids, the discrete form of `∫ p ∇·v = −∫ v·∇p`.
///
/// # References
/// R. J. LeVeque, *Finite Difference Methods for Ordinary and Partial Differential
/// Equations*, SIAM 2007, §1.1.
#[derive(Debug, Clone, PartialEq)]
pub struct Divergence1 {
    grid: Grid1,
    shape: [usize; 1],
}

impl Divergence1 {
    /// The divergence on `grid`.
    pub fn new(grid: Grid1) -> Self {
        Divergence1 {
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

impl<T: Real> LinearOperator<T> for Divergence1 {
    fn name(&self) -> &str {
        "divergence_1d"
    }
    fn input_shape(&self) -> &[usize] {
        &self.shape
    }
    fn output_shape(&self) -> &[usize] {
        &self.shape
    }
    fn apply_into(&self, x: ArrayViewD<'_, T>, out: ArrayViewMutD<'_, T>) {
        let (n, g) = (self.grid.n, normal_ghost(self.grid.boundary));
        with_slices(x, out, |x, o| {
            central_difference::<T, false>(x, o, 1, n, 1, self.c(), g);
        });
    }
    fn apply_transpose_into(&self, y: ArrayViewD<'_, T>, out: ArrayViewMutD<'_, T>) {
        let (n, g) = (self.grid.n, normal_ghost(self.grid.boundary).flipped());
        with_slices(y, out, |y, o| {
            central_difference::<T, false>(y, o, 1, n, 1, -self.c(), g);
        });
    }
    fn triplets(&self) -> Option<Vec<(usize, usize, T)>> {
        let mut t = Vec::new();
        let g = normal_ghost(self.grid.boundary);
        central_difference_entries(1, self.grid.n, 1, self.c(), g, 0, 0, |row, mut e| {
            push_row(&mut t, row, &mut e)
        });
        Some(t)
    }
}

/// The 2D divergence of a cell-centred velocity of shape `[2, nx, ny]`
/// (components `[v_x, v_y]`) by central differences, a scalar of shape `[nx, ny]`:
/// `(D v)_{ij} = (v_{x,i+1,j} − v_{x,i−1,j})/(2dx) + (v_{y,i,j+1} − v_{y,i,j−1})/(2dy)`.
///
/// Each component's ghost across a wall normal to it is `−v` (no flow through
/// zero-Dirichlet or closed walls); periodic axes wrap. Adjoint:
/// `(Dᵀ p)_0 = −G₊,ₓ p`, `(Dᵀ p)_1 = −G₊,ᵧ p`, which is `−G` for the
/// [`super::Gradient2`] of a periodic or closed grid.
///
/// # References
/// R. J. LeVeque, *Finite Difference Methods for Ordinary and Partial Differential
/// Equations*, SIAM 2007, §1.1.
#[derive(Debug, Clone, PartialEq)]
pub struct Divergence2 {
    grid: Grid2,
    input: [usize; 3],
    output: [usize; 2],
}

impl Divergence2 {
    /// The divergence on `grid`.
    pub fn new(grid: Grid2) -> Self {
        Divergence2 {
            grid,
            input: [2, grid.nx, grid.ny],
            output: grid.shape(),
        }
    }

    /// The grid.
    pub fn grid(&self) -> &Grid2 {
        &self.grid
    }

    fn axes(&self) -> [(f64, Ghost); 2] {
        [
            (0.5 / self.grid.dx, normal_ghost(self.grid.boundary_x)),
            (0.5 / self.grid.dy, normal_ghost(self.grid.boundary_y)),
        ]
    }
}

impl<T: Real> LinearOperator<T> for Divergence2 {
    fn name(&self) -> &str {
        "divergence_2d"
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
            let (vx, vy) = x.split_at(nx * ny);
            let [(cx, gx), (cy, gy)] = self.axes();
            central_difference::<T, false>(vx, o, nx, ny, 0, cx, gx);
            central_difference::<T, true>(vy, o, nx, ny, 1, cy, gy);
        });
    }
    fn apply_transpose_into(&self, y: ArrayViewD<'_, T>, out: ArrayViewMutD<'_, T>) {
        let (nx, ny) = (self.grid.nx, self.grid.ny);
        with_slices(y, out, |y, o| {
            let (ox, oy) = o.split_at_mut(nx * ny);
            let [(cx, gx), (cy, gy)] = self.axes();
            central_difference::<T, false>(y, ox, nx, ny, 0, -cx, gx.flipped());
            central_difference::<T, false>(y, oy, nx, ny, 1, -cy, gy.flipped());
        });
    }
    fn triplets(&self) -> Option<Vec<(usize, usize, T)>> {
        let (nx, ny) = (self.grid.nx, self.grid.ny);
        let [(cx, gx), (cy, gy)] = self.axes();
        // Row (i, j) reads v_x along x and v_y along y: merge both into one row.
        let mut rows: Vec<Vec<(usize, f64)>> = vec![Vec::with_capacity(4); nx * ny];
        central_difference_entries(nx, ny, 0, cx, gx, 0, 0, |row, e| {
            rows[row].extend_from_slice(&e)
        });
        central_difference_entries(nx, ny, 1, cy, gy, 0, nx * ny, |row, e| {
            rows[row].extend_from_slice(&e)
        });
        let mut t = Vec::with_capacity(4 * nx * ny);
        for (row, mut e) in rows.into_iter().enumerate() {
            push_row(&mut t, row, &mut e);
        }
        Some(t)
    }
}
