//! The pressure and viscosity systems of a fully periodic box without
//! obstacle, solved by the fast Fourier transform.
//!
//! On a box periodic in both axes with every face free, the pressure operator
//! `A = D_F D_Fᵀ` of [`crate::pressure`] is the five-point negative Laplacian
//! with wrap-around, a circulant operator, and so is `−L` for each velocity
//! component in [`crate::diffusion`] (its lattice has the cells' `nx × ny`
//! entries). The discrete Fourier modes `e^{2πi(ka/nx + lb/ny)}` are their
//! eigenvectors, with eigenvalues
//!
//! ```text
//! λ(k, l) = (2 − 2 cos(2πk/nx)) / dx² + (2 − 2 cos(2πl/ny)) / dy²
//! ```
//!
//! so `A⁺ b = F⁻¹ (F b / λ)`, with the `(0, 0)` mode (the constants, `A`'s
//! kernel) set to zero: the zero-mean solution, the same the sparse Cholesky
//! path returns for a singular operator; and the implicit viscosity step
//! `(I − ν dt L) x = r` is `x = F⁻¹ (F r / (1 + ν dt λ))`. Both operators are
//! symmetric, so the same solves are their adjoints. The cost is `O(n log n)`
//! with no factorisation and no fill-in; the result does not depend on the
//! thread count (one thread).
//!
//! # References
//! R. W. Hockney, *A fast direct solution of Poisson's equation using Fourier
//! analysis*, J. ACM 12 (1965) 95–113.

use std::fmt;
use std::sync::Arc;

use rustfft::num_complex::Complex;
use rustfft::{Fft, FftPlanner};

use crate::buffers::{for_row_blocks, give_back, scratch};
use diffphys_tape::pool;

use crate::boundaries::Faces;
use crate::grid::FlowGrid;
use crate::{FlowError, Result};

/// `A⁺` of the periodic five-point Laplacian on an `nx × ny` box.
pub(crate) struct PeriodicPoisson {
    nx: usize,
    ny: usize,
    along_y: Arc<dyn Fft<f64>>,
    along_y_inv: Arc<dyn Fft<f64>>,
    along_x: Arc<dyn Fft<f64>>,
    along_x_inv: Arc<dyn Fft<f64>>,
    /// `λ(k, l)` in the transposed layout `[l · nx + k]`.
    eigenvalues: Vec<f64>,
}

impl fmt::Debug for PeriodicPoisson {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("PeriodicPoisson")
            .field("nx", &self.nx)
            .field("ny", &self.ny)
            .finish_non_exhaustive()
    }
}

impl PeriodicPoisson {
    /// The solver of `grid` if it is a box periodic in both axes whose
    /// `faces` are all free (no solid cell): the only one whose operators the
    /// transform diagonalises.
    pub(crate) fn for_grid(grid: &FlowGrid, faces: &Faces) -> Option<Self> {
        (grid.periodic_x() && grid.periodic_y() && faces.all_free())
            .then(|| PeriodicPoisson::new(grid.nx, grid.ny, grid.dx, grid.dy))
    }

    /// The solver for `nx × ny` cells of size `dx × dy`.
    pub(crate) fn new(nx: usize, ny: usize, dx: f64, dy: f64) -> Self {
        let mut planner = FftPlanner::new();
        let along_y = planner.plan_fft_forward(ny);
        let along_y_inv = planner.plan_fft_inverse(ny);
        let along_x = planner.plan_fft_forward(nx);
        let along_x_inv = planner.plan_fft_inverse(nx);
        let symbol = |k: usize, n: usize, h: f64| {
            (2.0 - 2.0 * (2.0 * std::f64::consts::PI * k as f64 / n as f64).cos()) / (h * h)
        };
        let mut eigenvalues = vec![0.0; nx * ny];
        for l in 0..ny {
            for k in 0..nx {
                eigenvalues[l * nx + k] = symbol(k, nx, dx) + symbol(l, ny, dy);
            }
        }
        PeriodicPoisson {
            nx,
            ny,
            along_y,
            along_y_inv,
            along_x,
            along_x_inv,
            eigenvalues,
        }
    }

