//! Pressure projection with the obstacle and the per-side conditions, and its
//! implicit adjoint.
//!
//! With `D` the divergence over all faces (cells ← faces, `1/h` weights), `D_F`
//! its restriction to the free faces, `G_F = −D_Fᵀ` the pressure gradient on
//! the free faces and `M_f` the mask of fluid cells, the projection over a
//! pressure time scale `τ` (`τ = dt`, or `dt/2` for the incremental splitting
//! of [`crate::Splitting`]) solves
//!
//! ```text
//! A p = b,   A = −D_F G_F = D_F D_Fᵀ (identity on solid cells),   b = −M_f D u
//! u'_F = u_F − (G_F p)_F,   u'_X = u_X (fixed faces),   P = p / τ
//! ```
//!
//! so `D u' = 0` on every fluid cell up to the solver's tolerance. An outflow
//! side holds `p = 0` one cell outside, which makes `A` definite; without one
//! `A` is singular (constants on the fluid cells) and the solve returns the
//! zero-mean solution.
//!
//! **Adjoint.** `S = A⁺` is symmetric, so with `g` the gradient of `u'` and
//! `g_P` that of `P`, one more solve with the same operator gives
//!
//! ```text
//! s = M_f S(−D_F g_F − g_P/τ),     ∂L/∂u = g − G s     (G = −Dᵀ on all faces)
//! ```
//!
//! The forward solve may start from any guess (the previous step's pressure:
//! a warm start); the adjoint does not depend on it, so it stays exact.
//!
//! **Solvers** ([`PressureSolver`]): a sparse Cholesky factorisation (faer, via
//! [`diffphys_ops::reference::SparseCholesky`]) built once per scene, whose
//! solve is also the adjoint's; conjugate gradient with Jacobi, or with a
//! multigrid V-cycle of diffphys-ops as preconditioner (MG-PCG), for grids too
//! large to factorise.

use std::cell::RefCell;
use std::rc::Rc;
use std::sync::Arc;

use diffphys_ops::cg::{conjugate_gradient, CgParams, NullSpace, Preconditioning};
use diffphys_ops::multigrid::Multigrid;
use diffphys_ops::reference::SparseCholesky;
use diffphys_ops::{CellMask, LinearOperator};
use diffphys_tape::{ArrayD, ArrayViewD, BackwardArgs, Op, Real, TapeError};
use ndarray::{Array2, ArrayView2, ArrayViewMutD, IxDyn};

use crate::boundaries::{view2, FaceKind, Faces};
use crate::buffers::{give_back, narrow, owned, wide};
use crate::grid::FlowGrid;
use crate::sparse::Csr;
use crate::spectral::PeriodicPoisson;
use crate::staggered::{divergence_wide, gradient_wide, subtract_gradient_wide};
use crate::{FlowError, Result};

/// How the pressure system is solved.
#[derive(Debug, Clone, PartialEq)]
pub enum PressureSolver {
    /// Sparse Cholesky, factorised once per scene (the default; for small and
    /// medium grids).
    Cholesky,
    /// The fast Fourier transform (the module `spectral`): a direct solve
    /// in `O(n log n)` for a box periodic in both axes without obstacle; any
    /// other scene is refused when it is built.
    Fourier,
    /// Conjugate gradient with a Jacobi preconditioner, warm-started.
    Cg {
        /// Relative tolerance.
        rel_tol: f64,
        /// Iteration cap.
        max_iters: usize,
    },
    /// Conjugate gradient preconditioned by a multigrid V-cycle (MG-PCG),
    /// warm-started.
    MultigridCg {
        /// Relative tolerance.
        rel_tol: f64,
        /// Iteration cap.
        max_iters: usize,
        /// Smoothing sweeps per level (2 is a good default).
        sweeps: usize,
    },
}

/// The pressure operator `A = D_F D_Fᵀ` on the cells (identity on solid cells).
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct PoissonMatrix {
    csr: Csr,
    shape: [usize; 2],
}

