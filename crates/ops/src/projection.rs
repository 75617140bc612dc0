//! Pressure projection on a staggered grid: the divergence-free part of a
//! velocity, with the pressure that removes the rest, and its adjoint.
//!
//! With the face gradient `G` and divergence `D = −Gᵀ` of a [`MacGrid`] (face
//! weights `W` built in: closed faces carry nothing), the projection solves
//! `∇²p = ∇·u`, i.e. `D G p = D u`, and subtracts the pressure gradient:
//!
//! ```text
//! b  = −D u = Gᵀ u
//! p  = S b              S = A⁻¹ on the range of A = −D G = Gᵀ G (CG, mean removed if singular)
//! u' = W u − G p = P u  P = W − G S Gᵀ
//! ```
//!
//! so `D u' = −(b − A p)`: the divergence left is the CG residual, below the
//! solver's tolerance. `P` is symmetric (`S` is), and idempotent since
//! `S Gᵀ G S = S A S = S`: projecting twice changes nothing.
//!
//! **Adjoint.** With `g_u = ∂L/∂u'` and `g_p = ∂L/∂p` (either may be absent,
//! that is zero):
//!
//! ```text
//! ∂L/∂u = Pᵀ g_u + (S Gᵀ)ᵀ g_p = W g_u − G S (Gᵀ g_u) + G S g_p
//!       = W g_u − G s,    s = S (Gᵀ g_u − g_p) = S (−D g_u − g_p)
//! ```
//!
//! one CG solve with the same operator, whatever combination of outputs the
//! loss uses. The pressure output contributes through `−g_p` in the right-hand
//! side: a loss on `p` pulls the velocity along `G S g_p`.
//!
//! ```
//! use diffphys_ops::cg::CgParams;
//! use diffphys_ops::mac::MacGrid;
//! use diffphys_ops::projection::PressureProjection;
//! use diffphys_ops::{Boundary, Grid2};
//!
//! let mac = MacGrid::new(Grid2::new(12, 10, 1.0, 1.0, Boundary::Closed)?);
//! let proj = PressureProjection::new(mac.clone(), CgParams::default().with_rel_tol(1e-10));
//! let ux = diffphys_tape::test_array::<f64>(&mac.shape_x(), 1);
//! let uy = diffphys_tape::test_array::<f64>(&mac.shape_y(), 2);
//! let out = proj.project(ux.view(), uy.view(), None)?;
//! let div = mac.divergence(out.velocity_x.view(), out.velocity_y.view())?;
//! assert!(div.iter().all(|d| d.abs() < 1e-8));
//! # Ok::<(), diffphys_ops::OpsError>(())
//! ```
//!
//! # References
//! - A. J. Chorin, *Numerical solution of the Navier–Stokes equations*, Math.
//!   Comp. 22 (1968) 745–762 (projection).
//! - P. Holl, V. Koltun, N. Thuerey, *Learning to control PDEs with
//!   differentiable physics*, ICLR 2020 (differentiable projection, the
//!   `differentiate_pressure` scene of PhiFlow).

use std::sync::Arc;

use diffphys_tape::{ArrayD, ArrayViewD, BackwardArgs, Op, Real, TapeError};
use ndarray::{IxDyn, Zip};

use crate::cg::{conjugate_gradient, CgInfo, CgParams, Preconditioning};
use crate::mac::{MacGrid, PressureOperator};
use crate::multigrid::Multigrid;
use crate::poisson::{SolveLog, WarmStart};
use crate::{OpsError, Result};

/// The outputs of [`PressureProjection::project`].
#[derive(Debug, Clone, PartialEq)]
pub struct Projected<T> {
    /// `u'_x` on the x-faces.
    pub velocity_x: ArrayD<T>,
    /// `u'_y` on the y-faces.
    pub velocity_y: ArrayD<T>,
    /// The pressure `p` at the cell centres (zero mean over the active cells
    /// when the operator is singular).
    pub pressure: ArrayD<T>,
    /// The pressure solve.
    pub info: CgInfo,
}

