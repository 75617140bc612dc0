//! A geometric multigrid V-cycle for the cell-centred 5-point `−∇²` on a 2D
//! grid, built to precondition conjugate gradient: the cycle is a fixed,
//! symmetric positive definite linear map `B ≈ A⁻¹`, so preconditioned CG stays
//! valid and the adjoint solve of an implicit gradient is the same solver.
//!
//! Levels halve both axes while both cell counts are even (and the grid has
//! more than [`COARSEST_CELLS`] cells); each level rediscretises `−∇²` with
//! twice the spacing and the same boundary on each axis (zero Dirichlet, closed
//! walls, periodic). Between levels:
//!
//! - prolongation `P`: bilinear interpolation between cell centres (weights
//!   9/16, 3/16, 3/16, 1/16 from the four nearest coarse cells, with the
//!   boundary's ghost rule: `−x` across a Dirichlet wall, `+x` across a closed
//!   one, wrap-around if periodic);
//! - restriction `R = ¼ Pᵀ` (the transpose, so an average of a constant is that
//!   constant).
//!
//! Smoothing is red–black Gauss–Seidel, red then black before the coarse
//! correction and black then red after it (the adjoint order), which makes the
//! cycle symmetric. The coarsest level is solved exactly by a dense Cholesky
//! factorisation (regularised along the constants when the operator is
//! singular, all walls closed or periodic; the cycle then works on the
//! zero-mean subspace, `B = Π B Π`).
//!
//! # References
//! U. Trottenberg, C. W. Oosterlee, A. Schüller, *Multigrid*, Academic Press
//! 2001, §2 and §5.3 (cell-centred transfers, red–black smoothing);
//! O. Tatebe, *The multigrid preconditioned conjugate gradient method*, NASA
//! CP-3224 (1993) (symmetry conditions for MG as a CG preconditioner).

use diffphys_tape::Real;
use ndarray::{ArrayViewD, ArrayViewMutD};

use crate::{Boundary, Grid2, LinearOperator, OpsError, Result};

/// Levels stop coarsening at or below this many cells.
pub const COARSEST_CELLS: usize = 64;
/// The largest coarsest level solved by dense Cholesky.
const MAX_DIRECT_CELLS: usize = 4096;

/// One grid level: `−∇²` with spacing `h`, as per-cell diagonals and the two
/// axis coefficients `1/h²`.
#[derive(Debug, Clone)]
struct Level {
    nx: usize,
    ny: usize,
    cx: f64,
    cy: f64,
    bx: Boundary,
    by: Boundary,
    diag: Vec<f64>,
}

/// The neighbour of index `i` on an axis of `n` cells one step in direction
/// `step` (±1): its index, or `None` past a wall (whose ghost rule the diagonal
/// already holds).
fn neighbour(i: usize, n: usize, step: isize, b: Boundary) -> Option<usize> {
    let j = i as isize + step;
    if (0..n as isize).contains(&j) {
        Some(j as usize)
    } else if b == Boundary::Periodic {
        Some(j.rem_euclid(n as isize) as usize)
    } else {
        None
    }
}

/// The sign a wall's ghost cell carries: `−1` Dirichlet, `+1` closed.
fn ghost_sign(b: Boundary) -> f64 {
    match b {
        Boundary::ZeroDirichlet => -1.0,
        _ => 1.0,
    }
}

impl Level {
    fn new(nx: usize, ny: usize, hx: f64, hy: f64, bx: Boundary, by: Boundary) -> Self {
        let (cx, cy) = (1.0 / (hx * hx), 1.0 / (hy * hy));
        // Each missing neighbour (a wall) turns `2x − ghost` into `(2 − s) x`.
        let wall = |i: usize, n: usize, b: Boundary, c: f64| -> f64 {
            let mut d = 2.0 * c;
            for step in [-1, 1] {
                if neighbour(i, n, step, b).is_none() {
                    d -= ghost_sign(b) * c;
                }
            }
            d
        };
        let mut diag = vec![0.0; nx * ny];
        for i in 0..nx {
            for j in 0..ny {
                diag[i * ny + j] = wall(i, nx, bx, cx) + wall(j, ny, by, cy);
            }
        }
        Level {
            nx,
            ny,
            cx,
            cy,
            bx,
            by,
            diag,
        }
    }