impl LinearOperator<f64> for PoissonMatrix {
    fn name(&self) -> &str {
        "pressure (−D G)"
    }
    fn input_shape(&self) -> &[usize] {
        &self.shape
    }
    fn output_shape(&self) -> &[usize] {
        &self.shape
    }
    fn apply_into(&self, x: ArrayViewD<'_, f64>, mut out: ArrayViewMutD<'_, f64>) {
        let x = x.as_standard_layout();
        let xs = x.as_slice().expect("standard");
        match out.as_slice_mut() {
            Some(o) => {
                o.fill(0.0);
                self.csr.mul_add(1.0, xs, o);
            }
            None => {
                let mut o = vec![0.0; xs.len()];
                self.csr.mul_add(1.0, xs, &mut o);
                out.iter_mut().zip(o).for_each(|(a, b)| *a = b);
            }
        }
    }
    fn apply_transpose_into(&self, y: ArrayViewD<'_, f64>, out: ArrayViewMutD<'_, f64>) {
        self.apply_into(y, out);
    }
    fn is_symmetric(&self) -> bool {
        true
    }
    fn diagonal(&self) -> Option<ArrayD<f64>> {
        Some(ArrayD::from_shape_vec(IxDyn(&self.shape), self.csr.diagonal()).expect("one per cell"))
    }
    fn triplets(&self) -> Option<Vec<(usize, usize, f64)>> {
        Some(self.csr.triplets())
    }
}

/// A direct solver of the pressure system.
#[derive(Debug, Clone)]
enum Direct {
    Cholesky(Arc<SparseCholesky>),
    Fourier(Arc<PeriodicPoisson>),
}

/// The pressure system of a grid with its faces and solid cells, assembled
/// once (and factorised, for the direct solvers): what [`project`] solves.
#[derive(Debug, Clone)]
pub struct PressureSystem {
    grid: FlowGrid,
    faces: Arc<Faces>,
    matrix: PoissonMatrix,
    fluid: Vec<bool>,
    direct: Option<Direct>,
    cg: CgParams,
    /// Whether the operator is singular (no outflow).
    singular: bool,
}

impl PressureSystem {
    /// Assembles `A` on `grid` with its `faces` and `solid` cells and
    /// prepares `solver`.
    ///
    /// # Errors
    /// [`FlowError::InvalidScene`] for the Fourier solver on a grid that is
    /// not a box periodic in both axes without obstacle; the factorisation's
    /// or the multigrid hierarchy's errors.
    pub fn new(
        grid: &FlowGrid,
        faces: &Arc<Faces>,
        solid: &Array2<bool>,
        solver: &PressureSolver,
    ) -> Result<Self> {
        let spectral = PeriodicPoisson::for_grid(grid, faces).map(Arc::new);
        Self::with_spectral(grid, faces, solid, solver, spectral.as_ref())
    }

