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
    /// `λ(k, l)` for `l ≤ ny/2` in the transposed layout `[l · nx + k]`.
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
        // the modes l ≤ ny/2 only: the others are their conjugates
        let mut eigenvalues = vec![0.0; (ny / 2 + 1) * nx];
        for l in 0..ny / 2 + 1 {
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

    /// `F⁻¹ (m(λ) · F rhs)`, with real-to-complex transforms along `y`.
    ///
    /// The data are real, so along `y` two rows go through one complex
    /// transform (`z = u + i w`, whence `U = (Z + Z̄(−l))/2` and
    /// `W = (Z − Z̄(−l))/2i`) and only the modes `l ≤ ny/2` are kept; the
    /// others are their conjugates (Hermitian symmetry), so the transforms
    /// along `x` run on `ny/2 + 1` rows instead of `ny`. Back, two half
    /// spectra are completed by symmetry and go through one inverse
    /// transform, whose real and imaginary parts are the two rows.
    fn solve_symbol(&self, rhs: &[f64], multiplier: impl Fn(f64) -> f64 + Sync) -> Vec<f64> {
        let (nx, ny) = (self.nx, self.ny);
        debug_assert_eq!(rhs.len(), nx * ny, "one value per cell");
        if nx == 0 || ny == 0 {
            return scratch(0);
        }
        let m = ny / 2 + 1;
        let pairs = nx.div_ceil(2);
        let row = |a: usize| rhs.get(a * ny..(a + 1) * ny);
        let mut packed: Vec<Complex<f64>> = pool::take_or(pairs * ny, Complex::default());
        for (p, z) in packed.chunks_exact_mut(ny).enumerate() {
            let u = row(2 * p).expect("a row per pair");
            match row(2 * p + 1) {
                Some(w) => z
                    .iter_mut()
                    .zip(u.iter().zip(w))
                    .for_each(|(z, (&u, &w))| *z = Complex::new(u, w)),
                None => z
                    .iter_mut()
                    .zip(u)
                    .for_each(|(z, &u)| *z = Complex::new(u, 0.0)),
            }
        }
        each_row(&self.along_y, &mut packed, ny);
        // overwritten below, `[a · m + l]`
        let mut half: Vec<Complex<f64>> = pool::take_or(nx * m, Complex::default());
        for (a, h) in half.chunks_exact_mut(m).enumerate() {
            let z = &packed[(a / 2) * ny..(a / 2 + 1) * ny];
            let odd = a % 2 == 1;
            for (l, h) in h.iter_mut().enumerate() {
                let (zl, zc) = (z[l], z[if l == 0 { 0 } else { ny - l }].conj());
                let d = if odd { zl - zc } else { zl + zc };
                // (Z + Z̄)/2, or (Z − Z̄)/2i = (Im d, −Re d)/2
                *h = if odd {
                    Complex::new(0.5 * d.im, -0.5 * d.re)
                } else {
                    d * 0.5
                };
            }
        }
        // overwritten by the transpose
        let mut cols = pool::take_or(m * nx, Complex::default());
        transpose(&half, &mut cols, nx, m);
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
        transpose(&cols, &mut half, m, nx);
        // the modes l = 0 and l = ny/2 of a real row are real: their
        // imaginary parts are rounding, which a c2r transform drops
        let zero = vec![Complex::default(); m];
        for (p, z) in packed.chunks_exact_mut(ny).enumerate() {
            let u = &half[2 * p * m..(2 * p + 1) * m];
            let w = half.get((2 * p + 1) * m..(2 * p + 2) * m).unwrap_or(&zero);
            // u + i w on the kept modes
            z[..m]
                .iter_mut()
                .zip(u.iter().zip(w))
                .for_each(|(z, (u, w))| *z = Complex::new(u.re - w.im, u.im + w.re));
            // ū(ny − l) + i w̄(ny − l) on the others
            z[m..]
                .iter_mut()
                .zip(
                    u[1..]
                        .iter()
                        .rev()
                        .zip(w[1..].iter().rev())
                        .skip(usize::from(ny % 2 == 0)),
                )
                .for_each(|(z, (u, w))| *z = Complex::new(u.re + w.im, w.re - u.im));
            z[0] = Complex::new(u[0].re, w[0].re);
            if ny % 2 == 0 {
                z[ny / 2] = Complex::new(u[ny / 2].re, w[ny / 2].re);
            }
        }
        each_row(&self.along_y_inv, &mut packed, ny);
        let mut out = scratch(nx * ny);
        for (a, o) in out.chunks_exact_mut(ny).enumerate() {
            let z = &packed[(a / 2) * ny..(a / 2 + 1) * ny];
            if a % 2 == 0 {
                o.iter_mut().zip(z).for_each(|(o, c)| *o = c.re);
            } else {
                o.iter_mut().zip(z).for_each(|(o, c)| *o = c.im);
            }
        }
        give_back(packed);
        give_back(half);
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

#[cfg(test)]
mod tests {
    use super::*;

    /// `m(λ) · F b` transformed back by a direct double sum: the reference
    /// the real-to-complex path must meet to rounding.
    fn direct(nx: usize, ny: usize, rhs: &[f64], m: impl Fn(f64) -> f64) -> Vec<f64> {
        let (dx, dy) = (0.3, 0.7);
        let symbol = |k: usize, n: usize, h: f64| {
            (2.0 - 2.0 * (2.0 * std::f64::consts::PI * k as f64 / n as f64).cos()) / (h * h)
        };
        let tau = 2.0 * std::f64::consts::PI;
        let mut spec = vec![Complex::<f64>::default(); nx * ny];
        for k in 0..nx {
            for l in 0..ny {
                let mut s = Complex::<f64>::default();
                for a in 0..nx {
                    for b in 0..ny {
                        let t = -tau * ((k * a) as f64 / nx as f64 + (l * b) as f64 / ny as f64);
                        s += Complex::new(t.cos(), t.sin()) * rhs[a * ny + b];
                    }
                }
                spec[k * ny + l] = s * m(symbol(k, nx, dx) + symbol(l, ny, dy));
            }
        }
        (0..nx * ny)
            .map(|i| {
                let (a, b) = (i / ny, i % ny);
                let mut s = Complex::<f64>::default();
                for k in 0..nx {
                    for l in 0..ny {
                        let t = tau * ((k * a) as f64 / nx as f64 + (l * b) as f64 / ny as f64);
                        s += Complex::new(t.cos(), t.sin()) * spec[k * ny + l];
                    }
                }
                s.re / (nx * ny) as f64
            })
            .collect()
    }

    #[test]
    fn real_transforms_meet_the_direct_sums() {
        // odd and even sizes in each axis, one row, one column
        for (nx, ny) in [(6, 8), (7, 5), (5, 6), (1, 4), (4, 1), (8, 7), (3, 3)] {
            let rhs: Vec<f64> = (0..nx * ny)
                .map(|i| ((i * 7 + 3) % 13) as f64 / 13.0 - 0.4)
                .collect();
            let fft = PeriodicPoisson::new(nx, ny, 0.3, 0.7);
            let pinv = |l: f64| if l == 0.0 { 0.0 } else { 1.0 / l };
            for (got, want) in [
                (fft.solve(&rhs), direct(nx, ny, &rhs, pinv)),
                (
                    fft.solve_helmholtz(&rhs, 0.05),
                    direct(nx, ny, &rhs, |l| 1.0 / (1.0 + 0.05 * l)),
                ),
            ] {
                let top = want.iter().fold(0.0f64, |t, w| t.max(w.abs()));
                for (g, w) in got.iter().zip(&want) {
                    assert!((g - w).abs() <= 1e-12 * top, "{nx} x {ny}: {g} against {w}");
                }
            }
        }
    }
}