    fn cells(&self) -> usize {
        self.nx * self.ny
    }

    /// `Σ_neighbours c·x_nb` at cell `(i, j)` (the off-diagonal part, negated).
    #[inline]
    fn off<T: Real>(&self, x: &[T], i: usize, j: usize) -> T {
        let mut s = 0.0;
        for step in [-1, 1] {
            if let Some(k) = neighbour(i, self.nx, step, self.bx) {
                s += self.cx * x[k * self.ny + j].as_f64();
            }
            if let Some(k) = neighbour(j, self.ny, step, self.by) {
                s += self.cy * x[i * self.ny + k].as_f64();
            }
        }
        T::from_f64(s)
    }

    /// Whether `(i, j)` has all four neighbours inside the grid, where the
    /// stencil needs no boundary rule.
    #[inline]
    fn interior(&self, i: usize, j: usize) -> bool {
        i > 0 && j > 0 && i + 1 < self.nx && j + 1 < self.ny
    }

    /// [`Level::off`] for an interior cell: plain neighbours, no boundary rule.
    #[inline]
    fn off_interior<T: Real>(&self, x: &[T], k: usize) -> T {
        let (cx, cy) = (T::from_f64(self.cx), T::from_f64(self.cy));
        cx * (x[k - self.ny] + x[k + self.ny]) + cy * (x[k - 1] + x[k + 1])
    }

    /// `r = b − A x`.
    fn residual<T: Real>(&self, x: &[T], b: &[T], r: &mut [T]) {
        for i in 0..self.nx {
            for j in 0..self.ny {
                let k = i * self.ny + j;
                let off = if self.interior(i, j) {
                    self.off_interior(x, k)
                } else {
                    self.off(x, i, j)
                };
                r[k] = b[k] - (T::from_f64(self.diag[k]) * x[k] - off);
            }
        }
    }

    /// One Gauss–Seidel pass over the cells of one colour (`(i + j) % 2`).
    fn relax<T: Real>(&self, x: &mut [T], b: &[T], colour: usize) {
        for i in 0..self.nx {
            let mut j = (i + colour) % 2;
            while j < self.ny {
                let k = i * self.ny + j;
                let off = if self.interior(i, j) {
                    self.off_interior(x, k)
                } else {
                    self.off(x, i, j)
                };
                x[k] = (b[k] + off) / T::from_f64(self.diag[k]);
                j += 2;
            }
        }
    }

    /// The rows of `P` for fine cell `(i, j)` of this (fine) level: four coarse
    /// indices with their weights (signs of ghost rules included).
    fn prolongation_row(&self, i: usize, j: usize) -> [(usize, f64); 4] {
        let (cnx, cny) = (self.nx / 2, self.ny / 2);
        let (ci, cj) = (i / 2, j / 2);
        let side = |c: usize, fine: usize, n: usize, b: Boundary| -> (usize, f64) {
            let step = if fine % 2 == 0 { -1 } else { 1 };
            match neighbour(c, n, step, b) {
                Some(k) => (k, 1.0),
                None => (c, ghost_sign(b)),
            }
        };
        let (ni, si) = side(ci, i, cnx, self.bx);
        let (nj, sj) = side(cj, j, cny, self.by);
        [
            (ci * cny + cj, 9.0 / 16.0),
            (ni * cny + cj, si * 3.0 / 16.0),
            (ci * cny + nj, sj * 3.0 / 16.0),
            (ni * cny + nj, si * sj / 16.0),
        ]
    }