    /// [`PressureSystem::new`] sharing the Fourier solves of a periodic box.
    pub(crate) fn with_spectral(
        grid: &FlowGrid,
        faces: &Arc<Faces>,
        solid: &Array2<bool>,
        solver: &PressureSolver,
        spectral: Option<&Arc<PeriodicPoisson>>,
    ) -> Result<Self> {
        let (nx, ny) = (grid.nx, grid.ny);
        let (cx, cy) = (1.0 / (grid.dx * grid.dx), 1.0 / (grid.dy * grid.dy));
        let mut t = Vec::new();
        let mut open = false;
        let [nfx, _] = grid.shape_x();
        for f in 0..nfx {
            let (lo, hi) = grid.x_face_cells(f);
            for j in 0..ny {
                if faces.x[f * ny + j] == FaceKind::Free && lo != hi {
                    open |= lo.is_none() || hi.is_none();
                    push_face(&mut t, lo.map(|i| i * ny + j), hi.map(|i| i * ny + j), cx);
                }
            }
        }
        let [_, nfy] = grid.shape_y();
        for i in 0..nx {
            for f in 0..nfy {
                let (lo, hi) = grid.y_face_cells(f);
                if faces.y[i * nfy + f] == FaceKind::Free && lo != hi {
                    open |= lo.is_none() || hi.is_none();
                    push_face(&mut t, lo.map(|j| i * ny + j), hi.map(|j| i * ny + j), cy);
                }
            }
        }
        let fluid: Vec<bool> = solid.iter().map(|&s| !s).collect();
        for (c, &f) in fluid.iter().enumerate() {
            t.push((c, c, if f { 0.0 } else { 1.0 }));
        }
        let matrix = PoissonMatrix {
            csr: Csr::from_triplets(nx * ny, nx * ny, t),
            shape: [nx, ny],
        };
        let all_fluid = fluid.iter().all(|&f| f);
        let null_space = match (open, all_fluid) {
            (true, _) => NullSpace::None,
            (false, true) => NullSpace::Constant,
            (false, false) => {
                NullSpace::ConstantOn(CellMask::from_array(solid.mapv(|s| !s).into_dyn().view()))
            }
        };
        let mut cg = CgParams::default().with_null_space(null_space.clone());
        let mut direct = None;
        match solver {
            PressureSolver::Cholesky => {
                let chol = SparseCholesky::new(&matrix, null_space)
                    .map_err(|e| FlowError::Direct(e.to_string()))?;
                direct = Some(Direct::Cholesky(Arc::new(chol)));
            }
            PressureSolver::Fourier => {
                // the scene has its Fourier solves exactly on a periodic box without obstacle
                let Some(fft) = spectral else {
                    return Err(FlowError::scene(
                        "pressure solver",
                        "the Fourier solve needs a box periodic in both axes without obstacle; \
                         use Cholesky, Cg or MultigridCg",
                    ));
                };
                direct = Some(Direct::Fourier(Arc::clone(fft)));
            }
            PressureSolver::Cg { rel_tol, max_iters } => {
                cg = cg
                    .with_rel_tol(*rel_tol)
                    .with_max_iters(*max_iters)
                    .with_preconditioner(Preconditioning::Jacobi);
            }
            PressureSolver::MultigridCg {
                rel_tol,
                max_iters,
                sweeps,
            } => {
                let mg = Multigrid::for_mac(&grid.mac(Some(solid))?, *sweeps)?;
                cg = cg
                    .with_rel_tol(*rel_tol)
                    .with_max_iters(*max_iters)
                    .with_preconditioner(Arc::new(mg));
            }
        }
        Ok(PressureSystem {
            grid: grid.clone(),
            faces: Arc::clone(faces),
            matrix,
            fluid,
            direct,
            cg,
            singular: !open,
        })
    }

    /// The grid.
    pub fn grid(&self) -> &FlowGrid {
        &self.grid
    }

    /// Whether the operator is singular (no outflow side): constants on the
    /// fluid cells are its null space.
    pub fn is_singular(&self) -> bool {
        self.singular
    }

    /// Whether the solve iterates (CG or MG-PCG: a guess helps), not direct.
    pub(crate) fn iterates(&self) -> bool {
        self.direct.is_none()
    }

