//! The cell-centred Laplacian, 3-point in 1D and 5-point in 2D.

use diffphys_tape::{parallel, Real};
use ndarray::{ArrayD, ArrayViewD, ArrayViewMutD, IxDyn};

use super::{edge_indices, next, prev, push_row, with_slices, Ghost, Neighbour};
use crate::linear::wide;
use crate::{Grid1, Grid2, LinearOperator};

/// `σ·x + kx·δ²ₓx + ky·δ²ᵧx` on a row-major `nx × ny` array, with
/// `δ²x_i = x_{i−1} − 2x_i + x_{i+1}` and ghost cells from each axis' [`Ghost`]:
/// the one kernel behind the Laplacians (σ = 0) and explicit diffusion (σ = 1).
/// A 1D field is a single row with `kx = 0`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct FivePoint {
    pub(crate) nx: usize,
    pub(crate) ny: usize,
    pub(crate) kx: f64,
    pub(crate) ky: f64,
    pub(crate) shift: f64,
    pub(crate) gx: Ghost,
    pub(crate) gy: Ghost,
}

impl FivePoint {
    pub(crate) fn one_d(grid: &Grid1, c: f64, shift: f64) -> Self {
        FivePoint {
            nx: 1,
            ny: grid.n,
            kx: 0.0,
            ky: c / (grid.dx * grid.dx),
            shift,
            gx: Ghost::Mirror(1.0),
            gy: Ghost::scalar(grid.boundary),
        }
    }

    pub(crate) fn two_d(grid: &Grid2, c: f64, shift: f64) -> Self {
        FivePoint {
            nx: grid.nx,
            ny: grid.ny,
            kx: c / (grid.dx * grid.dx),
            ky: c / (grid.dy * grid.dy),
            shift,
            gx: Ghost::scalar(grid.boundary_x),
            gy: Ghost::scalar(grid.boundary_y),
        }
    }

    fn centre(&self) -> f64 {
        self.shift - 2.0 * (self.kx + self.ky)
    }

    /// `out = A x`, returning `<x, A x>` accumulated in `f64` when `DOT` (else
    /// zero).
    ///
    /// Blocks of whole rows of about [`parallel::CHUNK`] cells run on all cores
    /// for large grids; each block sums its rows' dot products, and the blocks'
    /// sums are added in order, so the result does not depend on the number of
    /// threads.
    pub(crate) fn run<T: Real, const DOT: bool>(&self, x: &[T], out: &mut [T]) -> f64 {
        let (nx, ny) = (self.nx, self.ny);
        assert_eq!(x.len(), nx * ny, "FivePoint: input length");
        assert_eq!(out.len(), nx * ny, "FivePoint: output length");
        if ny == 0 {
            return 0.0;
        }
        let rows_per_block = (parallel::CHUNK / ny).max(1);
        let parts = parallel::map_chunks_mut_by(out, rows_per_block * ny, |off, block| {
            let i0 = off / ny;
            let mut dot = 0.0;
            for (di, o) in block.chunks_exact_mut(ny).enumerate() {
                self.row(x, i0 + di, o);
                if DOT {
                    dot += row_dot(&x[(i0 + di) * ny..(i0 + di + 1) * ny], o);
                }
            }
            dot
        });
        parts.into_iter().sum()
    }

    /// Row `i` of `A x` into `o`.
    #[inline]
    fn row<T: Real>(&self, x: &[T], i: usize, o: &mut [T]) {
        let (nx, ny) = (self.nx, self.ny);
        let kx = T::from_f64(self.kx);
        let ky = T::from_f64(self.ky);
        let cc = T::from_f64(self.centre());
        let (p, q) = (prev(i, nx, self.gx), next(i, nx, self.gx));
        let (wp, wq) = (kx * T::from_f64(p.w), kx * T::from_f64(q.w));
        let xc = &x[i * ny..(i + 1) * ny];
        let xp = &x[p.idx * ny..(p.idx + 1) * ny];
        let xq = &x[q.idx * ny..(q.idx + 1) * ny];
        for j in edge_indices(ny) {
            let (l, r) = (prev(j, ny, self.gy), next(j, ny, self.gy));
            let (wl, wr) = (ky * T::from_f64(l.w), ky * T::from_f64(r.w));
            o[j] = wp * xp[j] + wq * xq[j] + cc * xc[j] + wl * xc[l.idx] + wr * xc[r.idx];
        }
        if ny <= 2 {
            return;
        }
        let inner = o[1..ny - 1].iter_mut().zip(xc.windows(3));
        if self.kx == 0.0 {
            for (o, w) in inner {
                *o = ky * (w[0] + w[2]) + cc * w[1];
            }
        } else {
            for (((o, w), &a), &b) in inner.zip(&xp[1..ny - 1]).zip(&xq[1..ny - 1]) {
                *o = wp * a + wq * b + ky * (w[0] + w[2]) + cc * w[1];
            }
        }
    }

