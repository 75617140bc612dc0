//! A geometric multigrid V-cycle for 5-point cell-centred pressure operators
//! on a 2D grid (`−∇²` of [`Laplacian2::negative`] with any boundary, and the
//! masked, face-weighted [`MacPoisson`] of pressure projection), built to
//! precondition conjugate gradient: the cycle is a fixed, symmetric positive
//! (semi)definite linear map `B ≈ A⁻¹`, so preconditioned CG stays valid and
//! the adjoint solve of an implicit gradient is the same solver.
//!
//! Each level is a symmetric 5-point operator given by its face couplings and
//! a diagonal,
//!
//! ```text
//! (A x)_c = d_c x_c − Σ_{faces f of c} a_f x_{other side of f},   d_c = Σ_f a_f + w_c
//! ```
//!
//! (`w_c ≥ 0` the wall terms: a zero Dirichlet wall or an open MAC face), with
//! inactive (masked) cells as identity rows. Coarsening merges 2 × 2 cells
//! (`⌈n/2⌉` per axis, so odd sizes coarsen too: the last coarse cell of an odd
//! axis has one child), while the level has more than [`COARSEST_CELLS`]
//! cells. A coarse face's coupling is the sum of the fine faces between its
//! two cells divided by 8, a coarse wall term the sum of its children's
//! divided by 8 (with both axes halved, `1/h² → 1/(4h²)` per face, two fine
//! faces per coarse face; a cell of an odd axis' end, with one child, is
//! scaled by the distances it really spans). Without a mask this is the
//! rediscretisation of `−∇²` with twice the spacing. With a mask, a coarse
//! cell is active if any of its children is, and its couplings are the sums
//! of the open fine faces between children (a cell that an obstacle cuts has
//! fewer, the faces into the obstacle being closed): the coarse grids correct
//! all the fluid up to the obstacle, and only cells wholly inside it get no
//! correction. Every level is symmetric and semidefinite. MG-PCG to a relative
//! residual of 1e-8 then takes 8–11 iterations from 64² to 1024² for a disc and
//! a block with closed or open sides (`benches/multigrid.rs`). The alternative
//! measured before it (a coarse cell active only if all its children are,
//! faces to cut cells zero Dirichlet walls) left a band of `2^l` fine cells
//! around the obstacle to level `l`'s smoother, and took 15–25 iterations at
//! 64²–128², growing with the grid.
//!
//! Between levels:
//!
//! - prolongation `P`: bilinear interpolation between cell centres (weights
//!   9/16, 3/16, 3/16, 1/16 from the four nearest coarse cells, with the grid
//!   boundary's ghost rule: `−x` across a Dirichlet wall, `+x` across a closed
//!   one, wrap-around if periodic), zero rows for inactive fine cells;
//! - restriction `R = ¼ Pᵀ`, fused with the residual (the fine residual is
//!   never stored).
//!
//! Smoothing is Gauss–Seidel in red–black order, rows and colours interleaved
//! (red on row `i`, then black on row `i − 1`: one pass over memory per sweep).
//! The black cells of the first and the last row come after all the others
//! (before them in reverse), which keeps the order a true red–black one on a
//! periodic axis. The sweeps after the coarse correction visit the cells in
//! exactly the reverse order of those before it, which makes the cycle
//! symmetric for every boundary and size (also where a periodic axis of odd
//! length breaks the checkerboard). On large levels the sweeps, the restricted
//! residual and the prolongation run on all cores in blocks of rows, with the
//! same result to the bit as on one thread (see `smoother`). The coarsest level is solved by a dense Cholesky
//! factorisation that skips vanishing pivots (a generalised inverse, still
//! symmetric, for singular levels: closed walls, periodic, isolated fluid
//! regions). When the finest operator is singular (no wall term anywhere) the
//! cycle works on the zero-mean subspace of the active cells, `B = Π B Π`.
//!
//! The cycle keeps one workspace of level vectors, allocated at construction
//! and reused by every application (a second thread applying the same cycle
//! at the same time gets a fresh one).
//!
//! CG sees the cycle only through the [`Preconditioner`] trait it
//! implements (`CgParams::with_preconditioner(Arc::new(cycle))`); as a
//! [`LinearOperator`] it is `B` itself, for tests and stationary iterations.
//!
//! # Layout
//! `hierarchy` (the levels' operators, coarsening, masks), `transfer`
//! (prolongation and the restricted residual), `smoother` (red–black
//! Gauss–Seidel, forward and exactly reversed), `cycle` (the V-cycle, its
//! workspace, the coarsest solve); this file the public type.
//!
//! # References
//! U. Trottenberg, C. W. Oosterlee, A. Schüller, *Multigrid*, Academic Press
//! 2001, §2 and §5.3 (cell-centred transfers, red–black smoothing);
//! O. Tatebe, *The multigrid preconditioned conjugate gradient method*, NASA
//! CP-3224 (1993) (symmetry conditions for MG as a CG preconditioner);
//! A. McAdams, E. Sifakis, J. Teran, *A parallel multigrid Poisson solver for
//! fluids simulation on large grids*, SCA 2010 (MG-PCG with obstacles).

use std::sync::Mutex;

use diffphys_tape::{parallel, Real};
use ndarray::{ArrayViewD, ArrayViewMutD};

use crate::cg::Preconditioner;
#[cfg(doc)]
use crate::mac::MacPoisson;
#[cfg(doc)]
use crate::stencil::Laplacian2;

use crate::mac::MacGrid;
use crate::{Grid2, LinearOperator, OpsError, Result};

