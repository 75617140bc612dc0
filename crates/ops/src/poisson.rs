//! The implicit Poisson solve: `p = A⁻¹ b` by conjugate gradient, differentiated
//! by one more solve with the same operator instead of through the iterations.
//!
//! For a symmetric positive definite `A` (for example `−∇²` with zero Dirichlet
//! walls, [`crate::stencil::Laplacian2::negative`]):
//!
//! ```text
//! forward:  p = A⁻¹ b
//! adjoint:  grad_b = A⁻ᵀ grad_p = A⁻¹ grad_p      (A = Aᵀ)
//! ```
//!
//! The Jacobian of `b ↦ A⁻¹ b` is `A⁻¹` itself, so its vector–Jacobian product
//! is a solve with `A⁻ᵀ`, which is the same operator when `A` is symmetric.
//! Nothing of the forward iterations is needed: the adjoint keeps only the
//! operator, and it may use its own tolerance and a warm start.
//!
//! For a singular operator (all-Neumann or periodic: constants in the kernel),
//! declared by [`CgParams::null_space`], the forward solve returns the
//! zero-mean solution of `A p = Π b` (`Π` removes the mean); its Jacobian
//! `Π A⁺ Π` is again symmetric, so the adjoint is the same projected solve:
//! `grad_b = Π A⁺ Π grad_p`.
//!
//! ```
//! use std::sync::Arc;
//! use diffphys_ops::cg::CgParams;
//! use diffphys_ops::poisson::PoissonSolve;
//! use diffphys_ops::{stencil::Laplacian2, Boundary, Grid2};
//! use diffphys_tape::Tape;
//!
//! let grid = Grid2::new(16, 16, 1.0, 1.0, Boundary::ZeroDirichlet)?;
//! let solve = PoissonSolve::new(Arc::new(Laplacian2::negative(grid)), CgParams::default());
//! let log = solve.log();
//! let tape = Tape::<f64>::new();
//! let b = tape.var(diffphys_tape::test_array(&[16, 16], 3));
//! let p = tape.apply(solve.clone(), &[b])?; // a handle: records into the same log
//! assert_eq!(log.forward_solves(), 1);
//! let loss = p.mul(p)?.sum()?; // L = Σ p², grad_b = A⁻¹ (2p)
//! let grads = tape.backward(loss, &[b])?;
//! assert_eq!(grads.get(b).unwrap().shape(), &[16, 16]);
//! assert!(log.last_forward().unwrap().iterations > 0);
//! assert!(log.last_adjoint().unwrap().relative_residual < 1e-8);
//! # Ok::<(), diffphys_ops::OpsError>(())
//! ```
//!
//! # References
//! - M. B. Giles and N. A. Pierce, *An introduction to the adjoint approach to
//!   design*, Flow, Turbulence and Combustion 65 (2000) 393–415.
//! - P. Holl, V. Koltun, N. Thuerey, *Learning to control PDEs with
//!   differentiable physics*, ICLR 2020 (implicit gradients of pressure solves).

use std::cell::RefCell;
use std::rc::Rc;
use std::sync::Arc;

use diffphys_tape::{ArrayD, ArrayViewD, BackwardArgs, Op, Real, TapeError};
use ndarray::IxDyn;

use crate::cg::{conjugate_gradient, CgError, CgInfo, CgParams, Preconditioning};
use crate::multigrid::Multigrid;
use crate::{LinearOperator, OpsError, Result};

/// `p = A⁻¹ b` by conjugate gradient from a zero initial guess (with a null
/// space in `params`: the zero-mean solution of `A p = Π b`).
///
/// # Errors
/// The [`CgError`] of the solve.
pub fn poisson_solve<T: Real, A: LinearOperator<T> + ?Sized>(
    op: &A,
    b: ArrayViewD<'_, T>,
    params: &CgParams,
) -> Result<(ArrayD<T>, CgInfo), CgError> {
    solve_from(op, b, params, None)
}

/// The vector–Jacobian product of [`poisson_solve`]:
/// `grad_b = A⁻ᵀ grad_p = A⁻¹ grad_p` (`A` symmetric; with a null space,
/// `Π A⁺ Π grad_p`). `warm_start` is the initial guess of the solve (the
/// previous adjoint solution in an optimisation loop, say); `None` starts from
/// zero.
///
/// # Errors
/// The [`CgError`] of the solve (a warm start of the wrong shape is
/// [`CgError::ShapeMismatch`]).
pub fn poisson_solve_vjp<T: Real, A: LinearOperator<T> + ?Sized>(
    op: &A,
    grad_p: ArrayViewD<'_, T>,
    params: &CgParams,
    warm_start: Option<ArrayViewD<'_, T>>,
) -> Result<(ArrayD<T>, CgInfo), CgError> {
    solve_from(op, grad_p, params, warm_start)
}

