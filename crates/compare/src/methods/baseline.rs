//! The straightforward conjugate gradient: the baseline of the per-iteration
//! speed floor, written the way CG is usually first written.
//!
//! This is deliberately the naive reference, not a method to use: one loop per
//! vector operation (the stencil, each dot product, each axpy in its own pass
//! over memory), and a stencil that decides at every cell whether each neighbour
//! lies across a wall. The solver of the implicit path fuses the stencil with the
//! curvature `<p, A p>` and keeps the boundary out of the inner loop; the harness
//! times both in the same run and reports the ratio per iteration.
//!
//! Six passes per iteration: `A p`, `<p, A p>`, `x += α p`, `r −= α A p`,
//! `<r, r>`, `p = r + β p`.
//!
//! # References
//! M. R. Hestenes and E. Stiefel, *Methods of conjugate gradients for solving
//! linear systems*, J. Res. Nat. Bur. Standards 49 (1952), the algorithm as
//! written here.

use diffphys_ops::{Boundary, Grid2};
use diffphys_tape::Real;

use super::Stop;
use crate::{CompareError, Result};

/// What lies across a wall of one axis, for [`StraightforwardLaplacian`].
#[derive(Debug, Clone, Copy, PartialEq)]
enum Across {
    /// The opposite edge cell.
    Wrap,
    /// A ghost equal to `s ×` the edge cell.
    Mirror(f64),
}

impl Across {
    fn of(b: Boundary) -> Self {
        match b {
            Boundary::Periodic => Across::Wrap,
            Boundary::ZeroDirichlet => Across::Mirror(-1.0),
            Boundary::Closed => Across::Mirror(1.0),
        }
    }
}

/// `A = −∇²` on a [`Grid2`], the same matrix as
/// [`diffphys_ops::stencil::Laplacian2::negative`], applied cell by cell with the
/// boundary tested for every neighbour:
/// `(A x)_{ij} = (2x_{ij} − x_{i−1,j} − x_{i+1,j})/dx² + (2x_{ij} − x_{i,j−1} − x_{i,j+1})/dy²`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StraightforwardLaplacian {
    nx: usize,
    ny: usize,
    kx: f64,
    ky: f64,
    across_x: Across,
    across_y: Across,
}

impl StraightforwardLaplacian {
    /// `−∇²` on `grid`.
    pub fn negative(grid: &Grid2) -> Self {
        StraightforwardLaplacian {
            nx: grid.nx,
            ny: grid.ny,
            kx: 1.0 / (grid.dx * grid.dx),
            ky: 1.0 / (grid.dy * grid.dy),
            across_x: Across::of(grid.boundary_x),
            across_y: Across::of(grid.boundary_y),
        }
    }

    /// Cells in the field.
    pub fn len(&self) -> usize {
        self.nx * self.ny
    }

    /// True for a grid without cells (never: grids have at least one).
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// `out = A x` on row-major slices of length [`Self::len`].
    ///
    /// # Errors
    /// [`CompareError::InvalidArgument`] if a slice has another length.
    pub fn apply<T: Real>(&self, x: &[T], out: &mut [T]) -> Result<()> {
        self.check_lengths(x.len(), out.len(), "x", "out")?;
        self.stencil(x, out);
        Ok(())
    }

    fn check_lengths(&self, a: usize, b: usize, a_name: &str, b_name: &str) -> Result<()> {
        let n = self.len();
        if a != n || b != n {
            return Err(CompareError::invalid(format!(
                "baseline CG: operator on {}×{} has {n} cells, {a_name} has {a}, {b_name} has {b}",
                self.nx, self.ny
            )));
        }
        Ok(())
    }