    /// `fine += P coarse`.
    fn prolong_add<T: Real>(&self, coarse: &[T], fine: &mut [T]) {
        for i in 0..self.nx {
            for j in 0..self.ny {
                let mut v = 0.0;
                for (k, w) in self.prolongation_row(i, j) {
                    v += w * coarse[k].as_f64();
                }
                fine[i * self.ny + j] += T::from_f64(v);
            }
        }
    }

    /// `coarse = ¼ Pᵀ fine`.
    fn restrict<T: Real>(&self, fine: &[T], coarse: &mut [T]) {
        coarse.iter_mut().for_each(|c| *c = T::zero());
        for i in 0..self.nx {
            for j in 0..self.ny {
                let f = fine[i * self.ny + j].as_f64();
                for (k, w) in self.prolongation_row(i, j) {
                    coarse[k] += T::from_f64(0.25 * w * f);
                }
            }
        }
    }
}

/// The dense Cholesky factor `L` (row-major, lower) of the coarsest level's
/// matrix, plus `α 1 1ᵀ` when the operator is singular.
#[derive(Debug, Clone)]
struct CoarseSolve {
    n: usize,
    l: Vec<f64>,
    singular: bool,
}

impl CoarseSolve {
    fn new(level: &Level, singular: bool) -> Result<Self> {
        let n = level.cells();
        let mut a = vec![0.0; n * n];
        let mut e = vec![0.0; n];
        let mut col = vec![0.0; n];
        for c in 0..n {
            e[c] = 1.0;
            level.residual(&e, &vec![0.0; n], &mut col);
            for r in 0..n {
                a[r * n + c] = -col[r];
            }
            e[c] = 0.0;
        }
        if singular {
            let alpha = level.diag.iter().cloned().fold(0.0, f64::max) / n as f64;
            a.iter_mut().for_each(|v| *v += alpha);
        }
        // In-place Cholesky, a = L Lᵀ.
        for j in 0..n {
            let mut d = a[j * n + j];
            for k in 0..j {
                d -= a[j * n + k] * a[j * n + k];
            }
            if d.is_nan() || d <= 0.0 {
                return Err(OpsError::invalid(
                    "multigrid",
                    format!("the coarsest level ({n} cells) is not positive definite"),
                ));
            }
            let d = d.sqrt();
            a[j * n + j] = d;
            for i in j + 1..n {
                let mut s = a[i * n + j];
                for k in 0..j {
                    s -= a[i * n + k] * a[j * n + k];
                }
                a[i * n + j] = s / d;
            }
        }
        Ok(CoarseSolve { n, l: a, singular })
    }

    fn solve<T: Real>(&self, b: &[T], x: &mut [T]) {
        let n = self.n;
        let mut y: Vec<f64> = b.iter().map(|v| v.as_f64()).collect();
        if self.singular {
            project_mean(&mut y);
        }
        for i in 0..n {
            let row = &self.l[i * n..i * n + i];
            let s = y[i] - row.iter().zip(&y[..i]).map(|(l, v)| l * v).sum::<f64>();
            y[i] = s / self.l[i * n + i];
        }
        for i in (0..n).rev() {
            let s = y[i] - (i + 1..n).map(|k| self.l[k * n + i] * y[k]).sum::<f64>();
            y[i] = s / self.l[i * n + i];
        }
        if self.singular {
            project_mean(&mut y);
        }
        for (o, v) in x.iter_mut().zip(y) {
            *o = T::from_f64(v);
        }
    }
}

fn project_mean<T: Real>(v: &mut [T]) {
    let mean = v.iter().map(|x| x.as_f64()).sum::<f64>() / v.len() as f64;
    let mean = T::from_f64(mean);
    v.iter_mut().for_each(|x| *x -= mean);
}

/// The V-cycle preconditioner `B ≈ (−∇²)⁻¹` on a 2D grid (see the module docs).
#[derive(Debug, Clone)]
pub struct Multigrid {
    levels: Vec<Level>,
    coarse: CoarseSolve,
    sweeps: usize,
    singular: bool,
    shape: [usize; 2],
}