/// The outputs of [`PressureProjection::project_vjp`].
#[derive(Debug, Clone, PartialEq)]
pub struct ProjectionGrad<T> {
    /// `∂L/∂u_x`.
    pub velocity_x: ArrayD<T>,
    /// `∂L/∂u_y`.
    pub velocity_y: ArrayD<T>,
    /// The adjoint solve `s = S(−D g_u − g_p)` (a warm start for the next one).
    pub adjoint_pressure: ArrayD<T>,
    /// The adjoint solve's record.
    pub info: CgInfo,
}

/// The projection of a [`MacGrid`]: its pressure operator and the CG
/// parameters of the forward and the adjoint solve (see the module docs).
#[derive(Debug, Clone, PartialEq)]
pub struct PressureProjection {
    mac: MacGrid,
    op: PressureOperator,
    forward: CgParams,
    adjoint: CgParams,
}

impl PressureProjection {
    /// The projection on `mac` with `params` for both solves. The null space
    /// of `params` is replaced by the grid's ([`MacGrid::null_space`]).
    pub fn new(mac: MacGrid, params: CgParams) -> Self {
        let params = params.with_null_space(mac.null_space());
        PressureProjection {
            op: mac.pressure_operator(),
            mac,
            adjoint: params.clone(),
            forward: params,
        }
    }

    /// With other parameters for the adjoint solve (null space again the grid's).
    pub fn with_adjoint_params(mut self, params: CgParams) -> Self {
        self.adjoint = params.with_null_space(self.mac.null_space());
        self
    }

    /// With a multigrid V-cycle of `sweeps` smoothing sweeps
    /// ([`Multigrid::for_mac`]: obstacle masks and open boundaries included)
    /// as the preconditioner of both pressure solves, forward and adjoint
    /// (MG-PCG); the gradient stays the implicit one of the same solver.
    /// Call it after [`PressureProjection::with_adjoint_params`], which
    /// replaces the adjoint parameters.
    ///
    /// # Errors
    /// As [`Multigrid::for_mac`] (`sweeps` of 0).
    pub fn with_multigrid(mut self, sweeps: usize) -> Result<Self> {
        let mg = Preconditioning::from(Arc::new(Multigrid::for_mac(&self.mac, sweeps)?));
        self.forward.preconditioner = mg.clone();
        self.adjoint.preconditioner = mg;
        Ok(self)
    }

    /// The staggered grid.
    pub fn mac(&self) -> &MacGrid {
        &self.mac
    }

    /// The pressure operator `A = −D G`.
    pub fn operator(&self) -> &PressureOperator {
        &self.op
    }

    /// The forward solve's parameters.
    pub fn forward_params(&self) -> &CgParams {
        &self.forward
    }

    /// The adjoint solve's parameters.
    pub fn adjoint_params(&self) -> &CgParams {
        &self.adjoint
    }

    /// `S rhs` from `guess` (zeros if `None`).
    fn solve<T: Real>(
        &self,
        rhs: ArrayViewD<'_, T>,
        params: &CgParams,
        guess: Option<ArrayViewD<'_, T>>,
    ) -> Result<(ArrayD<T>, CgInfo)> {
        let shape = self.mac.cell_shape();
        let mut x = match guess {
            Some(g) if g.shape() == shape.as_slice() => g.to_owned(),
            Some(g) => {
                return Err(OpsError::shape(
                    "pressure_projection guess",
                    &shape,
                    g.shape(),
                ))
            }
            None => ArrayD::zeros(IxDyn(&shape)),
        };
        let info = conjugate_gradient(&self.op, rhs, x.view_mut(), params)?;
        Ok((x, info))
    }

    /// `u' = W u − G p` with `p = S(−D u)`, starting the pressure solve from
    /// `pressure_guess` (the previous pressure, say) or zero.
    ///
    /// # Errors
    /// [`OpsError::ShapeMismatch`] for arrays of the wrong shapes,
    /// [`OpsError::Cg`] if the pressure solve fails.
    pub fn project<T: Real>(
        &self,
        ux: ArrayViewD<'_, T>,
        uy: ArrayViewD<'_, T>,
        pressure_guess: Option<ArrayViewD<'_, T>>,
    ) -> Result<Projected<T>> {
        let b = self.mac.divergence(ux.view(), uy.view())?.mapv(|v| -v);
        let (pressure, info) = self.solve(b.view(), &self.forward, pressure_guess)?;
        let (gx, gy) = self.mac.gradient(pressure.view())?;
        let (velocity_x, velocity_y) = self.masked_difference(ux, uy, &gx, &gy)?;
        Ok(Projected {
            velocity_x,
            velocity_y,
            pressure,
            info,
        })
    }