    /// `S rhs` from `guess`; returns the solution and the CG iterations (0 for
    /// the direct solve).
    fn solve(&self, mut rhs: Vec<f64>, guess: Option<Vec<f64>>) -> Result<(Vec<f64>, usize)> {
        for (r, &f) in rhs.iter_mut().zip(&self.fluid) {
            if !f {
                *r = 0.0;
            }
        }
        let shape = self.matrix.shape;
        let b = ArrayD::from_shape_vec(IxDyn(&shape), rhs).expect("one per cell");
        let (x, iterations) = match &self.direct {
            Some(Direct::Cholesky(chol)) => (
                chol.solve(b.view())
                    .map_err(|e| FlowError::Direct(e.to_string()))?,
                0,
            ),
            Some(Direct::Fourier(fft)) => {
                let rhs = b.as_slice().expect("standard layout");
                crate::spectral::check_finite("pressure solve", "right-hand side", rhs)?;
                let x =
                    ArrayD::from_shape_vec(IxDyn(&shape), fft.solve(rhs)).expect("one per cell");
                give_back(b.into_raw_vec_and_offset().0);
                (x, 0)
            }
            None => {
                let mut x = match guess {
                    Some(g) => ArrayD::from_shape_vec(IxDyn(&shape), g).expect("one per cell"),
                    None => ArrayD::zeros(IxDyn(&shape)),
                };
                let info = conjugate_gradient(&self.matrix, b.view(), x.view_mut(), &self.cg)
                    .map_err(|source| FlowError::Solve {
                        step: "pressure solve".into(),
                        quantity: "pressure".into(),
                        source,
                    })?;
                (x, info.iterations)
            }
        };
        let mut x = x.into_raw_vec_and_offset().0;
        for (v, &f) in x.iter_mut().zip(&self.fluid) {
            if !f {
                *v = 0.0;
            }
        }
        Ok((x, iterations))
    }
}

fn push_face(t: &mut Vec<(usize, usize, f64)>, lo: Option<usize>, hi: Option<usize>, c: f64) {
    for cell in [lo, hi].into_iter().flatten() {
        t.push((cell, cell, c));
    }
    if let (Some(a), Some(b)) = (lo, hi) {
        t.push((a, b, -c));
        t.push((b, a, -c));
    }
}

/// The outputs of [`project`].
#[derive(Debug, Clone, PartialEq)]
pub struct Projected<T> {
    /// `u'_x`.
    pub ux: Array2<T>,
    /// `u'_y`.
    pub uy: Array2<T>,
    /// The pressure `P = p/τ` at the cell centres (zero on solid cells).
    pub pressure: Array2<T>,
    /// CG iterations of the solve (0 for the direct solver).
    pub iterations: usize,
}

const NAME: &str = "pressure projection";

/// The projection of `(u_x, u_y)` over the pressure time scale `tau`, the
/// solve started from `pressure_guess` (a pressure `P`, scaled by `τ`) where
/// the solver is iterative. See the [module docs](self).
///
/// # Errors
/// [`FlowError::Shape`] for wrong shapes, [`FlowError::Solve`] or
/// [`FlowError::Direct`] if the solve fails.
pub fn project<T: Real>(
    system: &PressureSystem,
    tau: f64,
    ux: ArrayView2<'_, T>,
    uy: ArrayView2<'_, T>,
    pressure_guess: Option<ArrayView2<'_, T>>,
) -> Result<Projected<T>> {
    let (grid, faces) = (&system.grid, &*system.faces);
    grid.check_velocity(NAME, ux, uy)?;
    if let Some(p) = pressure_guess {
        grid.check_cells(NAME, "pressure guess", p)?;
    }
    let (mut ux, mut uy) = (owned(wide(ux)), owned(wide(uy)));
    let mut b = divergence_wide(grid, None, &ux, &uy);
    b.iter_mut().for_each(|d| *d = -*d);
    // a guess only where the solve iterates
    let guess = pressure_guess
        .filter(|_| system.iterates())
        .map(|p| p.iter().map(|v| v.as_f64() * tau).collect());
    let (p, iterations) = system.solve(b, guess)?;
    // `u −= 1 · g` is `u −= g`, bit for bit
    subtract_gradient_wide(grid, Some(faces), &p, 1.0, &mut ux, &mut uy);
    let mut pressure = p;
    pressure.iter_mut().for_each(|v| *v /= tau);
    Ok(Projected {
        ux: narrow(grid.shape_x(), ux),
        uy: narrow(grid.shape_y(), uy),
        pressure: narrow(grid.cell_shape(), pressure),
        iterations,
    })
}

