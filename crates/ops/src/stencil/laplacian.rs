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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::stencil::test_support;
    use crate::Boundary;
    use diffphys_tape::test_array;
    use ndarray::{arr1, arr2};

    const KINDS: [Boundary; 3] = [
        Boundary::Periodic,
        Boundary::ZeroDirichlet,
        Boundary::Closed,
    ];

    /// `A x` from the triplets, as a dense product.
    fn apply_triplets(t: &[(usize, usize, f64)], x: &ArrayD<f64>) -> Vec<f64> {
        let xs = x.as_slice().unwrap();
        let mut y = vec![0.0; xs.len()];
        for &(r, c, v) in t {
            y[r] += v * xs[c];
        }
        y
    }

    /// The shared checks, the triplets applied as a sparse product, the fused
    /// dot product and the diagonal.
    fn check_operator(a: &dyn LinearOperator<f64>, seed: u64, coef: f64) {
        test_support::check_operator_with_scale(a, seed, coef);
        let x = test_array::<f64>(a.input_shape(), seed);
        let ax = a.apply(x.view()).unwrap();
        let from_triplets = apply_triplets(&a.triplets().unwrap(), &x);
        for (p, q) in ax.iter().zip(&from_triplets) {
            assert!((p - q).abs() <= 1e-12 * (1.0 + p.abs()), "{p} vs {q}");
        }

        let mut out = ArrayD::zeros(IxDyn(a.output_shape()));
        let dot = a.apply_into_dot(x.view(), out.view_mut());
        // <x, A x> computed in the same pass agrees with the separate sum.
        let expect: f64 = x.iter().zip(&ax).map(|(p, q)| p * q).sum();
        assert!((dot - expect).abs() <= 1e-12 * expect.abs().max(1.0));
        assert_eq!(out, ax);

        let diag = a.diagonal().unwrap();
        let n = x.len();
        for (k, d) in diag.iter().enumerate() {
            let mut e = vec![0.0; n];
            e[k] = 1.0;
            let col = a
                .apply(
                    ArrayD::from_shape_vec(IxDyn(a.input_shape()), e)
                        .unwrap()
                        .view(),
                )
                .unwrap();
            assert!((col.as_slice().unwrap()[k] - d).abs() < 1e-12);
        }
    }

    #[test]
    fn one_d_stencil_values_by_boundary() {
        let x = arr1(&[1.0, 2.0, 4.0, 8.0]).into_dyn();
        let grid = |b| Grid1::new(4, 0.5, 0.0, b).unwrap();
        // 1/dx² = 4; interior cells: 4·(x₀ − 2x₁ + x₂) = 4·(1 − 4 + 4) = 4, 4·(2 − 8 + 8) = 8.
        let periodic = Laplacian1::new(grid(Boundary::Periodic))
            .apply(x.view())
            .unwrap();
        // wrap: 4·(8 − 2 + 2) = 32, 4·(4 − 16 + 1) = −44
        assert_eq!(periodic, arr1(&[32.0, 4.0, 8.0, -44.0]).into_dyn());
        let dirichlet = Laplacian1::new(grid(Boundary::ZeroDirichlet))
            .apply(x.view())
            .unwrap();
        // ghost −x: 4·(−1 − 2 + 2) = −4, 4·(4 − 16 − 8) = −80
        assert_eq!(dirichlet, arr1(&[-4.0, 4.0, 8.0, -80.0]).into_dyn());
        let closed = Laplacian1::negative(grid(Boundary::Closed))
            .scaled(0.5)
            .apply(x.view())
            .unwrap();
        // −½·: ghost +x: 4·(1 − 2 + 2) = 4, 4·(4 − 16 + 8) = −16
        assert_eq!(closed, arr1(&[-2.0, -2.0, -4.0, 8.0]).into_dyn());
    }

    #[test]
    fn two_d_stencil_on_a_non_square_grid() {
        // dx = 1, dy = 0.5: kx = 1, ky = 4.
        let grid = Grid2::new(2, 3, 1.0, 0.5, Boundary::Closed)
            .unwrap()
            .with_boundaries(Boundary::ZeroDirichlet, Boundary::Periodic);
        let x = arr2(&[[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]]).into_dyn();
        let ax = Laplacian2::new(grid).apply(x.view()).unwrap();
        // (0,0): x: (−1) − 2·1 + 4 = 1; y (wrap): 3 − 2 + 2 = 3 → 1 + 4·3 = 13
        // (0,1): x: −2 − 4 + 5 = −1; y: 1 − 4 + 3 = 0 → −1
        // (1,2): x: 3 − 12 − 6 = −15; y: 5 − 12 + 4 = −3 → −15 − 12 = −27
        assert_eq!(ax[[0, 0]], 13.0);
        assert_eq!(ax[[0, 1]], -1.0);
        assert_eq!(ax[[1, 2]], -27.0);
    }

    #[test]
    fn adjoint_triplets_dot_and_diagonal_for_every_boundary_1d() {
        for (k, b) in KINDS.into_iter().enumerate() {
            for n in [1, 2, 3, 7] {
                let g = Grid1::new(n, 0.3, 0.0, b).unwrap();
                // the centre coefficient 2/dx² bounds the others
                let coef = 2.0 / (0.3 * 0.3);
                check_operator(&Laplacian1::new(g), 10 * k as u64 + n as u64, coef);
                check_operator(
                    &Laplacian1::negative(g).scaled(2.5),
                    7 + n as u64,
                    2.5 * coef,
                );
            }
        }
    }

    #[test]
    fn adjoint_triplets_dot_and_diagonal_for_every_boundary_2d() {
        for (k, bx) in KINDS.into_iter().enumerate() {
            for (m, by) in KINDS.into_iter().enumerate() {
                for (nx, ny) in [(1, 1), (1, 4), (5, 1), (2, 2), (4, 7), (6, 3)] {
                    let g = Grid2::new(nx, ny, 0.7, 0.2, Boundary::Periodic)
                        .unwrap()
                        .with_boundaries(bx, by);
                    let seed = (100 * k + 10 * m + nx * ny) as u64;
                    let coef = 2.0 / (0.7 * 0.7) + 2.0 / (0.2 * 0.2);
                    check_operator(&Laplacian2::new(g), seed, coef);
                    check_operator(&Laplacian2::negative(g).scaled(0.3), seed + 3, 0.3 * coef);
                }
            }
        }
    }

    #[test]
    fn negative_laplacian_is_positive_definite_with_dirichlet_walls() {
        let g = Grid2::new(5, 4, 0.1, 0.3, Boundary::ZeroDirichlet).unwrap();
        let a = Laplacian2::negative(g);
        for seed in 0..5 {
            let x = test_array::<f64>(&[5, 4], seed);
            let mut out = ArrayD::zeros(IxDyn(&[5, 4]));
            assert!(a.apply_into_dot(x.view(), out.view_mut()) > 0.0);
        }
        // Periodic and closed: constants are in the kernel.
        for b in [Boundary::Periodic, Boundary::Closed] {
            let g = Grid2::new(5, 4, 0.1, 0.3, b).unwrap();
            let ones = ArrayD::<f64>::ones(IxDyn(&[5, 4]));
            let a1 = Laplacian2::negative(g).apply(ones.view()).unwrap();
            assert!(a1.iter().all(|v| v.abs() < 1e-10), "{b:?}");
        }
    }

    #[test]
    fn f32_matches_f64_and_strided_views_work() {
        let g = Grid2::new(6, 5, 0.5, 0.25, Boundary::Closed).unwrap();
        let a = Laplacian2::new(g);
        let x = test_array::<f64>(&[6, 5], 3);
        let ax = a.apply(x.view()).unwrap();
        let x32 = x.mapv(|v| v as f32);
        let ax32 = LinearOperator::<f32>::apply(&a, x32.view()).unwrap();
        for (p, q) in ax.iter().zip(&ax32) {
            assert!((p - f64::from(*q)).abs() < 1e-4 * (1.0 + p.abs()));
        }
        // A transposed (non-standard-layout) input of shape [6, 5].
        let xt = x.t().to_owned();
        let ax_t = a.apply(xt.t()).unwrap();
        assert_eq!(ax_t, ax);
        // A non-contiguous output view.
        let mut big = ArrayD::<f64>::zeros(IxDyn(&[5, 6]));
        a.apply_into(x.view(), big.view_mut().reversed_axes());
        assert_eq!(big.t(), ax);
    }
}