impl Multigrid {
    /// The cycle for `−∇²` on `grid` (the operator of
    /// [`crate::stencil::Laplacian2::negative`]), with `sweeps` red–black
    /// Gauss–Seidel sweeps before and after each coarse correction (2 is a good
    /// default).
    ///
    /// # Errors
    /// [`OpsError::InvalidArgument`] if `sweeps` is 0, or if the grid does not
    /// coarsen to at most 4096 cells by halving (its cell counts need enough
    /// factors of two).
    pub fn new(grid: &Grid2, sweeps: usize) -> Result<Self> {
        if sweeps == 0 {
            return Err(OpsError::invalid(
                "multigrid",
                "at least one smoothing sweep",
            ));
        }
        let (bx, by) = (grid.boundary_x, grid.boundary_y);
        let mut levels = vec![Level::new(grid.nx, grid.ny, grid.dx, grid.dy, bx, by)];
        loop {
            let l = levels.last().expect("one level");
            if l.nx % 2 != 0 || l.ny % 2 != 0 || l.cells() <= COARSEST_CELLS || l.nx < 4 || l.ny < 4
            {
                break;
            }
            let (hx, hy) = (1.0 / l.cx.sqrt(), 1.0 / l.cy.sqrt());
            levels.push(Level::new(l.nx / 2, l.ny / 2, 2.0 * hx, 2.0 * hy, bx, by));
        }
        let last = levels.last().expect("one level");
        if last.cells() > MAX_DIRECT_CELLS {
            return Err(OpsError::invalid(
                "multigrid",
                format!(
                    "a {}×{} grid coarsens by halving only to {}×{} ({} cells, more than the \
                     {MAX_DIRECT_CELLS} solved directly): use cell counts with more factors of two",
                    grid.nx,
                    grid.ny,
                    last.nx,
                    last.ny,
                    last.cells()
                ),
            ));
        }
        let singular = bx != Boundary::ZeroDirichlet && by != Boundary::ZeroDirichlet;
        let coarse = CoarseSolve::new(last, singular)?;
        Ok(Multigrid {
            levels,
            coarse,
            sweeps,
            singular,
            shape: [grid.nx, grid.ny],
        })
    }

    /// The number of levels, the finest included.
    pub fn levels(&self) -> usize {
        self.levels.len()
    }

    /// `z = B r`: one V-cycle from a zero guess, on slices of the grid's size
    /// (the solver's own buffers; users go through [`LinearOperator`], which
    /// checks shapes).
    pub(crate) fn apply_slice<T: Real>(&self, r: &[T], z: &mut [T]) {
        if self.singular {
            let mut rp = r.to_vec();
            project_mean(&mut rp);
            self.cycle(0, &rp, z);
            project_mean(z);
        } else {
            self.cycle(0, r, z);
        }
    }

    fn cycle<T: Real>(&self, l: usize, b: &[T], x: &mut [T]) {
        if l + 1 == self.levels.len() {
            self.coarse.solve(b, x);
            return;
        }
        let level = &self.levels[l];
        x.iter_mut().for_each(|v| *v = T::zero());
        for _ in 0..self.sweeps {
            level.relax(x, b, 0);
            level.relax(x, b, 1);
        }
        let mut r = vec![T::zero(); level.cells()];
        level.residual(x, b, &mut r);
        let coarse = &self.levels[l + 1];
        let mut rc = vec![T::zero(); coarse.cells()];
        level.restrict(&r, &mut rc);
        let mut ec = vec![T::zero(); coarse.cells()];
        self.cycle(l + 1, &rc, &mut ec);
        level.prolong_add(&ec, x);
        for _ in 0..self.sweeps {
            level.relax(x, b, 1);
            level.relax(x, b, 0);
        }
    }
}