/// CG on `op` from `x0` (zeros if `None`).
fn solve_from<T: Real, A: LinearOperator<T> + ?Sized>(
    op: &A,
    rhs: ArrayViewD<'_, T>,
    params: &CgParams,
    x0: Option<ArrayViewD<'_, T>>,
) -> Result<(ArrayD<T>, CgInfo), CgError> {
    let mut x = match x0 {
        Some(x0) => {
            if x0.shape() != op.input_shape() {
                return Err(CgError::ShapeMismatch {
                    what: "warm start".to_string(),
                    expected: op.input_shape().to_vec(),
                    found: x0.shape().to_vec(),
                });
            }
            x0.to_owned()
        }
        None => ArrayD::zeros(IxDyn(op.input_shape())),
    };
    let info = conjugate_gradient(op, rhs, x.view_mut(), params)?;
    Ok((x, info))
}

/// Which solves start from the previous solution of the same kind.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct WarmStart {
    /// The forward solve starts from the previous forward solution.
    pub forward: bool,
    /// The adjoint solve starts from the previous adjoint solution.
    pub adjoint: bool,
}

impl WarmStart {
    /// Both solves warm-started.
    pub fn both() -> Self {
        WarmStart {
            forward: true,
            adjoint: true,
        }
    }
}

/// What a [`SolveLog`] holds.
#[derive(Debug, Clone)]
struct LogState<T> {
    last_forward: Option<CgInfo>,
    last_adjoint: Option<CgInfo>,
    forward_solves: usize,
    adjoint_solves: usize,
    forward_iterations: usize,
    adjoint_iterations: usize,
    previous_forward: Option<ArrayD<T>>,
    previous_adjoint: Option<ArrayD<T>>,
}

impl<T> Default for LogState<T> {
    fn default() -> Self {
        LogState {
            last_forward: None,
            last_adjoint: None,
            forward_solves: 0,
            adjoint_solves: 0,
            forward_iterations: 0,
            adjoint_iterations: 0,
            previous_forward: None,
            previous_adjoint: None,
        }
    }
}

/// A shared record of the solves of implicit ops ([`PoissonSolve`],
/// [`crate::projection::ProjectionOp`]): the [`CgInfo`] of the last forward and
/// adjoint solves, counts and total iterations, and the previous solutions that
/// warm starts use. Cloning gives another handle on the same record, so a
/// harness keeps one and reads it after each step.
#[derive(Debug)]
pub struct SolveLog<T> {
    state: Rc<RefCell<LogState<T>>>,
}

impl<T> Clone for SolveLog<T> {
    fn clone(&self) -> Self {
        SolveLog {
            state: Rc::clone(&self.state),
        }
    }
}

impl<T> Default for SolveLog<T> {
    fn default() -> Self {
        SolveLog {
            state: Rc::new(RefCell::new(LogState::default())),
        }
    }
}

impl<T: Real> SolveLog<T> {
    /// An empty log.
    pub fn new() -> Self {
        Self::default()
    }

    /// The [`CgInfo`] of the last forward solve.
    pub fn last_forward(&self) -> Option<CgInfo> {
        self.state.borrow().last_forward.clone()
    }

    /// The [`CgInfo`] of the last adjoint solve.
    pub fn last_adjoint(&self) -> Option<CgInfo> {
        self.state.borrow().last_adjoint.clone()
    }

    /// Forward solves recorded.
    pub fn forward_solves(&self) -> usize {
        self.state.borrow().forward_solves
    }

    /// Adjoint solves recorded.
    pub fn adjoint_solves(&self) -> usize {
        self.state.borrow().adjoint_solves
    }

    /// CG iterations of all forward solves.
    pub fn forward_iterations(&self) -> usize {
        self.state.borrow().forward_iterations
    }

    /// CG iterations of all adjoint solves.
    pub fn adjoint_iterations(&self) -> usize {
        self.state.borrow().adjoint_iterations
    }

    /// Bytes held for warm starts (the previous solutions).
    pub fn warm_start_bytes(&self) -> usize {
        let s = self.state.borrow();
        let len = |a: &Option<ArrayD<T>>| a.as_ref().map_or(0, |a| a.len());
        (len(&s.previous_forward) + len(&s.previous_adjoint)) * std::mem::size_of::<T>()
    }