    /// [`Self::apply`] on slices whose lengths the caller checked.
    fn stencil<T: Real>(&self, x: &[T], out: &mut [T]) {
        let (nx, ny) = (self.nx, self.ny);
        let kx = T::from_f64(self.kx);
        let ky = T::from_f64(self.ky);
        let two = T::from_f64(2.0);
        let at = |i: usize, j: usize| x[i * ny + j];
        let neighbour = |edge: T, wrapped: T, across: Across| match across {
            Across::Wrap => wrapped,
            Across::Mirror(s) => T::from_f64(s) * edge,
        };
        for i in 0..nx {
            for j in 0..ny {
                let c = at(i, j);
                let west = if i > 0 {
                    at(i - 1, j)
                } else {
                    neighbour(c, at(nx - 1, j), self.across_x)
                };
                let east = if i + 1 < nx {
                    at(i + 1, j)
                } else {
                    neighbour(c, at(0, j), self.across_x)
                };
                let south = if j > 0 {
                    at(i, j - 1)
                } else {
                    neighbour(c, at(i, ny - 1), self.across_y)
                };
                let north = if j + 1 < ny {
                    at(i, j + 1)
                } else {
                    neighbour(c, at(i, 0), self.across_y)
                };
                out[i * ny + j] = kx * (two * c - west - east) + ky * (two * c - south - north);
            }
        }
    }
}

/// What [`baseline_cg`] did.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BaselineCgInfo {
    /// Iterations performed.
    pub iterations: usize,
    /// `‖r‖/‖b‖` from the recurrence at the end.
    pub relative_residual: f64,
}

fn dot<T: Real>(a: &[T], b: &[T]) -> T {
    let mut s = T::zero();
    for (&u, &v) in a.iter().zip(b) {
        s += u * v;
    }
    s
}

/// `y += a·x`.
fn axpy<T: Real>(a: T, x: &[T], y: &mut [T]) {
    for (y, &x) in y.iter_mut().zip(x) {
        *y += a * x;
    }
}