    /// The vector–Jacobian product of [`PressureProjection::project`]:
    /// `∂L/∂u = W g_u − G s` with `s = S(−D g_u − g_p)`; an absent gradient is
    /// zero. `warm_start` starts the adjoint solve (the previous
    /// [`ProjectionGrad::adjoint_pressure`], say).
    ///
    /// # Errors
    /// As [`PressureProjection::project`].
    pub fn project_vjp<T: Real>(
        &self,
        grad_ux: Option<ArrayViewD<'_, T>>,
        grad_uy: Option<ArrayViewD<'_, T>>,
        grad_p: Option<ArrayViewD<'_, T>>,
        warm_start: Option<ArrayViewD<'_, T>>,
    ) -> Result<ProjectionGrad<T>> {
        let zeros = |s: [usize; 2]| ArrayD::<T>::zeros(IxDyn(&s));
        let gux = grad_ux.map_or_else(|| zeros(self.mac.shape_x()), |g| g.to_owned());
        let guy = grad_uy.map_or_else(|| zeros(self.mac.shape_y()), |g| g.to_owned());
        let mut rhs = self.mac.divergence(gux.view(), guy.view())?.mapv(|v| -v);
        if let Some(gp) = grad_p {
            if gp.shape() != rhs.shape() {
                return Err(OpsError::shape(
                    "pressure_projection grad_pressure",
                    rhs.shape(),
                    gp.shape(),
                ));
            }
            rhs -= &gp;
        }
        let (s, info) = self.solve(rhs.view(), &self.adjoint, warm_start)?;
        let (gx, gy) = self.mac.gradient(s.view())?;
        let (velocity_x, velocity_y) = self.masked_difference(gux.view(), guy.view(), &gx, &gy)?;
        Ok(ProjectionGrad {
            velocity_x,
            velocity_y,
            adjoint_pressure: s,
            info,
        })
    }

    /// `(W u_x − g_x, W u_y − g_y)`.
    fn masked_difference<T: Real>(
        &self,
        ux: ArrayViewD<'_, T>,
        uy: ArrayViewD<'_, T>,
        gx: &ArrayD<T>,
        gy: &ArrayD<T>,
    ) -> Result<(ArrayD<T>, ArrayD<T>)> {
        let mut vx = Zip::from(&ux).and(gx).map_collect(|&u, &g| u - g);
        let mut vy = Zip::from(&uy).and(gy).map_collect(|&u, &g| u - g);
        self.mac.zero_closed_faces(vx.view_mut(), vy.view_mut())?;
        Ok((vx, vy))
    }
}

/// The projection as a tape op: inputs `[u_x, u_y]`, outputs
/// `[u'_x, u'_y, p]`, backward by one adjoint solve (see the module docs).
///
/// Holds the shared [`PressureProjection`], which solves are warm-started, and a
/// [`SolveLog`] (the infos of the solves, the previous pressure and adjoint
/// solution). Keeps nothing of the forward solve: [`Op::saved_bytes`] is 0.
/// Solver failures surface as [`TapeError::Op`] named `pressure_projection`
/// with the [`CgError`](crate::cg::CgError) as its cause.
///
/// Recorded with `let out = tape.apply_multi(op, &[ux, uy])?` (`out` is
/// `[u'_x, u'_y, p]`). As with [`crate::poisson::PoissonSolve`], a clone is
/// another handle sharing the log and its warm starts;
/// [`ProjectionOp::clone_with_new_log`] gives one with its own.
#[derive(Debug)]
pub struct ProjectionOp<T> {
    projection: Arc<PressureProjection>,
    warm_start: WarmStart,
    log: SolveLog<T>,
}

impl<T> Clone for ProjectionOp<T> {
    fn clone(&self) -> Self {
        ProjectionOp {
            projection: Arc::clone(&self.projection),
            warm_start: self.warm_start,
            log: self.log.clone(),
        }
    }
}