    /// Forgets counts, infos and warm-start solutions.
    pub fn clear(&self) {
        *self.state.borrow_mut() = LogState::default();
    }

    /// The previous forward solution, if warm starts are on and its shape fits.
    pub(crate) fn forward_guess(&self, on: bool, shape: &[usize]) -> Option<ArrayD<T>> {
        let s = self.state.borrow();
        s.previous_forward
            .as_ref()
            .filter(|p| on && p.shape() == shape)
            .cloned()
    }

    /// The previous adjoint solution, if warm starts are on and its shape fits.
    pub(crate) fn adjoint_guess(&self, on: bool, shape: &[usize]) -> Option<ArrayD<T>> {
        let s = self.state.borrow();
        s.previous_adjoint
            .as_ref()
            .filter(|p| on && p.shape() == shape)
            .cloned()
    }

    /// Records a forward solve (keeping `x` if `keep`).
    pub(crate) fn record_forward(&self, info: &CgInfo, x: &ArrayD<T>, keep: bool) {
        let mut s = self.state.borrow_mut();
        s.forward_solves += 1;
        s.forward_iterations += info.iterations;
        s.last_forward = Some(info.clone());
        if keep {
            store(&mut s.previous_forward, x);
        }
    }

    /// Records an adjoint solve (keeping `x` if `keep`).
    pub(crate) fn record_adjoint(&self, info: &CgInfo, x: &ArrayD<T>, keep: bool) {
        let mut s = self.state.borrow_mut();
        s.adjoint_solves += 1;
        s.adjoint_iterations += info.iterations;
        s.last_adjoint = Some(info.clone());
        if keep {
            store(&mut s.previous_adjoint, x);
        }
    }
}

/// Copies `x` into `slot`, reusing its allocation when the shape matches.
fn store<T: Real>(slot: &mut Option<ArrayD<T>>, x: &ArrayD<T>) {
    match slot {
        Some(s) if s.shape() == x.shape() => s.assign(x),
        _ => *slot = Some(x.clone()),
    }
}

/// The Poisson solve as a tape op: forward `p = A⁻¹ b` by CG, backward
/// `grad_b = A⁻¹ grad_p` by one more CG solve (see the module docs).
///
/// Holds the operator (shared, `Arc<A>`), the [`CgParams`] of the forward and of
/// the adjoint solve, which solves are warm-started, and a [`SolveLog`]. The op
/// keeps nothing of the forward iterations: its backward needs neither `b` nor
/// `p`. Its [`Op::saved_bytes`] is 0; the warm-start solutions live in the log,
/// shared by all steps ([`SolveLog::warm_start_bytes`]).
///
/// Recorded with `tape.apply(solve, &[b])`; the tape keeps the op, so a time
/// loop records a clone per step.
///
/// # What a clone shares
/// A `PoissonSolve` is a cheap handle. [`Clone`] shares everything with the
/// original: the operator (an `Arc`), the parameters (copied, but equal), and
/// the [`SolveLog`], which holds the counts and the warm-start solutions. So
/// the clones recorded on successive steps of one loop warm-start from each
/// other, and one [`PoissonSolve::log`] handle reads them all. For a solve
/// that must not see another's warm start or counts (two independent fields,
/// a validation run beside training), take [`PoissonSolve::clone_with_new_log`]:
/// the same operator and parameters, its own empty log.
///
/// Errors of a solve surface as [`TapeError::Op`] named `poisson_solve`, with the
/// [`CgError`] as its cause.
#[derive(Debug)]
pub struct PoissonSolve<T, A> {
    op: Arc<A>,
    forward: CgParams,
    adjoint: CgParams,
    warm_start: WarmStart,
    log: SolveLog<T>,
}

/// Another handle on the same solve, sharing its log and warm starts (see
/// [`PoissonSolve`]).
impl<T, A> Clone for PoissonSolve<T, A> {
    fn clone(&self) -> Self {
        PoissonSolve {
            op: Arc::clone(&self.op),
            forward: self.forward.clone(),
            adjoint: self.adjoint.clone(),
            warm_start: self.warm_start,
            log: self.log.clone(),
        }
    }
}

impl<T: Real, A: LinearOperator<T>> PoissonSolve<T, A> {
    /// The solve of `op` with `params` for the forward and the adjoint solve, no
    /// warm start, and a fresh log.
    pub fn new(op: Arc<A>, params: CgParams) -> Self {
        PoissonSolve {
            op,
            adjoint: params.clone(),
            forward: params,
            warm_start: WarmStart::default(),
            log: SolveLog::new(),
        }
    }