    /// The row of `A` for cell `(i, j)` as `(column, value)` before merging.
    fn row_entries(&self, i: usize, j: usize) -> [(usize, f64); 5] {
        let ny = self.ny;
        let (p, q) = (prev(i, self.nx, self.gx), next(i, self.nx, self.gx));
        let (l, r) = (prev(j, ny, self.gy), next(j, ny, self.gy));
        let along_x = |n: Neighbour| (n.idx * ny + j, self.kx * n.w);
        let along_y = |n: Neighbour| (i * ny + n.idx, self.ky * n.w);
        [
            (i * ny + j, self.centre()),
            along_x(p),
            along_x(q),
            along_y(l),
            along_y(r),
        ]
    }

    pub(crate) fn diagonal<T: Real>(&self, shape: &[usize]) -> ArrayD<T> {
        let mut d = Vec::with_capacity(self.nx * self.ny);
        for i in 0..self.nx {
            for j in 0..self.ny {
                let row = i * self.ny + j;
                let v: f64 = self
                    .row_entries(i, j)
                    .iter()
                    .filter(|e| e.0 == row)
                    .map(|e| e.1)
                    .sum();
                d.push(T::from_f64(v));
            }
        }
        ArrayD::from_shape_vec(IxDyn(shape), d).expect("nx·ny entries")
    }

    pub(crate) fn triplets<T: Real>(&self) -> Vec<(usize, usize, T)> {
        let mut t = Vec::with_capacity(5 * self.nx * self.ny);
        for i in 0..self.nx {
            for j in 0..self.ny {
                push_row(&mut t, i * self.ny + j, &mut self.row_entries(i, j));
            }
        }
        t
    }

    pub(crate) fn apply_view<T: Real, const DOT: bool>(
        &self,
        x: ArrayViewD<'_, T>,
        out: ArrayViewMutD<'_, T>,
    ) -> f64 {
        with_slices(x, out, |x, o| self.run::<T, DOT>(x, o))
    }
}

/// `Σ x_j o_j` over one row (hot in cache), in `f64` with four lanes.
#[inline]
fn row_dot<T: Real>(x: &[T], o: &[T]) -> f64 {
    let mut acc = [0.0f64; 4];
    let (xc, oc) = (x.chunks_exact(4), o.chunks_exact(4));
    let (xr, or) = (xc.remainder(), oc.remainder());
    for (x, o) in xc.zip(oc) {
        for l in 0..4 {
            acc[l] += wide(x[l]) * wide(o[l]);
        }
    }
    for (x, o) in xr.iter().zip(or) {
        acc[0] += wide(*x) * wide(*o);
    }
    (acc[0] + acc[1]) + (acc[2] + acc[3])
}

/// Implements [`LinearOperator`] for a symmetric operator backed by a
/// [`FivePoint`] field `stencil` and a `shape` field.
macro_rules! five_point_operator {
    ($ty:ty, $name:literal) => {
        impl<T: Real> LinearOperator<T> for $ty {
            fn name(&self) -> &str {
                $name
            }
            fn input_shape(&self) -> &[usize] {
                &self.shape
            }
            fn output_shape(&self) -> &[usize] {
                &self.shape
            }
            fn apply_into(&self, x: ArrayViewD<'_, T>, out: ArrayViewMutD<'_, T>) {
                self.stencil.apply_view::<T, false>(x, out);
            }
            fn apply_transpose_into(&self, y: ArrayViewD<'_, T>, out: ArrayViewMutD<'_, T>) {
                self.stencil.apply_view::<T, false>(y, out);
            }
            fn apply_into_dot(&self, x: ArrayViewD<'_, T>, out: ArrayViewMutD<'_, T>) -> f64 {
                self.stencil.apply_view::<T, true>(x, out)
            }
            fn is_symmetric(&self) -> bool {
                true
            }
            fn diagonal(&self) -> Option<ArrayD<T>> {
                Some(self.stencil.diagonal(&self.shape))
            }
            fn triplets(&self) -> Option<Vec<(usize, usize, T)>> {
                Some(self.stencil.triplets())
            }
        }
    };
}
pub(crate) use five_point_operator;