/// The vector–Jacobian product of [`project`]: `(∂L/∂u_x, ∂L/∂u_y)` from the
/// gradients of `u'_x`, `u'_y` and `P` (absent: zero), by one solve.
///
/// # Errors
/// As [`project`].
pub fn project_vjp<T: Real>(
    system: &PressureSystem,
    tau: f64,
    grad_x: ArrayView2<'_, T>,
    grad_y: ArrayView2<'_, T>,
    grad_pressure: Option<ArrayView2<'_, T>>,
) -> Result<(Array2<T>, Array2<T>)> {
    let (grid, faces) = (&system.grid, &*system.faces);
    grid.check_velocity(NAME, grad_x, grad_y)?;
    let (mut gx, mut gy) = (owned(wide(grad_x)), owned(wide(grad_y)));
    let mut rhs = divergence_wide(grid, Some(faces), &gx, &gy);
    rhs.iter_mut().for_each(|d| *d = -*d);
    if let Some(gp) = grad_pressure {
        grid.check_cells(NAME, "pressure gradient", gp)?;
        rhs.iter_mut()
            .zip(gp.iter())
            .for_each(|(r, g)| *r -= g.as_f64() / tau);
    }
    let (s, _) = system.solve(rhs, None)?;
    let (sx, sy) = gradient_wide(grid, None, &s);
    gx.iter_mut().zip(&sx).for_each(|(g, s)| *g -= s);
    gy.iter_mut().zip(&sy).for_each(|(g, s)| *g -= s);
    for v in [s, sx, sy] {
        give_back(v);
    }
    Ok((narrow(grid.shape_x(), gx), narrow(grid.shape_y(), gy)))
}

/// Iteration counts of the pressure solves, shared between a step and its ops.
#[derive(Debug, Clone, Default)]
pub struct SolveCounter(Rc<RefCell<Vec<usize>>>);

impl SolveCounter {
    /// An empty counter.
    pub fn new() -> Self {
        Self::default()
    }

    pub(crate) fn push(&self, n: usize) {
        self.0.borrow_mut().push(n);
    }

    /// The iterations of each forward solve recorded so far.
    pub fn iterations(&self) -> Vec<usize> {
        self.0.borrow().clone()
    }
}

/// [`project`] as a tape op: inputs `[u_x, u_y, pressure_guess]`, outputs
/// `[u_x', u_y', P]`. The guess gets no gradient (the adjoint does not depend
/// on it); [`Op::saved_bytes`] is 0.
#[derive(Debug, Clone)]
pub struct Project {
    /// The pressure system.
    pub system: Arc<PressureSystem>,
    /// The pressure time scale `τ`.
    pub tau: f64,
    /// Where the forward solves' iteration counts go.
    pub counter: SolveCounter,
}

impl<T: Real> Op<T> for Project {
    fn name(&self) -> &str {
        NAME
    }