mod cycle;
mod hierarchy;
mod smoother;
mod transfer;

use cycle::{CoarseSolve, Workspace};
use hierarchy::Level;
use transfer::Transfer1;

/// Levels stop coarsening at or below this many cells.
pub const COARSEST_CELLS: usize = 64;
/// Cells per block of the parallel smoother and transfers: half of what a
/// pool thread splits from (`min_parallel_len / POOL_DISCOUNT`, so that a
/// level that splits has at least two blocks), at most four
/// [`parallel::CHUNK`]s. The results do not depend on it.
fn block_cells() -> usize {
    (parallel::min_parallel_len() / parallel::POOL_DISCOUNT / 2).clamp(1, 4 * parallel::CHUNK)
}

/// The largest coarsest level solved by dense Cholesky.
const MAX_DIRECT_CELLS: usize = 4096;

/// The V-cycle preconditioner `B ≈ A⁻¹` on a 2D grid (see the module docs).
#[derive(Debug)]
pub struct Multigrid {
    levels: Vec<Level>,
    /// The transfers of level `l` to `l + 1` along x and y.
    transfers: Vec<(Transfer1, Transfer1)>,
    coarse: CoarseSolve,
    sweeps: usize,
    singular: bool,
    shape: [usize; 2],
    work: Mutex<Workspace>,
}

impl Clone for Multigrid {
    /// The same cycle with a workspace of its own.
    fn clone(&self) -> Self {
        Multigrid {
            levels: self.levels.clone(),
            transfers: self.transfers.clone(),
            coarse: self.coarse.clone(),
            sweeps: self.sweeps,
            singular: self.singular,
            shape: self.shape,
            work: Mutex::new(self.workspace()),
        }
    }
}

impl Multigrid {
    /// The cycle for `−∇²` on `grid` (the operator of
    /// [`Laplacian2::negative`]: zero Dirichlet, closed or periodic on each
    /// axis), with `sweeps` Gauss–Seidel sweeps before and after each coarse
    /// correction (2 is a good default).
    ///
    /// # Errors
    /// [`OpsError::InvalidArgument`] if `sweeps` is 0, or if the grid does not
    /// coarsen to at most 4096 cells (an axis of one cell with more than 4096
    /// along the other).
    pub fn new(grid: &Grid2, sweeps: usize) -> Result<Self> {
        Self::build(Level::laplacian(grid), sweeps)
    }

    /// The cycle for the pressure operator of a staggered grid,
    /// [`MacGrid::pressure_operator`] (masks of obstacle cells, open
    /// boundaries), with `sweeps` sweeps as in [`Multigrid::new`].
    ///
    /// # Errors
    /// As [`Multigrid::new`].
    pub fn for_mac(mac: &MacGrid, sweeps: usize) -> Result<Self> {
        Self::build(Level::mac(mac), sweeps)
    }

    fn build(fine: Level, sweeps: usize) -> Result<Self> {
        if sweeps == 0 {
            return Err(OpsError::invalid(
                "multigrid",
                "at least one smoothing sweep",
            ));
        }
        let shape = [fine.nx, fine.ny];
        let singular = (0..fine.cells())
            .all(|k| fine.wall[0][k] + fine.wall[1][k] == 0.0 || !fine.is_active(k));
        let mut levels = vec![fine];
        let mut transfers = Vec::new();
        loop {
            let l = levels.last().expect("one level");
            if l.cells() <= COARSEST_CELLS || l.nx < 2 || l.ny < 2 {
                break;
            }
            transfers.push((Transfer1::new(l.nx, l.bx), Transfer1::new(l.ny, l.by)));
            let next = l.coarsen();
            levels.push(next);
        }
        let last = levels.last().expect("one level");
        if last.cells() > MAX_DIRECT_CELLS {
            return Err(OpsError::invalid(
                "multigrid",
                format!(
                    "a {}×{} grid coarsens only to {}×{} ({} cells, more than the \
                     {MAX_DIRECT_CELLS} solved directly): an axis of one cell is too long",
                    shape[0],
                    shape[1],
                    last.nx,
                    last.ny,
                    last.cells()
                ),
            ));
        }
        let coarse = CoarseSolve::new(last)?;
        let mut mg = Multigrid {
            levels,
            transfers,
            coarse,
            sweeps,
            singular,
            shape,
            work: Mutex::new(Workspace::default()),
        };
        mg.work = Mutex::new(mg.workspace());
        Ok(mg)
    }

    /// The number of levels, the finest included.
    pub fn levels(&self) -> usize {
        self.levels.len()
    }

    /// The cells of each level, finest first.
    pub fn level_shapes(&self) -> Vec<[usize; 2]> {
        self.levels.iter().map(|l| [l.nx, l.ny]).collect()
    }

    /// Whether the operator is singular (no wall term: closed or periodic
    /// boundaries), so that the cycle works on the zero-mean subspace of the
    /// active cells.
    pub fn is_singular(&self) -> bool {
        self.singular
    }
}

/// One V-cycle per CG iteration, `M⁻¹ = B`.
impl<T: Real> Preconditioner<T> for Multigrid {
    fn name(&self) -> &str {
        "multigrid_v_cycle"
    }

    fn shape(&self) -> Option<&[usize]> {
        Some(&self.shape)
    }

    fn apply(&self, r: &[T], z: &mut [T]) {
        self.apply_cycle(r, z);
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
            Some(o) => self.apply_cycle(xs, o),
            None => {
                let mut buf = vec![T::zero(); xs.len()];
                self.apply_cycle(xs, &mut buf);
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