    /// With other parameters (its own tolerance, say) for the adjoint solve.
    pub fn with_adjoint_params(mut self, params: CgParams) -> Self {
        self.adjoint = params;
        self
    }

    /// With `mg` (built for this operator: [`Multigrid::new`] for a
    /// [`Laplacian2::negative`](crate::stencil::Laplacian2::negative),
    /// [`Multigrid::for_mac`] for a MAC pressure operator) as the
    /// preconditioner of both solves, forward and adjoint: MG-PCG. The
    /// implicit gradient stays exact (to the tolerance): the adjoint solve is
    /// the same symmetric solver.
    ///
    /// # Errors
    /// [`OpsError::ShapeMismatch`] if the
    /// cycle's grid does not have the operator's shape.
    pub fn with_multigrid(mut self, mg: Arc<Multigrid>) -> Result<Self> {
        let expected = self.op.input_shape();
        let found = LinearOperator::<T>::input_shape(&*mg);
        if expected != found {
            return Err(OpsError::shape("poisson_solve multigrid", expected, found));
        }
        let pre = Preconditioning::from(mg);
        self.forward.preconditioner = pre.clone();
        self.adjoint.preconditioner = pre;
        Ok(self)
    }

    /// With warm starts.
    pub fn with_warm_start(mut self, warm_start: WarmStart) -> Self {
        self.warm_start = warm_start;
        self
    }

    /// Recording into (and warm-starting from) an existing log.
    pub fn with_log(mut self, log: SolveLog<T>) -> Self {
        self.log = log;
        self
    }

    /// The same operator, parameters and warm-start policy with a log of its
    /// own: unlike a [`Clone`], it neither reads nor writes the original's
    /// warm-start solutions and counts.
    pub fn clone_with_new_log(&self) -> Self {
        self.clone().with_log(SolveLog::new())
    }

    /// A handle on the log (shared by every clone of this solve).
    pub fn log(&self) -> SolveLog<T> {
        self.log.clone()
    }

    /// The operator.
    pub fn operator(&self) -> &Arc<A> {
        &self.op
    }

    /// The forward parameters.
    pub fn forward_params(&self) -> &CgParams {
        &self.forward
    }

    /// The adjoint parameters.
    pub fn adjoint_params(&self) -> &CgParams {
        &self.adjoint
    }
}

const NAME: &str = "poisson_solve";

impl<T: Real, A: LinearOperator<T>> Op<T> for PoissonSolve<T, A> {
    fn name(&self) -> &str {
        NAME
    }

    fn forward(&mut self, inputs: &[ArrayViewD<'_, T>]) -> diffphys_tape::Result<Vec<ArrayD<T>>> {
        if inputs.len() != 1 {
            return Err(TapeError::Arity {
                op: NAME.to_string(),
                expected: 1,
                found: inputs.len(),
            });
        }
        let b = &inputs[0];
        if b.shape() != self.op.output_shape() {
            return Err(TapeError::shape(NAME, self.op.output_shape(), b.shape()));
        }
        let guess = self
            .log
            .forward_guess(self.warm_start.forward, self.op.input_shape());
        let (p, info) = solve_from(
            &*self.op,
            b.view(),
            &self.forward,
            guess.as_ref().map(|g| g.view()),
        )
        .map_err(|e| {
            let kind = e.kind();
            TapeError::op_of_kind(NAME, e, kind)
        })?;
        self.log.record_forward(&info, &p, self.warm_start.forward);
        Ok(vec![p])
    }

    fn backward(
        &self,
        args: &BackwardArgs<'_, T>,
    ) -> diffphys_tape::Result<Vec<Option<ArrayD<T>>>> {
        if !args.needs(0) {
            return Ok(vec![None]);
        }
        let guess = self
            .log
            .adjoint_guess(self.warm_start.adjoint, self.op.input_shape());
        let (grad_b, info) = poisson_solve_vjp(
            &*self.op,
            args.grad_out().view(),
            &self.adjoint,
            guess.as_ref().map(|g| g.view()),
        )
        .map_err(|e| {
            let kind = e.kind();
            TapeError::op_of_kind(NAME, e, kind)
        })?;
        self.log
            .record_adjoint(&info, &grad_b, self.warm_start.adjoint);
        Ok(vec![Some(grad_b)])
    }

    fn saved_bytes(&self) -> usize {
        0
    }
}