    fn forward(&mut self, inputs: &[ArrayViewD<'_, T>]) -> diffphys_tape::Result<Vec<ArrayD<T>>> {
        TapeError::check_arity(NAME, 3, inputs.len())?;
        let out = project(
            &self.system,
            self.tau,
            view2(&inputs[0])?,
            view2(&inputs[1])?,
            Some(view2(&inputs[2])?),
        )?;
        self.counter.push(out.iterations);
        Ok(vec![
            out.ux.into_dyn(),
            out.uy.into_dyn(),
            out.pressure.into_dyn(),
        ])
    }

    fn backward(
        &self,
        args: &BackwardArgs<'_, T>,
    ) -> diffphys_tape::Result<Vec<Option<ArrayD<T>>>> {
        if !args.needs(0) && !args.needs(1) {
            return Ok(vec![None, None, None]);
        }
        let gx = args.grad_output_or_zeros(0);
        let gy = args.grad_output_or_zeros(1);
        let gp = args.grad_outputs[2].as_ref().map(view2).transpose()?;
        let (a, b) = project_vjp(
            &self.system,
            self.tau,
            view2(&gx.view())?,
            view2(&gy.view())?,
            gp,
        )?;
        Ok(vec![
            args.needs(0).then(|| a.into_dyn()),
            args.needs(1).then(|| b.into_dyn()),
            None,
        ])
    }
}

/// `u_F − c (G_F P)_F`: the pressure gradient of the previous step applied to
/// the free faces (the incremental splitting advects `u − (dt/2) ∇P`).
/// Linear; adjoint `∂L/∂u = g`, `∂L/∂P = c D_F g_F`.
///
/// # Errors
/// [`FlowError::Shape`] for wrong shapes.
pub fn subtract_pressure_gradient<T: Real>(
    grid: &FlowGrid,
    faces: &Faces,
    c: f64,
    ux: ArrayView2<'_, T>,
    uy: ArrayView2<'_, T>,
    pressure: ArrayView2<'_, T>,
) -> Result<(Array2<T>, Array2<T>)> {
    const STEP: &str = "pressure gradient";
    grid.check_velocity(STEP, ux, uy)?;
    grid.check_cells(STEP, "pressure", pressure)?;
    let (mut ux, mut uy) = (owned(wide(ux)), owned(wide(uy)));
    subtract_gradient_wide(grid, Some(faces), &wide(pressure), c, &mut ux, &mut uy);
    Ok((narrow(grid.shape_x(), ux), narrow(grid.shape_y(), uy)))
}

/// The vector–Jacobian product of [`subtract_pressure_gradient`]:
/// `(∂L/∂u_x, ∂L/∂u_y, ∂L/∂P)`.
///
/// # Errors
/// [`FlowError::Shape`] for wrong shapes.
pub fn subtract_pressure_gradient_vjp<T: Real>(
    grid: &FlowGrid,
    faces: &Faces,
    c: f64,
    grad_x: ArrayView2<'_, T>,
    grad_y: ArrayView2<'_, T>,
) -> Result<(Array2<T>, Array2<T>, Array2<T>)> {
    grid.check_velocity("pressure gradient", grad_x, grad_y)?;
    let mut gp = divergence_wide(grid, Some(faces), &wide(grad_x), &wide(grad_y));
    gp.iter_mut().for_each(|v| *v *= c);
    Ok((
        grad_x.to_owned(),
        grad_y.to_owned(),
        narrow(grid.cell_shape(), gp),
    ))
}

/// [`subtract_pressure_gradient`] as a tape op: inputs `[u_x, u_y, P]`,
/// outputs `[u_x', u_y']`.
#[derive(Debug, Clone)]
pub struct SubtractPressureGradient {
    /// The grid.
    pub grid: FlowGrid,
    /// Its faces: the gradient acts on the free ones.
    pub faces: Arc<Faces>,
    /// The factor `c` (`dt/2` in the incremental splitting).
    pub c: f64,
}

impl<T: Real> Op<T> for SubtractPressureGradient {
    fn name(&self) -> &str {
        "pressure gradient"
    }

    fn forward(&mut self, inputs: &[ArrayViewD<'_, T>]) -> diffphys_tape::Result<Vec<ArrayD<T>>> {
        TapeError::check_arity("pressure gradient", 3, inputs.len())?;
        let (a, b) = subtract_pressure_gradient(
            &self.grid,
            &self.faces,
            self.c,
            view2(&inputs[0])?,
            view2(&inputs[1])?,
            view2(&inputs[2])?,
        )?;
        Ok(vec![a.into_dyn(), b.into_dyn()])
    }

    fn backward(
        &self,
        args: &BackwardArgs<'_, T>,
    ) -> diffphys_tape::Result<Vec<Option<ArrayD<T>>>> {
        let gx = args.grad_output_or_zeros(0);
        let gy = args.grad_output_or_zeros(1);
        let (a, b, p) = subtract_pressure_gradient_vjp(
            &self.grid,
            &self.faces,
            self.c,
            view2(&gx.view())?,
            view2(&gy.view())?,
        )?;
        Ok(vec![
            args.needs(0).then(|| a.into_dyn()),
            args.needs(1).then(|| b.into_dyn()),
            args.needs(2).then(|| p.into_dyn()),
        ])
    }
}