const NAME: &str = "pressure_projection";

/// A projection error as a tape error: CG failures as [`TapeError::Op`] with
/// the [`CgError`](crate::cg::CgError) itself as source, the rest through [`OpsError`]'s conversion.
fn tape_error(e: OpsError) -> TapeError {
    match e {
        OpsError::Cg(cg) => {
            let kind = cg.kind();
            TapeError::op_of_kind(NAME, cg, kind)
        }
        other => other.into(),
    }
}

impl<T: Real> ProjectionOp<T> {
    /// The op of `projection`, no warm start, a fresh log.
    pub fn new(projection: Arc<PressureProjection>) -> Self {
        ProjectionOp {
            projection,
            warm_start: WarmStart::default(),
            log: SolveLog::new(),
        }
    }

    /// With warm starts (forward: from the previous pressure; adjoint: from the
    /// previous adjoint solution).
    pub fn with_warm_start(mut self, warm_start: WarmStart) -> Self {
        self.warm_start = warm_start;
        self
    }

    /// Recording into (and warm-starting from) an existing log.
    pub fn with_log(mut self, log: SolveLog<T>) -> Self {
        self.log = log;
        self
    }

    /// The same projection and warm-start policy with a log of its own: unlike
    /// a clone, it neither reads nor writes the original's warm-start solutions
    /// and counts.
    pub fn clone_with_new_log(&self) -> Self {
        self.clone().with_log(SolveLog::new())
    }

    /// A handle on the log (shared by every clone of this op).
    pub fn log(&self) -> SolveLog<T> {
        self.log.clone()
    }

    /// The projection.
    pub fn projection(&self) -> &Arc<PressureProjection> {
        &self.projection
    }
}

impl<T: Real> Op<T> for ProjectionOp<T> {
    fn name(&self) -> &str {
        NAME
    }

    fn forward(&mut self, inputs: &[ArrayViewD<'_, T>]) -> diffphys_tape::Result<Vec<ArrayD<T>>> {
        if inputs.len() != 2 {
            return Err(TapeError::Arity {
                op: NAME.to_string(),
                expected: 2,
                found: inputs.len(),
            });
        }
        let shape = self.projection.mac().cell_shape();
        let guess = self.log.forward_guess(self.warm_start.forward, &shape);
        let out = self
            .projection
            .project(
                inputs[0].view(),
                inputs[1].view(),
                guess.as_ref().map(|g| g.view()),
            )
            .map_err(tape_error)?;
        self.log
            .record_forward(&out.info, &out.pressure, self.warm_start.forward);
        Ok(vec![out.velocity_x, out.velocity_y, out.pressure])
    }

    fn backward(
        &self,
        args: &BackwardArgs<'_, T>,
    ) -> diffphys_tape::Result<Vec<Option<ArrayD<T>>>> {
        if !args.needs(0) && !args.needs(1) {
            return Ok(vec![None, None]);
        }
        let grad = |i: usize| args.grad_outputs[i].as_ref().map(|g| g.view());
        let shape = self.projection.mac().cell_shape();
        let guess = self.log.adjoint_guess(self.warm_start.adjoint, &shape);
        let g = self
            .projection
            .project_vjp(grad(0), grad(1), grad(2), guess.as_ref().map(|g| g.view()))
            .map_err(tape_error)?;
        self.log
            .record_adjoint(&g.info, &g.adjoint_pressure, self.warm_start.adjoint);
        Ok(vec![
            args.needs(0).then_some(g.velocity_x),
            args.needs(1).then_some(g.velocity_y),
        ])
    }

    fn saved_bytes(&self) -> usize {
        0
    }
}

/// Checks, for tests and reports, the largest `|D u|` over the cells.
///
/// # Errors
/// [`OpsError::ShapeMismatch`] for arrays of the wrong shapes.
pub fn max_abs_divergence<T: Real>(
    mac: &MacGrid,
    ux: ArrayViewD<'_, T>,
    uy: ArrayViewD<'_, T>,
) -> Result<f64> {
    let div = mac.divergence(ux, uy)?;
    Ok(div.iter().fold(0.0, |m, d| m.max(d.as_f64().abs())))
}