/// Solves `A x = b` from the initial `x` by conjugate gradient, one loop per
/// vector operation (see the module docs). Stops as `stop` says; a tolerance not
/// met within the cap is not an error here (the baseline is for timing; the
/// residual is returned).
///
/// # Errors
/// [`CompareError::InvalidArgument`] if a slice length differs from the
/// operator's, [`CompareError::NonFinite`] if the curvature `<p, A p>` or the
/// residual becomes non-finite or the curvature non-positive (breakdown).
pub fn baseline_cg<T: Real>(
    a: &StraightforwardLaplacian,
    b: &[T],
    x: &mut [T],
    stop: Stop,
) -> Result<BaselineCgInfo> {
    a.check_lengths(b.len(), x.len(), "b", "x")?;
    let n = a.len();
    let breakdown = |what: String| CompareError::NonFinite {
        method: "baseline_cg".to_string(),
        what,
    };
    let mut r = vec![T::zero(); n];
    let mut ap = vec![T::zero(); n];
    a.stencil(x, &mut ap);
    for ((r, &b), &ap) in r.iter_mut().zip(b).zip(&ap) {
        *r = b - ap;
    }
    let mut p = r.clone();
    let mut rr = dot(&r, &r);
    let b_norm = dot(b, b).sqrt().as_f64();
    let scale = if b_norm > 0.0 { b_norm } else { 1.0 };
    let mut iterations = 0;
    while iterations < stop.max_iters() {
        if let Stop::Tolerance { rtol, .. } = stop {
            if rr.sqrt().as_f64() <= rtol * scale {
                break;
            }
        }
        if rr == T::zero() {
            break;
        }
        a.stencil(&p, &mut ap);
        let pap = dot(&p, &ap);
        if !(pap.is_finite() && pap > T::zero()) {
            return Err(breakdown(format!(
                "curvature <p, A p> = {pap} at iteration {iterations}"
            )));
        }
        let alpha = rr / pap;
        axpy(alpha, &p, x);
        axpy(-alpha, &ap, &mut r);
        let rr_new = dot(&r, &r);
        if !rr_new.is_finite() {
            return Err(breakdown(format!(
                "residual norm² {rr_new} at iteration {iterations}"
            )));
        }
        let beta = rr_new / rr;
        for (p, &r) in p.iter_mut().zip(&r) {
            *p = r + beta * *p;
        }
        rr = rr_new;
        iterations += 1;
    }
    Ok(BaselineCgInfo {
        iterations,
        relative_residual: rr.sqrt().as_f64() / scale,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use diffphys_ops::stencil::Laplacian2;
    use diffphys_ops::LinearOperator;
    use diffphys_tape::test_array;

    #[test]
    fn same_matrix_as_the_ops_laplacian_for_every_boundary() {
        let kinds = [
            Boundary::Periodic,
            Boundary::ZeroDirichlet,
            Boundary::Closed,
        ];
        for bx in kinds {
            for by in kinds {
                let grid = Grid2::new(5, 4, 0.5, 0.25, Boundary::Periodic)
                    .unwrap()
                    .with_boundaries(bx, by);
                let x = test_array::<f64>(&[5, 4], 3);
                let want = Laplacian2::negative(grid).apply(x.view()).unwrap();
                let mut got = vec![0.0; 20];
                StraightforwardLaplacian::negative(&grid)
                    .apply(x.as_slice().unwrap(), &mut got)
                    .unwrap();
                for (g, w) in got.iter().zip(want.iter()) {
                    assert!((g - w).abs() <= 1e-12 * w.abs().max(1.0), "{bx:?}/{by:?}");
                }
            }
        }
    }

    #[test]
    fn solves_a_manufactured_system() {
        // b = A x*, so CG must return x* (to the tolerance).
        let grid = Grid2::square(12, 12, 1.0 / 12.0, Boundary::ZeroDirichlet).unwrap();
        let a = StraightforwardLaplacian::negative(&grid);
        let x_star = test_array::<f64>(&[12, 12], 7);
        let mut b = vec![0.0; 144];
        a.apply(x_star.as_slice().unwrap(), &mut b).unwrap();
        let mut x = vec![0.0; 144];
        let stop = Stop::Tolerance {
            rtol: 1e-12,
            max_iters: 1000,
        };
        let info = baseline_cg(&a, &b, &mut x, stop).unwrap();
        assert!(info.relative_residual <= 1e-12);
        assert!(info.iterations < 144 + 20);
        for (g, w) in x.iter().zip(x_star.iter()) {
            assert!((g - w).abs() < 1e-9);
        }
    }

    #[test]
    fn fixed_count_runs_exactly_that_many_iterations() {
        let grid = Grid2::square(8, 8, 1.0 / 8.0, Boundary::ZeroDirichlet).unwrap();
        let a = StraightforwardLaplacian::negative(&grid);
        let b = vec![1.0f32; 64];
        let mut x = vec![0.0f32; 64];
        let info = baseline_cg(&a, &b, &mut x, Stop::Iterations(5)).unwrap();
        assert_eq!(info.iterations, 5);
        assert!(baseline_cg(&a, &b[..10], &mut x, Stop::Iterations(5)).is_err());
    }

    #[test]
    fn slices_of_the_wrong_length_or_empty_are_typed_errors() {
        let grid = Grid2::square(4, 4, 0.25, Boundary::ZeroDirichlet).unwrap();
        let a = StraightforwardLaplacian::negative(&grid);
        let mut out = vec![0.0f64; 16];
        for x in [&[][..], &[1.0; 15][..]] {
            let e = a.apply(x, &mut out).unwrap_err();
            assert!(matches!(e, CompareError::InvalidArgument(_)), "{e}");
            assert!(e.to_string().contains("16 cells"), "{e}");
        }
        assert!(a.apply(&[1.0; 16], &mut []).is_err());
        let mut x: Vec<f64> = Vec::new();
        assert!(baseline_cg(&a, &[], &mut x, Stop::Iterations(3)).is_err());
    }
}