    /// `A⁺ b` for `b` in the layout `[a · ny + b]`: the zero-mean solution of
    /// `A p = b − mean(b)`.
    pub(crate) fn solve(&self, rhs: &[f64]) -> Vec<f64> {
        self.solve_symbol(rhs, |lambda| if lambda == 0.0 { 0.0 } else { 1.0 / lambda })
    }

    /// `(I + a A)⁻¹ r` (`a = ν dt`: the implicit viscosity step `(I − ν dt L)`
    /// of a velocity component), for `r` in the layout `[a · ny + b]`.
    pub(crate) fn solve_helmholtz(&self, rhs: &[f64], a: f64) -> Vec<f64> {
        self.solve_symbol(rhs, |lambda| 1.0 / (1.0 + a * lambda))
    }

    /// `F⁻¹ (m(λ) · F rhs)`.
    fn solve_symbol(&self, rhs: &[f64], multiplier: impl Fn(f64) -> f64 + Sync) -> Vec<f64> {
        let (nx, ny) = (self.nx, self.ny);
        debug_assert_eq!(rhs.len(), nx * ny, "one value per cell");
        let mut rows: Vec<Complex<f64>> = pool::take_or(nx * ny, Complex::default());
        rows.iter_mut()
            .zip(rhs)
            .for_each(|(r, &v)| *r = Complex::new(v, 0.0));
        each_row(&self.along_y, &mut rows, ny);
        // overwritten by the transpose
        let mut cols = pool::take_or(nx * ny, Complex::default());
        transpose(&rows, &mut cols, nx, ny);
        each_row(&self.along_x, &mut cols, nx);
        // λ(0, 0) = 0 exactly (cos 0 = 1), the one mode a pseudo-inverse drops
        let scale = 1.0 / (nx * ny) as f64;
        for_row_blocks(&mut cols, nx, |off, block| {
            block
                .iter_mut()
                .zip(&self.eigenvalues[off..])
                .for_each(|(c, &lambda)| *c *= scale * multiplier(lambda));
        });
        each_row(&self.along_x_inv, &mut cols, nx);
        transpose(&cols, &mut rows, ny, nx);
        each_row(&self.along_y_inv, &mut rows, ny);
        let mut out = scratch(nx * ny);
        out.iter_mut().zip(&rows).for_each(|(o, c)| *o = c.re);
        give_back(rows);
        give_back(cols);
        out
    }
}

/// `fft` applied to each row of `len` entries of `data`: blocks of rows on
/// all cores for a large array (each row transformed alone, so the same bits
/// on any number of threads).
fn each_row(fft: &Arc<dyn Fft<f64>>, data: &mut [Complex<f64>], len: usize) {
    if len == 0 {
        return;
    }
    for_row_blocks(data, len, |_, block| {
        let mut scratch = vec![Complex::default(); fft.get_inplace_scratch_len()];
        fft.process_with_scratch(block, &mut scratch);
    });
}

/// [`FlowError::NonFinite`] naming `step` and `quantity` if `v` holds NaN or
/// infinity: a transform would spread one to every entry of the solution.
pub(crate) fn check_finite(step: &str, quantity: &str, v: &[f64]) -> Result<()> {
    let count = v.iter().filter(|x| !x.is_finite()).count();
    if count == 0 {
        Ok(())
    } else {
        Err(FlowError::NonFinite {
            step: step.into(),
            quantity: quantity.into(),
            count,
        })
    }
}

/// `to[b · na + a] = from[a · nb + b]` for an `na × nb` array, in tiles;
/// blocks of `to`'s rows on all cores for a large array.
fn transpose(from: &[Complex<f64>], to: &mut [Complex<f64>], na: usize, nb: usize) {
    const TILE: usize = 16;
    if na == 0 {
        return;
    }
    for_row_blocks(to, na, |off, block| {
        let (b_lo, b_hi) = (off / na, off / na + block.len() / na);
        for a0 in (0..na).step_by(TILE) {
            for b in b_lo..b_hi {
                let out = &mut block[(b - b_lo) * na..(b - b_lo + 1) * na];
                for a in a0..(a0 + TILE).min(na) {
                    out[a] = from[a * nb + b];
                }
            }
        }
    });
}