/// The cell-centred 1D Laplacian times a constant, `c·∇²`, on a [`Grid1`]:
/// `(A x)_i = c·(x_{i−1} − 2x_i + x_{i+1})/dx²`.
///
/// Beyond an edge, a periodic grid wraps; zero Dirichlet reads the ghost
/// `x_{−1} = −x_0` (the wall value is zero), closed walls `x_{−1} = x_0` (zero
/// flux). The matrix is symmetric, so the adjoint is the operator itself:
/// `Aᵀ = A`. `−∇²` ([`Laplacian1::negative`]) is positive definite with zero
/// Dirichlet walls and positive semidefinite (constants in its kernel) otherwise.
///
/// # References
/// R. J. LeVeque, *Finite Difference Methods for Ordinary and Partial Differential
/// Equations*, SIAM 2007, §2.1 and §2.12 (ghost cells for Neumann conditions).
#[derive(Debug, Clone, PartialEq)]
pub struct Laplacian1 {
    grid: Grid1,
    scale: f64,
    shape: [usize; 1],
    stencil: FivePoint,
}

impl Laplacian1 {
    /// `∇²` on `grid`.
    pub fn new(grid: Grid1) -> Self {
        Self::with_scale(grid, 1.0)
    }

    /// `−∇²` on `grid`.
    pub fn negative(grid: Grid1) -> Self {
        Self::with_scale(grid, -1.0)
    }

    /// The same stencil multiplied by `c`.
    pub fn scaled(self, c: f64) -> Self {
        Self::with_scale(self.grid, self.scale * c)
    }

    fn with_scale(grid: Grid1, scale: f64) -> Self {
        Laplacian1 {
            grid,
            scale,
            shape: grid.shape(),
            stencil: FivePoint::one_d(&grid, scale, 0.0),
        }
    }

    /// The grid.
    pub fn grid(&self) -> &Grid1 {
        &self.grid
    }

    /// The factor `c` in `c·∇²`.
    pub fn scale(&self) -> f64 {
        self.scale
    }
}

five_point_operator!(Laplacian1, "laplacian_1d");

/// The cell-centred 2D Laplacian times a constant, `c·∇²`, on a [`Grid2`] (fields
/// of shape `[nx, ny]`):
/// `(A x)_{ij} = c·[(x_{i−1,j} − 2x_{ij} + x_{i+1,j})/dx² + (x_{i,j−1} − 2x_{ij} + x_{i,j+1})/dy²]`.
///
/// Each axis closes with its own boundary as in [`Laplacian1`] (wrap, ghost
/// `−x` for zero Dirichlet, ghost `+x` for closed walls). Symmetric: `Aᵀ = A`.
/// `−∇²` ([`Laplacian2::negative`]) is positive definite if any axis has zero
/// Dirichlet walls, positive semidefinite otherwise.
///
/// # References
/// R. J. LeVeque, *Finite Difference Methods for Ordinary and Partial Differential
/// Equations*, SIAM 2007, §3.2 (the 5-point Laplacian).
#[derive(Debug, Clone, PartialEq)]
pub struct Laplacian2 {
    grid: Grid2,
    scale: f64,
    shape: [usize; 2],
    stencil: FivePoint,
}

impl Laplacian2 {
    /// `∇²` on `grid`.
    pub fn new(grid: Grid2) -> Self {
        Self::with_scale(grid, 1.0)
    }

    /// `−∇²` on `grid`.
    pub fn negative(grid: Grid2) -> Self {
        Self::with_scale(grid, -1.0)
    }

    /// The same stencil multiplied by `c`.
    pub fn scaled(self, c: f64) -> Self {
        Self::with_scale(self.grid, self.scale * c)
    }

    fn with_scale(grid: Grid2, scale: f64) -> Self {
        Laplacian2 {
            grid,
            scale,
            shape: grid.shape(),
            stencil: FivePoint::two_d(&grid, scale, 0.0),
        }
    }

    /// The grid.
    pub fn grid(&self) -> &Grid2 {
        &self.grid
    }

    /// The factor `c` in `c·∇²`.
    pub fn scale(&self) -> f64 {
        self.scale
    }
}

five_point_operator!(Laplacian2, "laplacian_2d");