impl<T: Real> LinearOperator<T> for Multigrid {
    fn name(&self) -> &str {
        "multigrid_v_cycle"
    }

    fn input_shape(&self) -> &[usize] {
        &self.shape
    }

    fn output_shape(&self) -> &[usize] {
        &self.shape
    }

    fn apply_into(&self, x: ArrayViewD<'_, T>, mut out: ArrayViewMutD<'_, T>) {
        let x = x.as_standard_layout();
        let xs = x.as_slice().expect("standard layout");
        match out.as_slice_mut() {
            Some(o) => self.apply_slice(xs, o),
            None => {
                let mut buf = vec![T::zero(); xs.len()];
                self.apply_slice(xs, &mut buf);
                out.iter_mut().zip(buf).for_each(|(o, v)| *o = v);
            }
        }
    }

    /// `B` is symmetric: the transpose is the same cycle.
    fn apply_transpose_into(&self, y: ArrayViewD<'_, T>, out: ArrayViewMutD<'_, T>) {
        self.apply_into(y, out);
    }

    fn is_symmetric(&self) -> bool {
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::stencil::Laplacian2;
    use diffphys_tape::{check_adjoint, test_array, ArrayD};
    use ndarray::IxDyn;

    const KINDS: [Boundary; 3] = [
        Boundary::ZeroDirichlet,
        Boundary::Closed,
        Boundary::Periodic,
    ];

    fn grid(nx: usize, ny: usize, bx: Boundary, by: Boundary) -> Grid2 {
        let mut g = Grid2::new(nx, ny, 1.0 / nx as f64, 1.3 / ny as f64, bx).unwrap();
        g.boundary_y = by;
        g
    }

    #[test]
    fn the_level_operator_is_the_laplacian() {
        for bx in KINDS {
            for by in KINDS {
                let g = grid(8, 6, bx, by);
                let level = &Multigrid::new(&g, 1).unwrap().levels[0];
                let x = test_array::<f64>(&[8, 6], 1);
                let mut r = vec![0.0; 48];
                level.residual(x.as_slice().unwrap(), &[0.0; 48], &mut r);
                let a = LinearOperator::<f64>::apply(&Laplacian2::negative(g), x.view()).unwrap();
                for (p, q) in r.iter().zip(a.iter()) {
                    assert!((-p - q).abs() < 1e-9 * q.abs().max(1.0), "{bx:?} {by:?}");
                }
            }
        }
    }

    #[test]
    fn the_cycle_is_symmetric_for_every_boundary() {
        for bx in KINDS {
            for by in KINDS {
                let mg = Multigrid::new(&grid(32, 16, bx, by), 2).unwrap();
                assert!(mg.levels() >= 3);
                let (x, y) = (
                    test_array::<f64>(&[32, 16], 2),
                    test_array::<f64>(&[32, 16], 3),
                );
                let report = check_adjoint(
                    |v| LinearOperator::<f64>::apply(&mg, v).unwrap(),
                    |v| LinearOperator::<f64>::apply_transpose(&mg, v).unwrap(),
                    x.view(),
                    y.view(),
                )
                .unwrap();
                // Symmetric in fact, not only by declaration: <B x, y> = <x, B y>.
                assert!(report.passes(1e-12), "{bx:?} {by:?}: {report:?}");
            }
        }
    }

    /// The error reduction of the stationary iteration `x ← x + B (b − A x)`
    /// per cycle, from the last of `cycles`.
    fn rate(g: &Grid2) -> f64 {
        let mg = Multigrid::new(g, 2).unwrap();
        let a = Laplacian2::negative(*g);
        let shape = [g.nx, g.ny];
        let mut b = test_array::<f64>(&shape, 4);
        if mg.singular {
            project_mean(b.as_slice_mut().unwrap());
        }
        let mut x = ArrayD::<f64>::zeros(IxDyn(&shape));
        let mut norms = Vec::new();
        for _ in 0..8 {
            let ax = LinearOperator::<f64>::apply(&a, x.view()).unwrap();
            let r = &b - &ax;
            norms.push(r.iter().map(|v| v * v).sum::<f64>().sqrt());
            let z = LinearOperator::<f64>::apply(&mg, r.view()).unwrap();
            x += &z;
        }
        norms[7] / norms[6]
    }

    #[test]
    fn each_cycle_cuts_the_residual_by_a_size_independent_factor() {
        // Cells of aspect ratio 1.3 (a point smoother slows with anisotropy):
        // measured 0.18–0.19 per V(2,2) cycle at every size and boundary.
        for bx in KINDS {
            let r32 = rate(&grid(32, 32, bx, bx));
            let r512 = rate(&grid(512, 512, bx, bx));
            assert!(r32 < 0.25 && r512 < 0.25, "{bx:?}: {r32} {r512}");
            assert!(
                r512 - r32 < 0.02,
                "{bx:?}: the rate grows with size, {r32} → {r512}"
            );
        }
        // A size that is not a power of two (80 × 48 coarsens to 5 × 3), with
        // cells of aspect ratio 2.2: measured 0.33.
        assert!(rate(&grid(80, 48, Boundary::ZeroDirichlet, Boundary::Closed)) < 0.4);
    }

    /// Iterations of the project's CG, preconditioned by the cycle, to relative
    /// residual `rtol`, and the true relative residual reached.
    fn pcg(g: &Grid2, rtol: f64) -> (usize, f64) {
        use crate::cg::{conjugate_gradient, CgParams, NullSpace, Preconditioner};
        let mg = std::sync::Arc::new(Multigrid::new(g, 2).unwrap());
        let a = Laplacian2::negative(*g);
        let mut b = test_array::<f64>(&[g.nx, g.ny], 5);
        let mut params = CgParams::default()
            .with_rel_tol(rtol)
            .with_preconditioner(Preconditioner::Multigrid(mg.clone()));
        if mg.singular {
            project_mean(b.as_slice_mut().unwrap());
            params.null_space = NullSpace::Constant;
        }
        let mut x = ArrayD::<f64>::zeros(IxDyn(&[g.nx, g.ny]));
        let info = conjugate_gradient(&a, b.view(), x.view_mut(), &params).unwrap();
        let r = &b - &LinearOperator::<f64>::apply(&a, x.view()).unwrap();
        let norm = |v: &ArrayD<f64>| v.iter().map(|x| x * x).sum::<f64>().sqrt();
        (info.iterations, norm(&r) / norm(&b))
    }

    #[test]
    fn preconditioned_cg_reaches_1e_8_in_few_iterations_at_any_size_and_boundary() {
        for bx in KINDS {
            for n in [32, 64, 256] {
                let g = Grid2::new(n, n, 1.0 / n as f64, 1.0 / n as f64, bx).unwrap();
                let (k, reached) = pcg(&g, 1e-8);
                assert!(
                    k <= 15 && reached <= 1e-8,
                    "{bx:?} {n}²: {k} iterations, {reached:e}"
                );
            }
        }
        // Mixed walls and a size that is not a power of two.
        let (k, reached) = pcg(
            &grid(80, 48, Boundary::Closed, Boundary::ZeroDirichlet),
            1e-8,
        );
        assert!(
            k <= 20 && reached <= 1e-8,
            "80×48: {k} iterations, {reached:e}"
        );
    }

    #[test]
    fn sizes_that_do_not_coarsen_are_an_error() {
        let g = grid(
            2 * 67,
            2 * 67,
            Boundary::ZeroDirichlet,
            Boundary::ZeroDirichlet,
        );
        let err = Multigrid::new(&g, 2).unwrap_err();
        assert!(err.to_string().contains("factors of two"), "{err}");
        assert!(Multigrid::new(&grid(16, 16, Boundary::Closed, Boundary::Closed), 0).is_err());
    }
}
